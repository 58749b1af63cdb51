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
    parser.set_defaults(handler=run)


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
    app.worker_main(
        celery_worker_argv(args, queue=settings.queue, embedded=settings.embedded, loglevel=loglevel)
    )
    return 0
