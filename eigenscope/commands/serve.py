"""``eigenscope serve``: the HTTP API plus analysis workers, one command.

With no ``EIGENSCOPE_REDIS_URL`` nothing else is needed: jobs go through an embedded broker and a SQLite
job store in the data directory. With it set, ``eigenscope serve --no-worker`` runs the API alone and
``eigenscope worker`` processes run anywhere that shares the data directory and the database.

The command supervises its children (uvicorn, a Celery worker): an API process or a worker that dies is
restarted, and SIGINT/SIGTERM stop them all within ``--grace`` seconds. It is the subreaper of their
children, so the orphan of a crashed child is reaped and stopped here too: a stop leaves no process. The
children share one Prometheus multiprocess directory, so ``/metrics`` of any API process
(``--api-workers N``) counts every request and every job of the service.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from typing import TYPE_CHECKING, Any

from backend.logs import console
from eigenscope.cli import UsageError

if TYPE_CHECKING:
    from backend.settings import Settings


def load_settings(**overrides: Any) -> Settings:
    """Settings from the environment with non-None ``overrides``; bad values become a one-line error."""
    from pydantic import ValidationError

    from backend.settings import Settings

    values = {k: v for k, v in overrides.items() if v is not None}
    try:
        return Settings(**values)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(x) for x in first.get("loc", ()))
        name = f"EIGENSCOPE_{where.upper()}" if where else "settings"
        raise UsageError(f"{name}: {first.get('msg')}") from None


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "serve",
        help="run the HTTP API and analysis workers",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000; 0 is not allowed)")
    parser.add_argument(
        "--workers", type=int, default=1, help="analysis worker processes (default 1; each runs one job)"
    )
    parser.add_argument("--api-workers", type=int, default=1, help="uvicorn worker processes (default 1)")
    parser.add_argument("--no-worker", action="store_true", help="run the API only (workers run elsewhere)")
    parser.add_argument(
        "--data-dir", default=None, help="data directory (default EIGENSCOPE_DATA_DIR or ./var)"
    )
    parser.add_argument("--log-level", default=None, help="log level (default EIGENSCOPE_LOG_LEVEL or INFO)")
    parser.add_argument(
        "--grace", type=float, default=10.0, help="seconds children get to stop before they are killed"
    )
    parser.set_defaults(handler=run)


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Ask Linux to SIGTERM this child when the supervisor dies, so no orphan outlives it."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:
        pass


def _become_subreaper() -> None:
    """Ask Linux to make this process the parent of its descendants' orphans (PR_SET_CHILD_SUBREAPER), so
    that a child's child outliving its parent (a crashed API's upload validator) is reaped and stopped
    here rather than by init."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(36, 1)  # PR_SET_CHILD_SUBREAPER
    except Exception:
        pass


def adopted_children(parent: int) -> list[int]:
    """The live processes whose parent is ``parent`` (from ``/proc``)."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", encoding="ascii", errors="replace") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == parent and fields[0] != "Z":
            found.append(int(entry))
    return found


class Supervisor:
    """Starts, watches, restarts and stops the API and worker processes, and reaps every orphan of
    theirs (it is their subreaper): a stop leaves no process behind."""

    def __init__(self, env: dict[str, str], *, grace_s: float) -> None:
        self.env = env
        self.grace_s = grace_s
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.commands: dict[str, list[str]] = {}
        self.restarts: dict[str, list[float]] = {}
        self.stopping = False
        _become_subreaper()

    def start(self, name: str, cmd: list[str]) -> None:
        self.commands[name] = cmd
        self.procs[name] = subprocess.Popen(cmd, env=self.env, preexec_fn=_die_with_parent)

    def request_stop(self, signum: int, _frame: Any) -> None:
        self.stopping = True

    def watch(self, *, restartable: tuple[str, ...]) -> int:
        """Block until a stop is requested or a child that may not be restarted exits (or one keeps dying:
        5 times in a minute); returns the exit status."""
        while not self.stopping:
            for name, proc in list(self.procs.items()):
                code = proc.poll()
                if code is None:
                    continue
                if name not in restartable:
                    console(f"eigenscope serve: {name} exited with status {code}; stopping", level="ERROR")
                    return code or 1
                recent = [t for t in self.restarts.get(name, []) if time.monotonic() - t < 60]
                if len(recent) >= 5:
                    console(f"eigenscope serve: {name} keeps dying (status {code}); stopping", level="ERROR")
                    return code or 1
                console(f"eigenscope serve: {name} exited with status {code}; restarting it", level="WARNING")
                self.restarts[name] = [*recent, time.monotonic()]
                self.start(name, self.commands[name])
            self.reap_orphans()
            time.sleep(0.2)
        return 0

    def reap_orphans(self) -> int:
        """Collect the exit status of adopted orphans that ended (never of the children this supervisor
        started: their ``Popen`` does); returns how many were reaped."""
        ours = {proc.pid for proc in self.procs.values()}
        reaped = 0
        while True:
            try:
                info = os.waitid(os.P_ALL, 0, os.WEXITED | os.WNOHANG | os.WNOWAIT)
            except ChildProcessError:
                return reaped
            if info is None or info.si_pid in ours:
                return reaped
            with contextlib.suppress(ChildProcessError):
                os.waitpid(info.si_pid, 0)
            reaped += 1

    def stop_all(self) -> None:
        """SIGTERM every child, wait ``grace_s``, then SIGKILL the rest; then the same for the orphans of
        theirs that were handed to this supervisor.

        A worker finishes its running job if it can within the grace period; a job it is killed in the
        middle of is taken over on the next start (its lease names a process that no longer exists).
        """
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + self.grace_s
        for proc in self.procs.values():
            try:
                proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
        self._stop_orphans(deadline)

    def _stop_orphans(self, deadline: float) -> None:
        """SIGTERM the adopted orphans (those appearing meanwhile too) until ``deadline`` (a second at
        least), then SIGKILL what is left, and reap them all."""
        end = max(deadline, time.monotonic() + 1.0)
        signalled: set[int] = set()
        while time.monotonic() < end:
            self.reap_orphans()
            orphans = adopted_children(os.getpid())
            if not orphans:
                return
            for pid in set(orphans) - signalled:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGTERM)
                signalled.add(pid)
            time.sleep(0.05)
        for pid in adopted_children(os.getpid()):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.1)
        self.reap_orphans()


def wait_until_up(url: str, proc: subprocess.Popen[bytes], timeout_s: float = 60.0) -> bool:
    """Poll ``url`` until it answers 200, the process dies, or the time runs out."""
    import urllib.request  # here, not at the top: every command imports this module to build its parser

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        try:
            with urllib.request.urlopen(url, timeout=1) as resp:
                if resp.status == 200:
                    return True
        except OSError:
            pass
        time.sleep(0.1)
    return False


def run(args: argparse.Namespace) -> int:
    if not 0 < args.port < 65536:
        raise UsageError(f"--port={args.port} must be between 1 and 65535")
    if args.workers < 1:
        raise UsageError(f"--workers={args.workers} must be at least 1 (use --no-worker for none)")
    if args.api_workers < 1:
        raise UsageError(f"--api-workers={args.api_workers} must be at least 1")
    settings = load_settings(data_dir=args.data_dir, log_level=args.log_level)
    from service.auth import KeyConfigError, KeyRing, write_digest_file

    try:
        ring = KeyRing.from_settings(settings)
    except KeyConfigError as exc:
        raise UsageError(str(exc)) from None
    check_exposure(args.host, settings, keys=ring.enabled)

    from backend.broker import ensure_broker_folders
    from backend.storage import Storage
    from backend.store import Store

    # Prepare the shared state once, before children race for it.
    Storage(settings.data_path).ensure()
    store = Store(settings.effective_database_url)
    try:
        store.create_schema()
    except Exception as exc:
        raise UsageError(f"cannot open the job store {settings.effective_database_url}: {exc}") from exc
    finally:
        store.dispose()
    if settings.embedded:
        ensure_broker_folders(settings)

    # The children get the keys' digests in a private file, never the plain keys in their environment.
    env = {
        k: v for k, v in os.environ.items() if k not in ("EIGENSCOPE_API_KEYS", "EIGENSCOPE_API_KEYS_FILE")
    }
    env.update(settings.child_environment())
    digests = write_digest_file(ring, settings.data_path / "run") if ring.enabled else None
    if digests is not None:
        env["EIGENSCOPE_API_KEYS_FILE"] = str(digests)
    metrics_dir = tempfile.mkdtemp(prefix="eigenscope-metrics-")
    env["PROMETHEUS_MULTIPROC_DIR"] = metrics_dir
    try:
        return _supervise(args, settings, env)
    finally:
        shutil.rmtree(metrics_dir, ignore_errors=True)
        if digests is not None:
            digests.unlink(missing_ok=True)


def _supervise(args: argparse.Namespace, settings: Settings, env: dict[str, str]) -> int:
    level = settings.log_level.lower()
    # Uvicorn's own lines (its banner-like start-up notes) only when debugging; the app logs at `level`.
    server_level = "debug" if level == "debug" else "warning"
    supervisor = Supervisor(env, grace_s=args.grace)
    signal.signal(signal.SIGTERM, supervisor.request_stop)
    signal.signal(signal.SIGINT, supervisor.request_stop)
    api_cmd = [
        sys.executable,
        "-m",
        "uvicorn",
        "--factory",
        "service.app:create_app",
        "--host",
        args.host,
        "--port",
        str(args.port),
        "--log-level",
        server_level,
        "--no-access-log",
        "--timeout-graceful-shutdown",
        str(max(int(args.grace) - 2, 1)),
        *uvicorn_limits(settings),
    ]
    if args.api_workers > 1:
        api_cmd += ["--workers", str(args.api_workers)]
    try:
        supervisor.start("api", api_cmd)
        if not args.no_worker:
            worker_cmd = [sys.executable, "-m", "eigenscope", "worker", "--concurrency", str(args.workers)]
            worker_cmd += ["--loglevel", settings.log_level]
            supervisor.start("worker", worker_cmd)
        host = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
        base = f"http://{host}:{args.port}"
        if wait_until_up(f"{base}/healthz", supervisor.procs["api"]):
            mode = "embedded broker" if settings.embedded else "Redis broker"
            workers = "no worker" if args.no_worker else f"{args.workers} worker(s)"
            console(
                f"eigenscope serving on {base} ({mode}, {workers}, data {settings.data_path}); "
                f"API docs at {base}/docs",
                fmt=settings.log_format,
            )
        return supervisor.watch(restartable=("api", "worker"))
    finally:
        supervisor.stop_all()


def uvicorn_limits(settings: Settings) -> list[str]:
    """Uvicorn's timeouts and limits, chosen rather than left at its defaults (see the settings).

    ``X-Forwarded-For`` and ``X-Forwarded-Proto`` are believed from ``trusted_proxies`` only (none by
    default). Keep-alive connections idle for ``http_timeout_keep_alive_s`` are closed; beyond
    ``http_limit_concurrency`` connections and tasks uvicorn answers 503; ``http_backlog`` pending
    connections wait in the kernel; a request line plus headers larger than ``http_max_header_kb`` is
    refused. WebSocket messages may be ``stream_max_frame_mb + stream_message_margin_mb`` MiB, at most
    ``stream_message_queue`` of them waiting per connection, and are not compressed: a live stream's
    frames are JPEG or PNG already, or raw depth that deflate would cost more CPU to squeeze than the
    stream can spare at 30 fps (the AsyncAPI document says so). Bodies are bounded by the app
    (:mod:`service.bodies`).
    """
    # Forwarded headers only from the configured proxies: uvicorn's default trusts 127.0.0.1, and a
    # client there could name itself anything in X-Forwarded-For (and escape the failed-key throttle).
    proxies = (
        ["--proxy-headers", "--forwarded-allow-ips", settings.trusted_proxies]
        if settings.trusted_proxies
        else ["--no-proxy-headers"]
    )
    return [
        *proxies,
        "--ws-per-message-deflate",
        "false",
        "--timeout-keep-alive",
        str(settings.http_timeout_keep_alive_s),
        "--limit-concurrency",
        str(settings.http_limit_concurrency),
        "--backlog",
        str(settings.http_backlog),
        "--h11-max-incomplete-event-size",
        str(settings.http_max_header_kb * 1024),
        # A stream's frame a little over its limit must reach the app, which answers `frame-too-large`
        # and goes on, rather than be cut by uvicorn's own 16 MiB (a 1009 close).
        "--ws-max-size",
        str(settings.ws_max_message_bytes),
        "--ws-max-queue",
        str(settings.stream_message_queue),
    ]


def is_loopback(host: str) -> bool:
    """True for an address (or ``localhost``) that only this machine reaches."""
    import ipaddress

    if host.strip("[]").lower() in ("localhost", "localhost."):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_exposure(host: str, settings: Settings, *, keys: bool) -> None:
    """Refuse to serve an open API (no keys) on an address other machines reach.

    ``settings.published_host`` is where a container's port is published (it decides when given:
    inside a container the API listens on 0.0.0.0 whatever the host publishes).
    """
    exposed = settings.published_host or host
    if keys or settings.allow_open_api or is_loopback(exposed):
        return
    raise UsageError(
        f"refusing to serve the API on {exposed} without API keys: anyone who reaches it could read and "
        "delete every clip and job. Set EIGENSCOPE_API_KEYS (or EIGENSCOPE_API_KEYS_FILE), listen on "
        "127.0.0.1, or set EIGENSCOPE_ALLOW_OPEN_API=true if a proxy in front authenticates"
    )
