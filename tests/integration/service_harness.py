"""Start real service processes for tests: ``eigenscope serve``, uvicorn, ``eigenscope worker``.

Every process runs in its own session (process group) and is killed with its children on teardown, so a
failing test leaves no orphans. Local Redis and PostgreSQL are used when reachable; with ``CI=true`` an
unreachable one fails the test instead of skipping it.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

REDIS_URL = os.environ.get("EIGENSCOPE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
POSTGRES_ADMIN_URL = os.environ.get(
    "EIGENSCOPE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/test"
)


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() in ("1", "true", "yes")


def unavailable(what: str, why: str) -> None:
    message = f"{what} is not reachable ({why}); start it or set the EIGENSCOPE_TEST_* URL"
    if in_ci():
        pytest.fail(f"CI requires {message}", pytrace=False)
    pytest.skip(message)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class PortTakenError(RuntimeError):
    """The service's port was bound by another process between :func:`free_port` and the service's own
    bind (other test runs on the machine start servers too): what answers there is not the service."""


def _listening_inodes(port: int) -> set[str]:
    """The inodes of the TCP sockets listening on ``port`` (from /proc/net/tcp and tcp6)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        with contextlib.suppress(OSError):
            for line in Path(table).read_text().splitlines()[1:]:
                fields = line.split()
                if fields[3] == "0A" and int(fields[1].rsplit(":", 1)[1], 16) == port:  # 0A: LISTEN
                    found.add(fields[9])
    return found


def _holds_socket(pid: int, inodes: set[str]) -> bool:
    with contextlib.suppress(OSError):
        for fd in os.listdir(f"/proc/{pid}/fd"):
            with contextlib.suppress(OSError):
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
                if link.startswith("socket:[") and link[8:-1] in inodes:
                    return True
    return False


def on_a_port_of_its_own(start: Callable[[int], LiveService], tries: int = 3) -> LiveService:
    """``start(port)`` on a fresh :func:`free_port` until the service, not another process, listens there."""
    for _ in range(tries - 1):
        with contextlib.suppress(PortTakenError):
            return start(free_port())
    return start(free_port())


def redis_url() -> str:
    """The test Redis URL (DB 15), flushed; skip or fail if unreachable."""
    import redis

    try:
        client = redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2)
        client.flushdb()
        client.close()
    except Exception as exc:
        unavailable(f"Redis at {REDIS_URL}", str(exc))
    return REDIS_URL


@contextlib.contextmanager
def postgres_database() -> Iterator[str]:
    """A fresh PostgreSQL database for one test run, dropped afterwards."""
    import psycopg

    admin = POSTGRES_ADMIN_URL.replace("postgresql+psycopg://", "postgresql://")
    conn = None
    for candidate in (admin, admin.replace("//postgres@", "//root@")):
        try:
            conn = psycopg.connect(candidate, autocommit=True, connect_timeout=3)
            admin = candidate
            break
        except Exception as exc:
            last = exc
    if conn is None:
        unavailable(f"PostgreSQL at {POSTGRES_ADMIN_URL}", str(last))
    assert conn is not None
    name = f"eigenscope_it_{uuid.uuid4().hex[:10]}"
    conn.execute(f'CREATE DATABASE "{name}"')
    base, _, _ = admin.rpartition("/")
    try:
        yield f"{base}/{name}"
    finally:
        with contextlib.suppress(Exception):
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.close()


@dataclass
class Proc:
    """A child process in its own session; ``stop`` kills the whole group."""

    name: str
    popen: subprocess.Popen[bytes]
    log_path: Path

    @classmethod
    def start(cls, name: str, cmd: list[str], *, env: dict[str, str], log_dir: Path) -> Proc:
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{name}.log"
        log = log_path.open("ab")
        popen = subprocess.Popen(
            cmd,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        log.close()
        return cls(name, popen, log_path)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")[-6000:]
        except OSError:
            return ""

    def stop(self, *, grace_s: float = 3.0) -> None:
        """SIGTERM to the group, ``grace_s`` to exit, then SIGKILL to whatever is left (0: at once)."""
        if grace_s > 0:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.popen.pid, signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.popen.wait(timeout=grace_s)
        # Whatever is left in the group (Celery pool children, a stuck server) goes now.
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            self.popen.wait(timeout=10)


def wait_for(predicate: Any, timeout_s: float, what: str, service: LiveService) -> Any:
    """``predicate()``'s first true value, asked every 50 ms for ``timeout_s`` at most (then the
    service's logs in the failure)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}:\n{service.logs()}")


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (children, their children, ...), from ``/proc``."""
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        parents.setdefault(ppid, []).append(int(entry.name))
    found: list[int] = []
    todo = [pid]
    while todo:
        for child in parents.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def cmdline(pid: int) -> str:
    """The command line of ``pid`` ("" once it has gone)."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def descendants_with(root: int, marker: str) -> list[int]:
    """The processes below ``root`` whose command line holds ``marker``."""
    return [pid for pid in descendants(root) if marker in cmdline(pid)]


def find_process(root: int, marker: str, timeout_s: float = 60.0) -> int:
    """The pid of the process below ``root`` whose command line holds ``marker`` (waits for it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for pid in descendants(root):
            if marker in cmdline(pid):
                return pid
        time.sleep(0.1)
    raise AssertionError(f"no process with {marker!r} below {root}")


def proc_status_kib(pid: int, field: str) -> int:
    """A ``/proc/<pid>/status`` figure in KiB (``VmRSS``, ``VmHWM``, ``VmSize``)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def children_of(pid: int) -> list[int]:
    out = subprocess.run(
        ["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True, check=False
    )
    return [int(x) for x in out.stdout.split()]


@dataclass
class LiveService:
    """A running API (+ workers) and an HTTP client for it."""

    base_url: str
    data_dir: Path
    env: dict[str, str]
    procs: list[Proc] = field(default_factory=list)
    client: httpx.Client = field(init=False)

    def __post_init__(self) -> None:
        self.client = httpx.Client(base_url=self.base_url, timeout=60.0)

    def logs(self) -> str:
        return "\n".join(f"--- {p.name} ---\n{p.log()}" for p in self.procs)

    @contextlib.contextmanager
    def logs_on_failure(self, tail: int = 6000) -> Iterator[None]:
        """Any exception raised inside carries the end of every process's log as a note (pytest prints
        it): a failure that depends on what the processes did says so."""
        try:
            yield
        except BaseException as exc:
            exc.add_note(f"service logs (last {tail} characters):\n{self.logs()[-tail:]}")
            raise

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for p in self.procs:
                if not p.alive():
                    raise RuntimeError(f"{p.name} exited with {p.popen.returncode}:\n{self.logs()}")
            try:
                if self.client.get("/readyz", timeout=2).status_code == 200:
                    self.check_listening()
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"service at {self.base_url} not ready after {timeout_s} s:\n{self.logs()}")

    def check_listening(self) -> None:
        """Raise :class:`PortTakenError` unless one of the service's processes (or their children) holds the
        socket listening on its port."""
        inodes = _listening_inodes(int(self.base_url.rsplit(":", 1)[1]))
        family, todo = [], [p.pid for p in self.procs if p.alive()]
        while todo:
            pid = todo.pop()
            family.append(pid)
            todo += children_of(pid)
        if not any(_holds_socket(pid, inodes) for pid in family):
            self.stop()
            raise PortTakenError(f"another process answers on {self.base_url}:\n{self.logs()}")

    def stop(self) -> None:
        """Tear the service down: every process group is killed at once. A graceful stop would take
        1.5-2.5 s per service (Celery's warm shutdown and its pool) for nothing a test reads; the tests
        of shutdown itself signal the processes and check them (test_reliability's SIGTERM test,
        test_faults' restarts)."""
        self.client.close()
        for p in reversed(self.procs):
            p.stop(grace_s=0)

    def upload(self, path: Path) -> httpx.Response:
        with path.open("rb") as fh:
            return self.client.post("/v1/clips", files={"file": (path.name, fh, "application/octet-stream")})

    def wait_job(self, job_id: str, timeout_s: float = 120.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        while True:
            job: dict[str, Any] = self.client.get(f"/v1/jobs/{job_id}").json()
            if job["status"] in ("succeeded", "failed", "cancelled"):
                return job
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"job {job_id} still {job['status']} after {timeout_s} s:\n{self.logs()}"
                )
            time.sleep(0.02)

    def wait_stream(self, stream_id: str, timeout_s: float = 60.0) -> dict[str, Any]:
        """The stream once it has ended (its frames filed as a clip when it succeeded)."""
        deadline = time.monotonic() + timeout_s
        while True:
            stream: dict[str, Any] = self.client.get(f"/v1/streams/{stream_id}").json()
            if stream["status"] in ("succeeded", "failed", "cancelled"):
                return stream
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"stream {stream_id} still {stream['status']} after {timeout_s} s:\n{self.logs()}"
                )
            time.sleep(0.02)


def base_env(data_dir: Path, **settings: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("EIGENSCOPE_")}
    env["EIGENSCOPE_DATA_DIR"] = str(data_dir)
    env["PYTHONUNBUFFERED"] = "1"
    for key, value in settings.items():
        env[f"EIGENSCOPE_{key.upper()}"] = value
    return env


def start_embedded(tmp_path: Path, *, workers: int = 1, api_workers: int = 1, **settings: str) -> LiveService:
    """``eigenscope serve`` with the embedded broker (and the job store given in ``settings``)."""
    return on_a_port_of_its_own(
        lambda port: _start_embedded(tmp_path, port, workers=workers, api_workers=api_workers, **settings)
    )


def _start_embedded(
    tmp_path: Path, port: int, *, workers: int, api_workers: int, **settings: str
) -> LiveService:
    data_dir = tmp_path / "data"
    env = base_env(data_dir, **settings)
    cmd = [sys.executable, "-m", "eigenscope", "serve", "--port", str(port), "--workers", str(workers)]
    cmd += ["--api-workers", str(api_workers)]
    service = LiveService(f"http://127.0.0.1:{port}", data_dir, env)
    service.procs.append(Proc.start("serve", cmd, env=env, log_dir=tmp_path))
    try:
        service.wait_ready()
        # serve's own /healthz probe may still be on its way once /readyz answers the harness: wait for
        # the line serve prints after it, so that request counters hold still from here on.
        _wait_logged(service.procs[0], "eigenscope serving on")
    except BaseException:
        service.stop()
        raise
    return service


def start_split(tmp_path: Path, *, workers: int = 1, **settings: str) -> LiveService:
    """uvicorn and separate ``eigenscope worker`` processes (the Redis deployment)."""
    return on_a_port_of_its_own(lambda port: _start_split(tmp_path, port, workers=workers, **settings))


def _start_split(tmp_path: Path, port: int, *, workers: int, **settings: str) -> LiveService:
    data_dir = tmp_path / "data"
    env = base_env(data_dir, **settings)
    service = LiveService(f"http://127.0.0.1:{port}", data_dir, env)
    api = [sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--port", str(port)]
    try:
        service.procs.append(Proc.start("api", api, env=env, log_dir=tmp_path))
        for i in range(workers):
            cmd = [
                sys.executable,
                "-m",
                "eigenscope",
                "worker",
                "--hostname",
                f"w{i}-{uuid.uuid4().hex[:6]}@%h",
            ]
            service.procs.append(Proc.start(f"worker{i}", cmd, env=env, log_dir=tmp_path))
        service.wait_ready()
        if workers:
            wait_worker_ready(service)
    except BaseException:
        service.stop()
        raise
    return service


def start_api(service: LiveService, *, port: int, name: str = "api") -> Proc:
    """A uvicorn process for ``service`` on ``port``; waits until ``/healthz`` answers (not ``/readyz``:
    fault tests start the API with parts of it unreachable)."""
    cmd = [sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--port", str(port)]
    proc = Proc.start(name, cmd, env=service.env, log_dir=service.data_dir.parent)
    service.procs.append(proc)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if not proc.alive():
            raise RuntimeError(f"{name} exited with {proc.popen.returncode}:\n{proc.log()}")
        try:
            if service.client.get("/healthz", timeout=2).status_code == 200:
                service.check_listening()
                return proc
        except httpx.HTTPError:
            pass
        time.sleep(0.05)
    raise RuntimeError(f"{name} not up after 60 s:\n{proc.log()}")


def start_worker(service: LiveService, name: str) -> Proc:
    """An ``eigenscope worker`` process (one pool process); waits until Celery says it is ready."""
    cmd = [sys.executable, "-m", "eigenscope", "worker", "--hostname", f"{name}-{uuid.uuid4().hex[:6]}@%h"]
    return _start_until_logged(service, name, cmd, " ready.")


def _start_until_logged(service: LiveService, name: str, cmd: list[str], marker: str) -> Proc:
    """Start ``cmd`` as a process of ``service`` and wait (60 s at most) until its log shows ``marker``."""
    proc = Proc.start(name, cmd, env=service.env, log_dir=service.data_dir.parent)
    service.procs.append(proc)
    _wait_logged(proc, marker)
    return proc


def _wait_logged(proc: Proc, marker: str, timeout_s: float = 60.0) -> None:
    """Wait until ``marker`` is anywhere in the process's log (not only its tail)."""
    deadline = time.monotonic() + timeout_s
    while marker not in proc.log_path.read_text(errors="replace"):
        if not proc.alive() or time.monotonic() > deadline:
            raise RuntimeError(f"{proc.name} did not start:\n{proc.log()}")
        time.sleep(0.05)


class RedisServer:
    """A private ``redis-server`` with AOF persistence (fsync on every write) on a free port, or with none
    (``persistent=False``: a restart loses every message, as the machine's shared Redis would).

    The machine's shared Redis runs without persistence and must not be restarted; tests that kill Redis
    start one of these instead. ``kill`` is a SIGKILL (no shutdown save); ``start`` reuses the port and
    the data directory, so the server comes back with what its append-only file holds.
    """

    def __init__(self, workdir: Path, *, persistent: bool = True) -> None:
        self.persistent = persistent
        binary = shutil.which("redis-server")
        if binary is None:
            unavailable("redis-server (the Redis server binary)", "not on PATH")
        assert binary is not None
        self.binary = binary
        self.dir = workdir
        self.dir.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        cmd = [
            self.binary,
            "--port",
            str(self.port),
            "--bind",
            "127.0.0.1",
            "--dir",
            str(self.dir),
            # Without persistence Redis keeps nothing over a restart (its default: no append-only file).
            *(["--appendonly", "yes", "--appendfsync", "always"] if self.persistent else []),
            "--save",
            "",
            "--protected-mode",
            "no",
        ]
        log = (self.dir / "redis.log").open("ab")
        self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        log.close()
        import redis

        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                client = redis.Redis.from_url(self.url, socket_connect_timeout=1)
                client.ping()
                client.close()
                return
            except Exception:
                if self.proc.poll() is not None:
                    break
                time.sleep(0.05)
        raise RuntimeError(f"redis-server on port {self.port} did not start")

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self.proc = None

    def queued(self, queue: str = "eigenscope") -> int:
        """Messages waiting in a Celery queue (not counting those delivered but not yet acknowledged)."""
        import redis

        client = redis.Redis.from_url(self.url, socket_connect_timeout=2)
        try:
            return int(client.llen(queue))
        finally:
            client.close()


def wait_worker_ready(service: LiveService, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if all(" ready." in p.log() for p in service.procs if p.name.startswith("worker")):
            return
        time.sleep(0.1)
    raise RuntimeError(f"workers not ready:\n{service.logs()}")


def synth_clip(out: Path, **options: Any) -> dict[str, Any]:
    """Render a ground-truth clip with ``eigenscope synth``; returns the truth JSON."""
    cmd = [sys.executable, "-m", "eigenscope", "synth", "--out", str(out)]
    for key, value in options.items():
        cmd += [f"--{key.replace('_', '-')}", str(value)]
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    truth: dict[str, Any] = json.loads(out.with_name(out.stem + ".truth.json").read_text())
    return truth


SMALL_CLIP = {"frames": 64, "width": 160, "height": 120, "frequency_hz": 4.0, "mass_kg": 0.5, "force_n": 5.0}


def start_stream_worker(service: LiveService, name: str) -> Proc:
    """An ``eigenscope stream-worker`` process; waits until it says it is ready."""
    return _start_until_logged(service, name, [sys.executable, "-m", "eigenscope", "stream-worker"], "ready:")


def wait_stream_worker(service: LiveService, timeout_s: float = 60.0) -> None:
    """Wait until the stream worker that each ``eigenscope worker`` starts says it is ready."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        workers = [p for p in service.procs if p.name.startswith("worker")]
        if workers and all("stream worker" in p.log() and "ready:" in p.log() for p in workers):
            return
        time.sleep(0.1)
    raise RuntimeError(f"stream workers not ready:\n{service.logs()}")


def wait_stream_worker_logged(service: LiveService, timeout_s: float = 60.0) -> None:
    """Wait until ``eigenscope serve``'s stream worker says it is ready (in the serve log)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if re.search(r"stream worker \d+ ready", service.logs()):
            return
        time.sleep(0.1)
    raise RuntimeError(f"the stream worker is not ready:\n{service.logs()}")
