"""The embedded broker (kombu's filesystem transport in ``DATA_DIR/broker``) never shows a consumer a message
that is not written whole: a half-written file taken by a polling worker was a lost job, queued for ever."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

from kombu import Connection

from backend.broker import celery_config
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
