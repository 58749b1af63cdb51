"""Streams leave nothing behind in any ending (issue 27, item 14): no worker came, the job was cancelled
or deleted, the session failed, the worker crashed; and retention covers stream records."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest

from backend.settings import Settings
from backend.storage import Storage
from backend.store import NewClip, NewStream, Store, StreamRecord
from backend.stream_transport import LocalTransport

PROBLEM = {"type": "about:blank", "title": "x", "status": 503, "detail": "no worker", "code": "no-worker"}


def new_stream(store: Store, stream_id: str = "s1") -> StreamRecord:
    stream, _job = store.create_stream(
        NewStream(
            stream_id=stream_id,
            owner="",
            token_digest="0" * 64,
            request={"width": 320, "height": 240},
            expires_at=None,
            clip=NewClip(
                clip_id=f"c{stream_id}",
                filename="stream.zip",
                path=f"clips/c{stream_id}/clip.zip",
                info={},
                size_bytes=0,
            ),
            excitation=None,
            parameters={},
        )
    )
    return stream


@pytest.fixture
def transport(tmp_path: Path) -> LocalTransport:
    return LocalTransport(tmp_path / "streams")


def leftovers(root: Path) -> list[str]:
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())


def test_a_stream_no_worker_took_up_leaves_no_pending_entry(store: Store, transport: LocalTransport) -> None:
    stream = new_stream(store)
    asyncio.run(transport.dispatch(stream.id))
    assert store.fail_stream_job(stream.job_id, PROBLEM)  # the relay's `no-worker`
    asyncio.run(transport.acleanup(stream.id))
    assert leftovers(transport.root) == []
    assert transport.claim(0.1) is None  # no worker picks the dead stream up later


def test_a_worker_that_picks_up_a_dead_stream_cleans_it_up(
    store: Store, settings: Settings, transport: LocalTransport
) -> None:
    from workers.streams import Session

    stream = new_stream(store)
    asyncio.run(transport.dispatch(stream.id))
    assert transport.claim(0.1) == stream.id  # taken just before the relay gave up on it
    store.fail_stream_job(stream.job_id, PROBLEM)
    Session(stream.id, settings, store, Storage(settings.data_path), transport).run()
    assert leftovers(transport.root) == []


def test_a_failed_session_leaves_no_frames_folder(tmp_path: Path) -> None:
    from workers.streams import ClipWriter

    writer = ClipWriter(tmp_path / "tmp" / "stream-s1" / "clip.zip")
    writer.add(frame=0, timestamp_s=0.0, color=b"\xff\xd8", color_ext="jpg", depth=None)
    writer.discard()
    assert not (tmp_path / "tmp" / "stream-s1").exists()


def test_the_sweeper_removes_the_files_of_ended_streams(settings: Settings) -> None:
    """After a worker crashed: its stream's frames in tmp/ and its message folder."""
    from tests.unit.service.helpers import make_client

    with make_client(settings) as client:
        ctx: Any = client.app.state.ctx  # type: ignore[attr-defined]
        ended, live = new_stream(ctx.store, "s1"), new_stream(ctx.store, "s2")
        for s in (ended, live):
            (ctx.storage.root / "tmp" / f"stream-{s.id}").mkdir(parents=True)
            (ctx.storage.root / "tmp" / f"stream-{s.id}" / "clip.zip").write_bytes(b"PK" * 1000)
            asyncio.run(ctx.stream_transport.dispatch(s.id))
        ctx.store.fail_stream_job(ended.job_id, PROBLEM)  # the lease of its crashed worker expired
        ctx.sweep()
        assert not (ctx.storage.root / "tmp" / "stream-s1").exists()
        assert not (ctx.stream_transport.root / "s1").exists()
        assert (ctx.storage.root / "tmp" / "stream-s2" / "clip.zip").exists()
        assert (ctx.stream_transport.root / "s2").exists()


def test_cancelling_a_streams_job_ends_the_stream(store: Store) -> None:
    stream = new_stream(store)
    store.update_stream(stream.id, status="finishing")
    store.cancel_job(stream.job_id)
    record = store.get_stream(stream.id)
    assert record.status == "failed"
    assert record.error is not None
    assert record.error["code"] == "stream-aborted"
    assert store.list_streams(owner="", active=True) == []


def test_deleting_a_streams_job_deletes_its_stream_and_retention_covers_the_rest(
    store: Store, settings: Settings
) -> None:
    from sqlalchemy import delete

    from backend.store.schema import JobRow
    from service.retention import cleanup

    deleted, orphan = new_stream(store, "s1"), new_stream(store, "s2")
    store.update_stream(deleted.id, last_estimate={"eigenfrequency_hz": 4.0})
    store.delete_job(deleted.job_id)
    assert store.find_stream(deleted.id) is None
    # A stream whose job went before deleting a job removed its stream too: retention removes it.
    store.fail_stream_job(orphan.job_id, PROBLEM)
    with store.engine.begin() as conn:
        conn.execute(delete(JobRow).where(JobRow.id == orphan.job_id))
    cleanup(store, Storage(settings.data_path), orphan_grace_s=3600)
    assert store.find_stream(orphan.id) is None
