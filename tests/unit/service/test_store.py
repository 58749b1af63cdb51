"""The job store: idempotency, pagination, cancellation, claims and leases."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from backend.errors import ConflictError, InvalidInputError, NotFoundError
from backend.store import ClaimOutcome, NewClip, NewJob, Store, lease_owner_token, owner_is_dead_here


def add_clip(store: Store, clip_id: str = "c1") -> str:
    store.add_clip(
        NewClip(
            clip_id=clip_id,
            filename="a.npz",
            path=f"clips/{clip_id}/clip.npz",
            info={"frames": 16},
            size_bytes=1,
        )
    )
    return clip_id


def new_job(store: Store, clip_id: str = "c1") -> str:
    job, created = store.create_job(NewJob(clip_id=clip_id, excitation=None, parameters={}))
    assert created
    return job.id


def test_job_needs_an_existing_clip(store: Store) -> None:
    with pytest.raises(InvalidInputError, match="does not exist"):
        store.create_job(NewJob(clip_id="nope", excitation=None, parameters={}))


def test_idempotency_key_same_and_different_body(store: Store) -> None:
    add_clip(store)
    a, created_a = store.create_job(
        NewJob(clip_id="c1", excitation=None, parameters={}, idempotency_key="k", request_hash="h1")
    )
    b, created_b = store.create_job(
        NewJob(clip_id="c1", excitation=None, parameters={}, idempotency_key="k", request_hash="h1")
    )
    assert created_a
    assert not created_b
    assert a.id == b.id
    with pytest.raises(InvalidInputError, match="different request body"):
        store.create_job(
            NewJob(clip_id="c1", excitation=None, parameters={}, idempotency_key="k", request_hash="h2")
        )


def test_list_newest_first_with_cursor_and_status(store: Store) -> None:
    add_clip(store)
    ids = [new_job(store) for _ in range(5)]
    page, cursor = store.list_jobs(limit=2)
    assert [j.id for j in page] == ids[::-1][:2]
    assert cursor
    page2, cursor2 = store.list_jobs(limit=2, cursor=cursor)
    assert [j.id for j in page2] == ids[::-1][2:4]
    page3, cursor3 = store.list_jobs(limit=2, cursor=cursor2)
    assert [j.id for j in page3] == ids[:1]
    assert cursor3 is None
    store.cancel_job(ids[0])
    assert [j.id for j in store.list_jobs(statuses=["cancelled"])[0]] == [ids[0]]
    with pytest.raises(InvalidInputError):
        store.list_jobs(cursor="!!")


def test_cancel_rules(store: Store) -> None:
    add_clip(store)
    job_id = new_job(store)
    assert store.cancel_job(job_id).status == "cancelled"
    assert store.cancel_job(job_id).status == "cancelled"  # idempotent
    assert store.claim_job(job_id, lease_owner_token()).outcome is ClaimOutcome.FINISHED
    done = new_job(store)
    owner = lease_owner_token()
    assert store.claim_job(done, owner).outcome is ClaimOutcome.CLAIMED
    assert store.complete_job(done, owner, {"x": 1})
    with pytest.raises(ConflictError):
        store.cancel_job(done)
    with pytest.raises(NotFoundError):
        store.cancel_job("missing")


def test_cancel_reaches_the_running_worker(store: Store) -> None:
    add_clip(store)
    job_id = new_job(store)
    owner = lease_owner_token()
    assert store.claim_job(job_id, owner).outcome is ClaimOutcome.CLAIMED
    assert store.report_progress(job_id, owner, "flow", 0.3)
    store.cancel_job(job_id)
    assert not store.report_progress(job_id, owner, "flow", 0.4)
    assert not store.complete_job(job_id, owner, {})
    assert store.get_job(job_id).status == "cancelled"


def test_live_lease_blocks_a_second_claim(store: Store) -> None:
    add_clip(store)
    job_id = new_job(store)
    first = store.claim_job(job_id, lease_owner_token())
    assert first.outcome is ClaimOutcome.CLAIMED
    assert first.job is not None
    assert first.job.attempts == 1
    second = store.claim_job(job_id, "otherhost/1/x")
    assert second.outcome is ClaimOutcome.BUSY
    assert 0 < second.retry_in_s <= store.lease_s + 1


def test_dead_owner_is_taken_over_and_attempts_are_bounded(store: Store) -> None:
    add_clip(store)
    job_id = new_job(store)
    dead = subprocess.Popen(["true"])
    dead.wait()
    import socket

    ghost = f"{socket.gethostname()}/{dead.pid}/abc"
    assert owner_is_dead_here(ghost)
    assert store.claim_job(job_id, ghost).outcome is ClaimOutcome.CLAIMED
    retaken = store.claim_job(job_id, lease_owner_token())
    assert retaken.outcome is ClaimOutcome.CLAIMED
    assert retaken.job is not None
    assert retaken.job.attempts == 2
    # max_attempts=2: the next take-over fails the job instead of running it a third time.
    store.renew_lease(job_id, retaken.job.lease_owner or "")
    with store._tx() as s:  # expire the lease
        from sqlalchemy import update

        from backend.store.schema import JobRow

        s.execute(update(JobRow).where(JobRow.id == job_id).values(lease_until=time.time() - 1))
    exhausted = store.claim_job(job_id, lease_owner_token())
    assert exhausted.outcome is ClaimOutcome.EXHAUSTED
    job = store.get_job(job_id)
    assert job.status == "failed"
    assert job.error is not None
    assert "stopped 2 time" in job.error["detail"]


def test_recover_requeues_expired_leases(store: Store) -> None:
    add_clip(store)
    job_id = new_job(store)
    owner = "elsewhere/1/x"
    assert store.claim_job(job_id, owner).outcome is ClaimOutcome.CLAIMED
    assert store.recover_stale_jobs(requeue_after_s=3600) == []
    from sqlalchemy import update

    from backend.store.schema import JobRow

    with store._tx() as s:
        s.execute(update(JobRow).where(JobRow.id == job_id).values(lease_until=time.time() - 1))
    assert store.recover_stale_jobs(requeue_after_s=3600) == [job_id]
    job = store.get_job(job_id)
    assert job.status == "queued"
    assert job.lease_owner is None
    assert job.attempts == 1
    store.mark_unpublished(job_id)
    assert store.recover_stale_jobs(requeue_after_s=3600) == [job_id]


def test_delete_clip_refused_while_a_job_is_active(store: Store) -> None:
    add_clip(store)
    job_id = new_job(store)
    with pytest.raises(ConflictError, match="cancel them first"):
        store.delete_clip("c1")
    store.cancel_job(job_id)
    store.delete_clip("c1")
    with pytest.raises(NotFoundError):
        store.get_clip("c1")


def test_tables_of_an_older_release_get_the_new_columns(tmp_path: Path) -> None:
    """A job store made before keys and retention existed is brought up to date, its rows kept."""
    import sqlite3

    db = tmp_path / "old.db"
    con = sqlite3.connect(db)
    con.executescript(
        """
        CREATE TABLE eigenscope_clips (id VARCHAR(64) PRIMARY KEY, filename VARCHAR(255), path VARCHAR(512),
            info JSON, size_bytes INTEGER, created_at DATETIME);
        CREATE TABLE eigenscope_jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, id VARCHAR(64) UNIQUE,
            clip_id VARCHAR(64), status VARCHAR(16), progress FLOAT, stage VARCHAR(64), attempts INTEGER,
            excitation JSON, parameters JSON, created_at DATETIME, started_at DATETIME, finished_at DATETIME,
            error JSON, result JSON, idempotency_key VARCHAR(255) UNIQUE, request_hash VARCHAR(64),
            lease_owner VARCHAR(255), lease_until FLOAT, enqueued_at FLOAT, version INTEGER);
        INSERT INTO eigenscope_clips
            VALUES ('c0', 'a.npz', 'clips/c0/clip.npz', '{}', 10, '2026-01-01 00:00:00');
        """
    )
    con.commit()
    con.close()
    store = Store(f"sqlite:///{db}")
    try:
        store.create_schema()
        store.create_schema()  # idempotent
        clip = store.get_clip("c0", "")
        assert (clip.owner, clip.expires_at, clip.size_bytes) == ("", None, 10)
        job, _ = store.create_job(NewJob(clip_id="c0", excitation=None, parameters={}, owner=""))
        assert store.get_job(job.id, "").output_bytes == 0
        assert store.usage("").stored_bytes == 10
        assert store.get_job(job.id, "").force_log_summary is None
        assert store.job_force_log(job.id) is None
        logged, _ = store.create_job(NewJob(clip_id="c0", excitation=None, parameters={}, **FORCE_LOG))
        assert store.job_force_log(logged.id) == FORCE_LOG["force_log"]
    finally:
        store.dispose()


#: A job's force log as the API stores it (``api_schemas.ForceLog`` and its summary, as JSON).
FORCE_LOG: dict[str, Any] = {
    "force_log": {
        "time_s": [i / 500 for i in range(8)],
        "fx": [6.0, 6.0, 6.0, 6.0, 0.0, 0.0, 0.0, 0.0],
        "fy": [0.0] * 8,
        "fz": [-0.25] * 8,
        "force_n": None,
        "offset_s": -1.5,
        "frame_id": "ft_sensor_link",
        "name": "push.csv",
    },
    "force_log_summary": {
        "name": "push.csv",
        "samples": 8,
        "start_s": -1.5,
        "end_s": -1.486,
        "columns": ["fx", "fy", "fz"],
        "frame_id": "ft_sensor_link",
    },
}


def test_a_force_log_is_stored_apart_from_the_record(store: Store) -> None:
    """The job's record (every poll and list reads it) carries the summary; the log, up to 200,000
    samples, is read only when asked for, exactly as it was sent."""
    add_clip(store)
    job, _ = store.create_job(NewJob(clip_id="c1", excitation=None, parameters={}, **FORCE_LOG))
    assert job.force_log_summary == FORCE_LOG["force_log_summary"]
    assert store.get_job(job.id).force_log_summary == FORCE_LOG["force_log_summary"]
    assert [j.force_log_summary for j in store.list_jobs()[0]] == [FORCE_LOG["force_log_summary"]]
    assert not hasattr(store.get_job(job.id), "force_log")
    assert store.job_force_log(job.id) == FORCE_LOG["force_log"]
    assert store.job_force_log("no-such-job") is None
    # A claim carries the summary too, and the log goes with the job when it is deleted.
    claimed = store.claim_job(job.id, "me/1/x").job
    assert claimed is not None
    assert claimed.force_log_summary == FORCE_LOG["force_log_summary"]
    store.cancel_job(job.id)
    store.delete_job(job.id)
    assert store.job_force_log(job.id) is None
