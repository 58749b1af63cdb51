"""``eigenscope worker``: a Celery worker that runs analysis jobs.

Run any number of these, on any machines that share ``EIGENSCOPE_DATA_DIR`` (clips and artifacts) and
``EIGENSCOPE_DATABASE_URL`` (job store), with ``EIGENSCOPE_REDIS_URL`` pointing at the broker. Without
``EIGENSCOPE_REDIS_URL`` the worker uses the embedded broker in the data directory (this machine only).
"""

from __future__ import annotations

import argparse
import os
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
        "--no-streams",
        action="store_true",
        help="do not run live stream sessions beside the jobs (see `eigenscope stream-worker`)",
    )
    parser.set_defaults(handler=run)


class StreamWorkerChild:
    """An ``eigenscope stream-worker`` process beside the Celery worker, restarted when it dies.

    It is a process of its own (not a thread of the Celery worker, whose pool forks) and dies with this
    one (PR_SET_PDEATHSIG).
    """

    def __init__(self, loglevel: str) -> None:
        import sys
        import threading

        self.cmd = [sys.executable, "-m", "eigenscope", "stream-worker", "--loglevel", loglevel]
        self.stopping = threading.Event()
        self.proc: Any = None
        self._thread = threading.Thread(target=self._watch, name="stream-worker-watch", daemon=True)

    def start(self) -> None:
        self._spawn()
        self._thread.start()

    def _spawn(self) -> None:
        import subprocess

        from eigenscope.commands.serve import _die_with_parent

        self.proc = subprocess.Popen(self.cmd, preexec_fn=_die_with_parent)

    def _watch(self) -> None:
        import sys
        import time

        while not self.stopping.wait(0.5):
            code = self.proc.poll()
            if code is not None and not self.stopping.is_set():
                print(f"eigenscope worker: stream worker exited with {code}; restarting it", file=sys.stderr)
                time.sleep(1.0)
                self._spawn()

    def stop(self) -> None:
        self.stopping.set()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except Exception:
                self.proc.kill()


def celery_worker_argv(args: argparse.Namespace, *, queue: str, embedded: bool, loglevel: str) -> list[str]:
    """The ``celery worker`` arguments for these options."""
    if args.concurrency < 1:
        raise UsageError(f"--concurrency={args.concurrency} must be at least 1")
    argv = [
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
    from service.storage import Storage
    from service.store import Store
    from workers.celery_app import create_celery

    settings = load_settings()
    if settings.background_niceness:
        os.nice(settings.background_niceness)  # an API on the same machine keeps answering promptly
    Storage(settings.data_path).ensure()
    store = Store(settings.effective_database_url)
    store.create_schema()
    store.dispose()
    app = create_celery(settings)
    loglevel = (args.loglevel or settings.log_level).upper()
    streams = None if args.no_streams else StreamWorkerChild(loglevel)
    if streams is not None:
        streams.start()
    try:
        app.worker_main(
            celery_worker_argv(args, queue=settings.queue, embedded=settings.embedded, loglevel=loglevel)
        )
    finally:
        if streams is not None:
            streams.stop()
    return 0
