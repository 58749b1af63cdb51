"""``eigenscope worker``: a Celery worker that runs analysis jobs.

Run any number of these, on any machines that share ``EIGENSCOPE_DATA_DIR`` (clips and artifacts) and
``EIGENSCOPE_DATABASE_URL`` (job store), with ``EIGENSCOPE_REDIS_URL`` pointing at the broker. Without
``EIGENSCOPE_REDIS_URL`` the worker uses the embedded broker in the data directory (this machine only).

With ``--metrics-port`` (or ``EIGENSCOPE_WORKER_METRICS_PORT``) the worker serves its own Prometheus
metrics there. Its log lines follow ``EIGENSCOPE_LOG_FORMAT`` and carry the id of the job they are about;
Celery's banner and its warnings about running as root are not shown (``--log-level DEBUG`` shows them).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
from typing import Any

from eigenscope.cli import UsageError


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "worker",
        help="run a worker that executes analysis jobs",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "-c", "--concurrency", type=int, default=1, help="analyses run in parallel (processes; default 1)"
    )
    parser.add_argument("--pool", choices=("prefork", "solo"), default="prefork", help="Celery pool")
    parser.add_argument("--hostname", default=None, help="Celery node name (default: worker@<host>)")
    parser.add_argument("--loglevel", default=None, help="log level (default EIGENSCOPE_LOG_LEVEL or INFO)")
    parser.add_argument(
        "--metrics-port",
        type=int,
        default=None,
        help="serve this worker's Prometheus /metrics on this port (default EIGENSCOPE_WORKER_METRICS_PORT; "
        "0 or unset: none)",
    )
    parser.add_argument(
        "--no-streams",
        action="store_true",
        help="do not run live stream sessions beside the jobs (see `eigenscope stream-worker`)",
    )
    parser.set_defaults(handler=run)


class StreamWorkerChild:
    """An ``eigenscope stream-worker`` process beside the Celery worker, restarted when it dies.

    It is a process of its own (not a thread of the Celery worker, whose pool forks) and dies with this
    one (PR_SET_PDEATHSIG). :meth:`stop` stops for good: no respawn once it has begun (the watcher checks
    under the same lock), the watcher joined, the child ended within ``grace_s`` (killed after).
    """

    def __init__(self, loglevel: str, *, grace_s: float = 8.0) -> None:
        import sys
        import threading

        self.cmd = [sys.executable, "-m", "eigenscope", "stream-worker", "--loglevel", loglevel]
        self.grace_s = grace_s
        self.stopping = threading.Event()
        self.proc: Any = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._watch, name="stream-worker-watch", daemon=True)

    def start(self) -> None:
        with self._lock:
            self._spawn()
        self._thread.start()

    def _spawn(self) -> None:
        """Start the child (the lock held, and not stopping)."""
        import subprocess

        from eigenscope.commands.serve import _die_with_parent

        self.proc = subprocess.Popen(self.cmd, preexec_fn=_die_with_parent)

    def _watch(self) -> None:
        from backend.logs import console

        while not self.stopping.wait(0.5):
            code = self.proc.poll()
            if code is None:
                continue
            console(f"eigenscope worker: stream worker exited with {code}; restarting it", level="WARNING")
            if self.stopping.wait(1.0):
                return
            with self._lock:
                if self.stopping.is_set():
                    return
                self._spawn()

    def begin_stop(self) -> None:
        """Stop respawning and ask the child to stop (SIGTERM), without waiting: as the Celery worker
        begins its own shutdown, so that both stop at once."""
        with self._lock:
            self.stopping.set()
            proc = self.proc
        if proc is not None and proc.poll() is None:
            proc.terminate()

    def stop(self) -> None:
        self.begin_stop()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        proc = self.proc
        if proc is not None and proc.poll() is None:
            try:
                proc.wait(timeout=self.grace_s)
            except Exception:
                proc.kill()
                proc.wait(timeout=5)


def celery_worker_argv(args: argparse.Namespace, *, queue: str, embedded: bool, loglevel: str) -> list[str]:
    """The ``celery worker`` arguments for these options."""
    if args.concurrency < 1:
        raise UsageError(f"--concurrency={args.concurrency} must be at least 1")
    argv = [
        *([] if loglevel == "DEBUG" else ["--quiet"]),  # the banner, unless debugging
        "worker",
        f"--concurrency={args.concurrency}",
        f"--pool={args.pool}",
        f"--loglevel={loglevel}",
        f"--queues={queue}",
    ]
    if args.hostname:
        argv.append(f"--hostname={args.hostname}")
    if embedded:
        # The embedded broker has no fanout worth polling: no gossip, mingle or broadcast heartbeats.
        argv += ["--without-gossip", "--without-mingle", "--without-heartbeat"]
    return argv


def run(args: argparse.Namespace) -> int:
    from eigenscope.commands.serve import load_settings

    settings = load_settings()
    port = args.metrics_port if args.metrics_port is not None else settings.worker_metrics_port
    own_metrics_dir = None
    if port and not os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        # Before prometheus_client is imported: the pool processes write their metrics here.
        own_metrics_dir = tempfile.mkdtemp(prefix="eigenscope-worker-metrics-")
        os.environ["PROMETHEUS_MULTIPROC_DIR"] = own_metrics_dir
    try:
        return _run_worker(args, settings, port)
    finally:
        if own_metrics_dir is not None:
            shutil.rmtree(own_metrics_dir, ignore_errors=True)


def _celery_says_through_logging() -> None:
    """Celery prints some messages itself ("worker: Warm shutdown (MainProcess)"): log them instead, so
    that in JSON mode every line is JSON."""
    import logging

    import celery.apps.worker as celery_worker

    say = logging.getLogger("celery.worker")
    celery_worker.safe_say = lambda msg, f=None: say.info("%s", msg)


def _run_worker(args: argparse.Namespace, settings: Any, port: int | None) -> int:
    from celery import signals

    from backend.logs import configure_logging
    from backend.storage import Storage
    from backend.store import Store
    from workers.celery_app import create_celery
    from workers.metrics import process_stopped, serve_metrics

    if settings.background_niceness:
        os.nice(settings.background_niceness)  # an API on the same machine keeps answering promptly
    loglevel = (args.loglevel or settings.log_level).upper()
    configure_logging(loglevel, settings.log_format)
    _celery_says_through_logging()
    Storage(settings.data_path).ensure()
    store = Store(settings.effective_database_url)
    store.create_schema()
    store.dispose()
    app = create_celery(settings)
    # Celery leaves the logging as configured above; every pool process counts itself alive.
    signals.setup_logging.connect(lambda **_: configure_logging(loglevel, settings.log_format), weak=False)
    signals.worker_process_init.connect(lambda **_: app.context().metrics.process_started(), weak=False)
    signals.worker_process_shutdown.connect(lambda **_: process_stopped(), weak=False)
    if args.pool == "solo":
        signals.worker_ready.connect(lambda **_: app.context().metrics.process_started(), weak=False)
    if port:
        serve_metrics(port)
    streams = None if args.no_streams else StreamWorkerChild(loglevel)
    if streams is not None:
        streams.start()
        signals.worker_shutting_down.connect(lambda **_: streams.begin_stop(), weak=False)
    try:
        app.worker_main(
            celery_worker_argv(args, queue=settings.queue, embedded=settings.embedded, loglevel=loglevel)
        )
    finally:
        if streams is not None:
            streams.stop()
    return 0
