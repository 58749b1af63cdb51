"""The embedded broker (kombu's filesystem transport in ``DATA_DIR/broker``) never shows a consumer a message
that is not written whole (a half-written file taken by a polling worker was a lost job, queued for ever),
and a worker asked to stop does not wait for messages first."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import pytest
from kombu import Connection
from kombu.transport import filesystem

from backend.broker import STOP_CHECK_S, celery_config
from backend.settings import Settings

_watch: dict[str, Any] = {"folder": None, "busy": False, "seen": []}


def _audit(event: str, args: tuple[Any, ...]) -> None:
    """At every audited step (open, lock, rename, write ...) while a message is being put, read each
    message file of the queue folder as a consumer would and note any that is not whole JSON."""
    folder = _watch["folder"]
    if folder is None or _watch["busy"]:
        return
    _watch["busy"] = True
    try:
        for name in os.listdir(folder):
            if name.endswith(".msg"):
                raw = (Path(folder) / name).read_bytes()
                try:
                    json.loads(raw)
                except ValueError:
                    _watch["seen"].append((event, name, raw))
    finally:
        _watch["busy"] = False


sys.addaudithook(_audit)  # audit hooks cannot be removed: inert while ``folder`` is None


def _connection(settings: Settings) -> Connection:
    config = celery_config(settings)
    return Connection(
        config["broker_url"],
        transport=config["broker_transport"],
        transport_options=config["broker_transport_options"],
    )


def test_a_message_file_is_only_ever_seen_whole(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data")
    folder = settings.broker_dir / "queue"
    with _connection(settings) as conn:
        queue = conn.SimpleQueue(settings.queue)
        _watch["folder"], _watch["seen"] = folder, []
        try:
            for i in range(5):
                queue.put({"job": i, "padding": "x" * 50_000})
        finally:
            _watch["folder"] = None
        assert _watch["seen"] == [], [(e, n, r[:40]) for e, n, r in _watch["seen"]]
        assert sorted(p.suffix for p in folder.iterdir()) == [".msg"] * 5  # no partial file left behind
        got = [queue.get(timeout=2) for _ in range(5)]
        assert sorted(m.payload["job"] for m in got) == list(range(5))
        for m in got:
            m.ack()
        queue.close()


def _parent_waits(monkeypatch: pytest.MonkeyPatch) -> list[float | None]:
    """The timeouts of kombu's own waits under the embedded transport's, recorded as they happen."""
    waits: list[float | None] = []
    parent = filesystem.Transport.drain_events

    def recorded(self: Any, connection: Any, timeout: float | None = None) -> Any:
        waits.append(timeout)
        return parent(self, connection, timeout=timeout)

    monkeypatch.setattr(filesystem.Transport, "drain_events", recorded)
    return waits


def test_a_worker_asked_to_stop_stops_waiting_for_messages(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Celery's loop waits 2 s per turn on a transport without asynchronous I/O and sees a SIGTERM only
    between turns (an idle `eigenscope serve` took 4.5-5.7 s to stop): a wait of the embedded transport
    ends as soon as the worker's warm stop (exit code 0) is requested, and otherwise lasts what it was
    asked, in slices that look for the request (messages are delivered through them: the test above)."""
    from celery.worker import state

    settings = Settings(data_dir=tmp_path / "data")
    waits = _parent_waits(monkeypatch)
    with _connection(settings) as conn:
        queue = conn.SimpleQueue(settings.queue)
        with pytest.raises(queue.Empty):
            queue.get(timeout=3 * STOP_CHECK_S)  # nothing queued, no stop: the whole wait, sliced
        assert len(waits) >= 3, waits
        assert all(w is not None and w <= STOP_CHECK_S for w in waits), waits
        waits.clear()
        monkeypatch.setattr(state, "should_stop", 0)  # what Celery's SIGTERM handler sets
        with pytest.raises(TimeoutError):
            conn.drain_events(timeout=3600)
        assert len(waits) == 1, waits
        queue.close()
