"""Retention: clips, jobs and their files expire; a periodic cleanup removes records and files together.

Each clip and job gets ``expires_at = created + EIGENSCOPE_RETENTION_S`` when it is made (none when the
retention is 0). The cleanup, run by the API's sweeper every ``EIGENSCOPE_CLEANUP_INTERVAL_S``:

1. deletes the records of finished jobs past their time, then their artifact folders;
2. deletes the records of clips past their time that no queued or running job uses, then their files;
3. removes any ``clips/`` or ``jobs/`` folder that has no record and is older than
   ``EIGENSCOPE_ORPHAN_GRACE_S`` (left by a crash between steps, or by an upload that died halfway),
   and the records of streams whose job is gone (a stream's record and estimates go with its job).

Records go first: a crash in between leaves files without a record, which step 3 removes on a later
pass, never a record pointing at missing files.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from backend.errors import ConflictError, NotFoundError
from backend.storage import Storage
from backend.store import Store

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class CleanupReport:
    jobs: int
    clips: int
    orphans: int

    @property
    def total(self) -> int:
        return self.jobs + self.clips + self.orphans


def expiry(created: float, retention_s: float) -> float | None:
    """When something made at ``created`` (epoch seconds) expires; None when kept forever."""
    return created + retention_s if retention_s > 0 else None


def cleanup(
    store: Store, storage: Storage, *, now: float | None = None, orphan_grace_s: float
) -> CleanupReport:
    """One pass (see the module docstring)."""
    now = time.time() if now is None else now
    jobs = 0
    for job in store.expired_jobs(now):
        if store.delete_finished_job(job.id):
            storage.delete_job_outputs(job.id)
            jobs += 1
    clips = 0
    for clip in store.expired_clips(now):
        try:
            store.delete_clip(clip.id)
        except (ConflictError, NotFoundError):
            continue  # a job was queued on it meanwhile, or it was deleted by its owner
        storage.delete_clip(clip.id)
        clips += 1
    orphans = remove_orphans(store, storage, cutoff=now - orphan_grace_s) + store.delete_orphan_streams()
    report = CleanupReport(jobs, clips, orphans)
    if report.total:
        log.info("cleanup: removed %d expired job(s), %d expired clip(s), %d orphan(s)", jobs, clips, orphans)
    return report


def remove_orphans(store: Store, storage: Storage, *, cutoff: float) -> int:
    """Remove ``clips/`` and ``jobs/`` entries older than ``cutoff`` that have no record."""
    clip_names = storage.entries_older_than("clips", cutoff)
    job_names = storage.entries_older_than("jobs", cutoff)
    if not clip_names and not job_names:
        return 0
    clips, jobs = store.existing_ids(clip_names, job_names)
    removed = 0
    for kind, names, known in (("clips", clip_names, clips), ("jobs", job_names, jobs)):
        for name in names:
            if name not in known:
                log.warning("cleanup: removing %s/%s, which has no record", kind, name)
                storage.remove_entry(kind, name)
                removed += 1
    return removed
