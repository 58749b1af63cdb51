"""The job and clip store: SQLAlchemy over SQLite (default) or PostgreSQL.

The job row is the source of truth for a job's state; Celery only carries "run job X" messages. A worker
must *claim* a job before running it: the claim sets a lease (owner and expiry) and counts the attempt,
in one optimistic-concurrency update (``version`` column), so two deliveries of the same message never
run the job at the same time. The lease is renewed while the job runs; progress, completion and failure
writes only land while the writer still owns the lease, which is how cancellation and take-over reach a
running worker.

Records are returned as frozen dataclasses, never as live ORM objects.

:class:`Store` is one object made of parts, one module each, over one engine:

- :mod:`~backend.store.engine` -- :class:`~backend.store.engine.StoreBase`: connections, transactions,
  schema creation and upgrades, a tenant's usage; the helpers the parts share;
- :mod:`~backend.store.schema` -- the tables; :mod:`~backend.store.records` -- what goes in and out;
- :mod:`~backend.store.clips` -- :class:`~backend.store.clips.ClipStore`;
- :mod:`~backend.store.jobs` -- :class:`~backend.store.jobs.JobStore`: jobs as the API sees them;
- :mod:`~backend.store.leases` -- :class:`~backend.store.leases.LeaseStore`: claims, leases and the
  writes of the worker holding a job, the recovery of jobs whose worker died, and :class:`Lease`, the
  worker's heartbeat;
- :mod:`~backend.store.callbacks` -- :class:`~backend.store.callbacks.CallbackStore`: job webhooks;
- :mod:`~backend.store.streams` -- :class:`~backend.store.streams.StreamStore`: live stream sessions.
"""

from __future__ import annotations

from backend.store.callbacks import CallbackStore
from backend.store.clips import ClipStore
from backend.store.engine import dumps_canonical, new_id, storage_quota_error
from backend.store.jobs import JobStore
from backend.store.leases import Lease, LeaseStore, lease_owner_token, owner_is_dead_here
from backend.store.records import (
    ACTIVE,
    ANY_OWNER,
    NO_LIMITS,
    STREAM_ACTIVE,
    TERMINAL,
    Claim,
    ClaimOutcome,
    ClipRecord,
    JobRecord,
    NewClip,
    NewJob,
    NewStream,
    StreamRecord,
    TenantLimits,
    Usage,
)
from backend.store.streams import StreamStore


class Store(ClipStore, JobStore, LeaseStore, CallbackStore, StreamStore):
    """Clips, jobs, their leases and callbacks, and live streams in a SQL database.

    Parameters
    ----------
    url : str
        SQLAlchemy database URL. SQLite files get WAL mode, a busy timeout and immediate transactions, so
        several processes can share one file.
    lease_s : float
        How long a claim lasts without renewal.
    max_attempts : int
        Claims a job may have before it is failed instead of run again.
    """


__all__ = [
    "ACTIVE",
    "ANY_OWNER",
    "NO_LIMITS",
    "STREAM_ACTIVE",
    "TERMINAL",
    "Claim",
    "ClaimOutcome",
    "ClipRecord",
    "JobRecord",
    "Lease",
    "NewClip",
    "NewJob",
    "NewStream",
    "Store",
    "StreamRecord",
    "TenantLimits",
    "Usage",
    "dumps_canonical",
    "lease_owner_token",
    "new_id",
    "owner_is_dead_here",
    "storage_quota_error",
]
