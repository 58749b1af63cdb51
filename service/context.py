"""Everything one API instance holds: settings, store, storage, queue, metrics and the recovery sweeper."""

from __future__ import annotations

import logging
import os
import shutil
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from backend.broker import ensure_broker_folders
from backend.errors import UnavailableError
from backend.settings import Settings
from backend.storage import Reservations, Storage
from backend.store import STREAM_ACTIVE, JobRecord, Store, TenantLimits
from backend.stream_transport import LocalTransport, StreamTransport, transport_for
from service.auth import FailedAuthLimiter, KeyRing
from service.metrics import Metrics
from service.queue import JobQueue
from service.retention import cleanup
from service.views import job_view
from service.webhooks import Dispatcher

log = logging.getLogger(__name__)

#: Files of the embedded broker's "processed" folder and stale temp files older than this are removed.
_CLEANUP_AGE_S = 3600.0


def _remove_older_than(folder: Path, pattern: str, age_s: float) -> None:
    cutoff = time.time() - age_s
    if not folder.is_dir():
        return
    for path in folder.glob(pattern):
        try:
            if path.stat().st_mtime < cutoff:
                if path.is_dir():
                    import shutil

                    shutil.rmtree(path, ignore_errors=True)
                else:
                    path.unlink(missing_ok=True)
        except OSError:
            continue


@dataclass
class ServiceContext:
    """The state of one app instance (stored on ``app.state.ctx``)."""

    settings: Settings
    store: Store
    storage: Storage
    queue: JobQueue
    metrics: Metrics
    stream_transport: StreamTransport
    keys: KeyRing = field(default_factory=lambda: KeyRing({}))
    auth_limiter: FailedAuthLimiter = field(default_factory=lambda: FailedAuthLimiter(20, 60.0))
    webhooks: Dispatcher | None = None
    schema_ready: bool = False
    #: Uploads being received now (changed on the event loop only).
    uploads_in_flight: int = 0
    #: Their bytes so far, per tenant (the running count their storage quota is checked against).
    upload_reservations: Reservations = field(default_factory=Reservations)
    _stop: threading.Event = field(default_factory=threading.Event)
    _sweeper: threading.Thread | None = None
    _last_cleanup: float = float("-inf")
    _last_reconcile: float = float("-inf")
    #: Queued jobs the broker held no message for at the last reconciliation: ``{id: enqueued_at}``.
    _unheld: dict[str, float] = field(default_factory=dict)

    @classmethod
    def build(cls, settings: Settings) -> ServiceContext:
        store = Store(
            settings.effective_database_url, lease_s=settings.lease_s, max_attempts=settings.max_attempts
        )
        return cls(
            settings=settings,
            store=store,
            storage=Storage(settings.data_path),
            queue=JobQueue(settings),
            metrics=Metrics(store),
            stream_transport=transport_for(settings),
            keys=KeyRing.from_settings(settings),
            auth_limiter=FailedAuthLimiter(
                settings.auth_failures_per_window,
                settings.auth_failure_window_s,
                known_s=settings.auth_known_key_s,
            ),
            webhooks=Dispatcher(store, settings, _webhook_view(settings))
            if settings.callback_hosts
            else None,
        )

    def start(self) -> None:
        """Create the storage tree and the tables, then start the sweeper thread.

        An unreachable database or storage does not stop the API from starting: ``/readyz`` reports it,
        requests that need it answer 503, and the sweeper creates the tables once the database is back.
        """
        try:
            self.storage.ensure()
            if self.settings.embedded:
                ensure_broker_folders(self.settings)
            self.remove_abandoned_uploads()  # a crashed process's half-received uploads go now
        except OSError as exc:
            log.error("storage %s cannot be prepared: %s", self.storage.root, exc)
        self.ensure_schema()
        self._stop.clear()
        self._sweeper = threading.Thread(target=self._sweep_loop, name="eigenscope-sweeper", daemon=True)
        self._sweeper.start()
        if self.webhooks is not None:
            self.webhooks.start()

    def stop(self) -> None:
        self._stop.set()
        if self.webhooks is not None:
            self.webhooks.stop()
        if self._sweeper is not None:
            self._sweeper.join(timeout=10)
            self._sweeper = None
        self.queue.close()
        self.stream_transport.close()
        self.store.dispose()

    @property
    def tenant_limits(self) -> TenantLimits:
        """What one API key may hold (``EIGENSCOPE_MAX_ACTIVE_JOBS_PER_KEY``,
        ``EIGENSCOPE_MAX_STORED_MB_PER_KEY``), with the Retry-After of a refusal."""
        return TenantLimits(
            max_active_jobs=self.settings.max_active_jobs_per_key,
            max_stored_bytes=self.settings.max_stored_bytes_per_key,
            retry_after_s=self.settings.quota_retry_after_s,
        )

    def publish(self, job_id: str) -> bool:
        """Publish a job; on broker trouble leave it for the sweeper (returns False)."""
        try:
            self.queue.publish(job_id)
            return True
        except Exception:
            log.warning("publishing job %s failed; the sweeper will retry", job_id, exc_info=True)
            try:
                self.store.mark_unpublished(job_id)
            except Exception:
                log.warning("could not flag job %s for republishing", job_id, exc_info=True)
            return False

    def ensure_schema(self) -> bool:
        """Create the tables if not done yet; False while the database cannot be reached."""
        if not self.schema_ready:
            try:
                self.store.create_schema()
                self.schema_ready = True
            except Exception as exc:
                log.error("job database unavailable, tables not created yet: %s", exc)
        return self.schema_ready

    def sweep(self) -> list[str]:
        """Requeue jobs of dead workers, republish lost messages, tidy temp files, remove expired data.

        Returns the ids of the jobs published again.
        """
        if not self.ensure_schema():
            return []
        now = time.monotonic()
        if now - self._last_reconcile >= self.settings.broker_reconcile_interval_s:
            self._last_reconcile = now
            self.reconcile_queue()
        published = []
        for job_id in self.store.recover_stale_jobs(requeue_after_s=self.settings.requeue_after_s):
            if self.publish(job_id):
                published.append(job_id)
        if published:
            log.info("sweeper: published %d job(s) again: %s", len(published), ", ".join(published))
        self.remove_abandoned_workdirs()
        self.remove_ended_stream_files()
        _remove_older_than(self.settings.broker_dir / "processed", "*.msg", _CLEANUP_AGE_S)
        self.remove_abandoned_uploads()
        _remove_older_than(
            self.storage.root / "tmp", "job-*", 2 * self.settings.task_hard_time_limit_s + _CLEANUP_AGE_S
        )
        _remove_older_than(self.storage.root / "tmp", "old-*", _CLEANUP_AGE_S)
        now = time.monotonic()
        if now - self._last_cleanup >= self.settings.cleanup_interval_s:
            self._last_cleanup = now
            cleanup(self.store, self.storage, orphan_grace_s=self.settings.orphan_grace_s)
        return published

    def reconcile_queue(self) -> list[str]:
        """Flag for publishing the queued jobs the broker holds no message for, at two reconciliations in
        a row (a Redis restarted without persistence lost them; once only may be a message on its way to
        a worker). Nothing runs twice: a job is claimed by one delivery only. Returns the flagged ids."""
        held = self.queue.held_job_ids()
        if held is None:
            self._unheld = {}
            return []
        before = time.time() - self.settings.broker_reconcile_interval_s
        unheld = {j: at for j, at in self.store.queued_jobs(enqueued_before=before).items() if j not in held}
        lost = [j for j, at in unheld.items() if self._unheld.get(j) == at]
        for job_id in lost:
            self.store.mark_unpublished(job_id)  # the sweep publishes it again now
        self._unheld = {j: at for j, at in unheld.items() if j not in lost}
        if lost:
            log.warning(
                "sweeper: the broker holds no message for %d queued job(s) (it lost them: a restart "
                "without persistence?); publishing them again: %s",
                len(lost),
                ", ".join(lost),
            )
        return lost

    def remove_abandoned_uploads(self) -> int:
        """Remove the uploads a crashed API process left, and those idle longer than a body may stall
        plus a validation may last (``BODY_IDLE_TIMEOUT_S + PROBE_TIMEOUT_S`` and a minute)."""
        s = self.settings
        removed = self.storage.remove_abandoned_uploads(idle_s=s.body_idle_timeout_s + s.probe_timeout_s + 60)
        if removed:
            log.info("removed %d abandoned upload(s) from %s", removed, self.storage.root / "tmp")
        return removed

    def remove_ended_stream_files(self) -> int:
        """Remove what streams that have ended (or are gone) left on disk: their frames being written
        (``tmp/stream-<id>/``, after a worker crashed) and, in embedded mode, their message folders.
        Returns how many were removed."""
        try:
            entries = list(os.scandir(self.storage.root / "tmp"))
        except FileNotFoundError:
            entries = []
        frames = {
            e.name.removeprefix("stream-"): Path(e.path) for e in entries if e.name.startswith("stream-")
        }
        transport = self.stream_transport
        messages = set(transport.stream_ids()) if isinstance(transport, LocalTransport) else set()
        removed = 0
        for stream_id in frames.keys() | messages:
            stream = self.store.find_stream(stream_id)
            if stream is not None and stream.status in STREAM_ACTIVE:
                continue
            if stream_id in frames:
                shutil.rmtree(frames[stream_id], ignore_errors=True)
                removed += 1
            if stream_id in messages:
                transport.cleanup(stream_id)
                removed += 1
        if removed:
            log.info("sweeper: removed %d file set(s) of ended streams", removed)
        return removed

    def remove_abandoned_workdirs(self) -> int:
        """Remove the temporary folders of attempts no worker runs any more (their job is not running:
        requeued after its worker died, failed, cancelled or gone). Returns how many were removed."""
        removed = 0
        for job_id in self.storage.job_workdirs():
            job = self.store.find_job(job_id)
            if job is None or job.status != "running":
                removed += self.storage.remove_job_workdirs(job_id)
        if removed:
            log.info("sweeper: removed %d temporary folder(s) of abandoned attempts", removed)
        return removed

    def _sweep_loop(self) -> None:
        while True:
            try:
                self.sweep()
            except UnavailableError as exc:
                log.warning("sweeper pass skipped: %s", exc.detail)
            except Exception:
                log.warning("sweeper pass failed", exc_info=True)
            if self._stop.wait(self.settings.sweep_interval_s):
                return


def _webhook_view(settings: Settings) -> Any:
    """The job representation a webhook carries: the API's, with absolute links given a public URL."""
    root = (settings.public_url or "").rstrip("/")

    def render(job: JobRecord) -> dict[str, Any]:
        view: dict[str, Any] = job_view(job, root_path=root).model_dump(mode="json")
        return view

    return render
