"""The store's job callbacks (webhooks): which are due, who is delivering each (a lease of its own, so
several API processes never send one callback twice at once), and how each delivery ended.

A job with a callback URL has its callback due when it ends (:func:`backend.store.engine._ended`).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from sqlalchemy import func, select, update

from backend.store.engine import StoreBase
from backend.store.records import ANY_OWNER, JobRecord
from backend.store.schema import JobRow

#: The callback error of a callback given up because its last attempt never reported.
_UNFINISHED_ATTEMPT = "the last attempt did not finish (the API process delivering it stopped)"


class CallbackStore(StoreBase):
    """Job callbacks in the store (a part of :class:`~backend.store.Store`)."""

    if TYPE_CHECKING:  # the other parts' methods this one builds on

        def find_job(self, job_id: str, owner: str | None = ANY_OWNER) -> JobRecord | None: ...

    def due_callbacks(self, *, limit: int) -> list[tuple[str, str]]:
        """``(job id, callback URL)`` of jobs whose callback is due and not leased, most overdue first."""
        now = time.time()
        query = (
            select(JobRow.id, JobRow.callback_url)
            .where(
                JobRow.callback_status == "pending",
                JobRow.callback_next_at <= now,
                (JobRow.callback_lease_until.is_(None)) | (JobRow.callback_lease_until < now),
            )
            .order_by(JobRow.callback_next_at)
            .limit(limit)
        )
        with self._tx(readonly=True) as s:
            return [(job_id, url or "") for job_id, url in s.execute(query).all()]

    def claim_callback(
        self, job_id: str, *, lease_s: float, max_attempts: int | None = None
    ) -> JobRecord | None:
        """Lease job ``job_id``'s due callback for one attempt (counted now); None when another process
        has it. A callback that already had ``max_attempts`` (its last attempt never reported: the process
        delivering it stopped) is given up instead, so the attempts never pass the maximum."""
        now = time.time()
        free = (JobRow.callback_lease_until.is_(None)) | (JobRow.callback_lease_until < now)
        with self._tx() as s:
            if max_attempts is not None:
                s.execute(
                    update(JobRow)
                    .where(
                        JobRow.id == job_id,
                        JobRow.callback_status == "pending",
                        JobRow.callback_attempts >= max_attempts,
                        free,
                    )
                    .values(
                        callback_status="failed",
                        callback_next_at=None,
                        callback_lease_until=None,
                        callback_error=func.coalesce(JobRow.callback_error, _UNFINISHED_ATTEMPT),
                    )
                )
            res = s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.callback_status == "pending", free)
                .values(callback_lease_until=now + lease_s, callback_attempts=JobRow.callback_attempts + 1)
            )
        if not res.rowcount:  # type: ignore[attr-defined]
            return None
        return self.find_job(job_id)

    def renew_callback_lease(self, job_id: str, *, lease_s: float) -> None:
        """Extend the lease of a callback being delivered (it must not pass to another process)."""
        with self._tx() as s:
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id, JobRow.callback_status == "pending")
                .values(callback_lease_until=time.time() + lease_s)
            )

    def claim_due_callbacks(
        self, *, limit: int, lease_s: float, max_attempts: int | None = None
    ) -> list[JobRecord]:
        """Jobs whose callback is due, each leased to the caller for ``lease_s`` (several API processes
        deliver without sending one callback twice at once); see :meth:`claim_callback`."""
        claimed = []
        for job_id, _url in self.due_callbacks(limit=limit):
            job = self.claim_callback(job_id, lease_s=lease_s, max_attempts=max_attempts)
            if job is not None:
                claimed.append(job)
        return claimed

    def record_callback(self, job_id: str, *, status: str, next_at: float | None, error: str | None) -> None:
        """The outcome of a delivery: ``delivered``, ``failed`` (given up) or ``pending`` again at
        ``next_at``."""
        with self._tx() as s:
            s.execute(
                update(JobRow)
                .where(JobRow.id == job_id)
                .values(
                    callback_status=status,
                    callback_next_at=next_at,
                    callback_lease_until=None,
                    callback_error=None if error is None else error[:500],
                )
            )
