"""``eigenscope stream-worker``: run live stream sessions (``/v1/streams``) on this machine.

``eigenscope worker`` starts one of these beside its analysis worker (and restarts it if it dies), so
nothing else is needed; run more of them to serve more streams at once. Each takes sessions from the
stream transport (Redis with ``EIGENSCOPE_REDIS_URL``, else the data directory) and runs up to
``EIGENSCOPE_STREAM_SESSIONS_PER_WORKER`` of them at a time.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from typing import Any, NoReturn


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "stream-worker",
        help="run live stream sessions (started by `eigenscope worker`)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--sessions", type=int, default=None, help="streams run at once (default from settings)"
    )
    parser.add_argument("--loglevel", default=None, help="log level (default EIGENSCOPE_LOG_LEVEL or INFO)")
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from backend.logs import configure_logging
    from backend.store import Store
    from eigenscope.cli import UsageError
    from eigenscope.commands.serve import load_settings
    from workers.streams import run_stream_worker

    if args.sessions is not None and args.sessions < 1:
        raise UsageError(f"--sessions={args.sessions} must be at least 1")
    settings = load_settings(stream_sessions_per_worker=args.sessions)
    # Lines as every other process writes them (EIGENSCOPE_LOG_FORMAT: text or one JSON object each).
    configure_logging((args.loglevel or settings.log_level).upper(), settings.log_format)
    if settings.background_niceness:
        os.nice(settings.background_niceness)
    store = Store(settings.effective_database_url)
    store.create_schema()
    store.dispose()
    stop = threading.Event()

    def request_stop(_signum: int, _frame: Any) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)
    try:
        run_stream_worker(settings, stop=stop)
    except Exception:
        logging.getLogger(__name__).exception("the stream worker failed")
        _leave(1)
    _leave(0)


def _leave(code: int) -> NoReturn:
    """Exit now: a thread of an interrupted session (a clip writer's pool, the flow) must not keep the
    process alive past its stop."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
