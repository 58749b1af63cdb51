"""A long-lived Python process that draws part of the figures while the caller draws the others.

matplotlib holds the GIL while it draws, so only a second process can use the second core. A child forked
for every render (:func:`workers.pipeline.render._fork_drawer`) costs little to start but makes both
processes pay copy-on-write faults on every page they touch afterwards, which on an analysing process
(hundreds of megabytes of freed buffers kept for reuse) cost as much as the drawing they share. A process
that lives as long as its parent and shares none of its memory pays that once: it starts (a fresh
interpreter, matplotlib imported) in the background at the first render, and every later render sends
it the analysis through a pipe (a couple of megabytes of pickled arrays) and has it draw and write its
figures while the caller draws the rest.

The process draws every string of text from the text cache, from the first use on, and hands the strings
it rendered back with each reply (:mod:`workers.pipeline._agg`): its figures have the same pixels as the
caller's own once the caller's cache is warm, and the caller's cache learns its strings.

A process that analyses one clip and exits (the command line) starts it *in the background* as it starts:
at the lowest CPU priority, so that it imports matplotlib on whatever core time the analysis leaves idle
(start-up, segmentation, registration) without slowing it, and then has it draw every figure while the
caller writes its other files.

It exits when its parent closes the pipe or dies (the pipe's end of file), and ignores the terminal's
interrupts (its own session, or in the background its own process group). Whatever goes wrong with it
(it dies, hangs, cannot start) the caller draws the figures itself and a new process is started later, at
most :data:`MAX_STARTS` times per process.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import pickle
import select
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis

#: A reply that has not come by then counts as a failure (the process is killed and replaced).
REPLY_TIMEOUT_S = 10.0
#: Processes started per calling process at the most (a process that keeps failing is not restarted).
MAX_STARTS = 3

_HEADER = struct.Struct("<Q")
_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])  # the folder holding the ``workers`` package


class _BrokenError(Exception):
    """The pipe closed, timed out or carried something unexpected."""


def _wait_for(fd: int, events: int, deadline: float) -> bool:
    """Whether ``fd`` is ready for ``events`` by ``deadline`` (a deadline passed still looks once).
    poll, not select: any descriptor number."""
    poller = select.poll()
    poller.register(fd, events)
    return bool(poller.poll(max(0.0, deadline - time.monotonic()) * 1000))


def _write_all(fd: int, data: bytes, deadline: float) -> None:
    view = memoryview(data)
    while view:
        if not _wait_for(fd, select.POLLOUT, deadline):  # poll waited until the deadline
            raise _BrokenError("timed out writing")
        try:
            view = view[os.write(fd, view) :]
        except BlockingIOError:
            continue
        except OSError as exc:  # the process died (broken pipe)
            raise _BrokenError(str(exc)) from exc


def _read_exactly(fd: int, n: int, deadline: float | None) -> bytes:
    chunks: list[bytes] = []
    while n:
        if deadline is not None and not _wait_for(fd, select.POLLIN, deadline):
            raise _BrokenError("timed out reading")
        try:
            chunk = os.read(fd, min(n, 1 << 20))
        except BlockingIOError:
            continue
        except OSError as exc:
            raise _BrokenError(str(exc)) from exc
        if not chunk:
            raise _BrokenError("end of file")
        chunks.append(chunk)
        n -= len(chunk)
    return b"".join(chunks)


def _frame(message: object) -> bytes:
    payload = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    return _HEADER.pack(len(payload)) + payload


def _send(fd: int, message: object, deadline: float) -> None:
    _write_all(fd, _frame(message), deadline)


def _receive(fd: int, deadline: float | None) -> Any:
    (size,) = _HEADER.unpack(_read_exactly(fd, _HEADER.size, deadline))
    return pickle.loads(_read_exactly(fd, size, deadline))


class DrawingProcess:
    """One drawing process and the pipes to it; used by one render at a time (:meth:`claim`)."""

    def __init__(self, *, background: bool = False, text_cache: str | os.PathLike[str] | None = None) -> None:
        """``background``: the process runs only on core time nothing else wants (Linux's ``SCHED_IDLE``),
        for its whole life. ``text_cache``: a file of rendered strings it starts with and keeps up to
        date (see :func:`workers.pipeline._agg.save_cache`)."""
        self._proc = self._spawn(background, None if text_cache is None else os.fspath(text_cache))
        assert self._proc.stdin is not None
        assert self._proc.stdout is not None
        self._to = self._proc.stdin.fileno()
        self._from = self._proc.stdout.fileno()
        os.set_blocking(self._to, False)
        self._owner = os.getpid()
        self._ready = False
        self._busy = threading.Lock()
        self.failed = False

    @staticmethod
    def _spawn(background: bool, text_cache: str | None) -> subprocess.Popen[bytes]:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (_PACKAGE_ROOT, env.get("PYTHONPATH")) if p)
        args = [sys.executable, "-m", "workers.pipeline._drawing_process"]
        if background:
            args.append(_BACKGROUND)
        if text_cache is not None:
            args += [_TEXT_CACHE, text_cache]
        return subprocess.Popen(
            args,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
            close_fds=True,
            # Ctrl-C in a terminal is the parent's to handle (EOF ends this one): the process leads a
            # session of its own, or, in the background, a process group of its own in the parent's
            # session, since a session is also a scheduling group (Linux's autogroups): in one of its own
            # the process would take half the CPU from the parent whatever its priority.
            start_new_session=not background,
            process_group=0 if background else None,
        )

    @property
    def pid(self) -> int:
        return self._proc.pid

    def claim(self) -> bool:
        """Take the process for one render: False while it is starting, drawing for another thread, or
        broken. A True is followed by :meth:`submit` and :meth:`collect`, or :meth:`release`."""
        if self.failed or not self._busy.acquire(blocking=False):
            return False
        with self._failing_on_error(release=True):
            if not self._ready:
                if not _wait_for(self._from, select.POLLIN, 0.0):
                    self._busy.release()  # still starting
                    return False
                if _receive(self._from, time.monotonic() + REPLY_TIMEOUT_S) != ("ready",):
                    raise _BrokenError("no ready message")
                self._ready = True
            return True
        return False

    def submit(self, analysis: Analysis, out: Path, keys: tuple[str, ...]) -> bool:
        """Send the process the figures ``keys`` of ``analysis`` to draw into ``out`` (after :meth:`claim`);
        False (and the claim given back) when it could not be sent."""
        try:
            payload = _frame(("draw", analysis, str(out), keys))
        except (pickle.PicklingError, TypeError, AttributeError):
            self._busy.release()  # nothing was sent: the process is still in step
            return False
        with self._failing_on_error(release=True):
            _write_all(self._to, payload, time.monotonic() + REPLY_TIMEOUT_S)
            return True
        return False

    def collect(self) -> tuple[bool, Any]:
        """Wait for the submitted figures: (whether they were all written, the text cache's additions for
        :func:`workers.pipeline._agg.add_strings`). Gives the claim back."""
        with self._failing_on_error(release=False):
            try:
                reply = _receive(self._from, time.monotonic() + REPLY_TIMEOUT_S)
            finally:
                self._busy.release()
            if not (isinstance(reply, tuple) and len(reply) == 3 and reply[0] == "done"):
                raise _BrokenError(f"unexpected reply {type(reply).__name__}")
            _, error, added = reply
            return error is None, added
        return False, None

    @contextlib.contextmanager
    def _failing_on_error(self, *, release: bool) -> Iterator[None]:
        """End the process on any error inside (it may be out of step with this side of the pipe: an
        exception raised into the caller, a time limit say, still propagates), giving back the claim
        when ``release``; a broken pipe or a garbled message is swallowed (the caller then sees the
        method's failure value)."""
        try:
            yield
        except BaseException as exc:
            self._fail()
            if release:
                self._busy.release()
            if not isinstance(exc, _BrokenError | pickle.UnpicklingError | ValueError | EOFError):
                raise

    def release(self) -> None:
        """Give back a claim that will not be used."""
        self._busy.release()

    def _fail(self) -> None:
        self.failed = True
        self.close(kill=True)

    def close(self, *, kill: bool = False) -> None:
        """End the process: closing its pipe ends it; ``kill`` does not wait for that."""
        if os.getpid() != self._owner:
            return
        self.forget()
        if kill and self._proc.poll() is None:
            self._proc.kill()
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - it ignores the closed pipe
            self._proc.kill()
            self._proc.wait()

    def forget(self) -> None:
        """Close this side's ends of the pipes (which ends the process once no other copy is open); alone,
        in a forked child: drop the parent's pipes without touching the parent's process."""
        for stream in (self._proc.stdin, self._proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()


_SHARED: DrawingProcess | None = None
_STARTS = 0
_SHARED_LOCK = threading.Lock()
#: How this process's drawing process is started (and started again after a failure): see start_shared.
_OPTIONS: dict[str, Any] = {}
#: Command-line arguments of the process (see :class:`DrawingProcess`).
_BACKGROUND = "--background"
_TEXT_CACHE = "--text-cache"


def claim_shared() -> DrawingProcess | None:
    """This process's drawing process, claimed for one render; None while it starts (the first call
    starts it), while another thread's render uses it, or when it cannot be had."""
    global _SHARED, _STARTS
    with _SHARED_LOCK:
        if _SHARED is not None and _SHARED.failed:
            _SHARED = None
        if _SHARED is None:
            if _STARTS >= MAX_STARTS:
                return None
            _STARTS += 1
            try:
                _SHARED = DrawingProcess(**_OPTIONS)
            except OSError:
                return None
            return None  # it is starting: this render draws everything itself
        helper = _SHARED
    return helper if helper.claim() else None


def claim_shared_waiting(wait_s: float) -> DrawingProcess | None:
    """:func:`claim_shared`, waiting up to ``wait_s`` seconds for the process to be ready (or free)."""
    deadline = time.monotonic() + wait_s
    claimed = claim_shared()
    while claimed is None and time.monotonic() < deadline:
        if _SHARED is None and _STARTS >= MAX_STARTS:
            return None  # none runs, and none will be started again
        time.sleep(0.005)
        claimed = claim_shared()
    return claimed


def start_shared(
    wait_s: float = 0.0,
    *,
    background: bool = False,
    text_cache: str | os.PathLike[str] | None = None,
) -> bool:
    """Start this process's drawing process unless it runs; whether it is ready to draw (waiting up to
    ``wait_s`` seconds for it to start). ``background`` and ``text_cache`` (see :class:`DrawingProcess`)
    apply to this process's drawing processes from the next one started."""
    _OPTIONS.update(background=background, text_cache=text_cache)
    claimed = claim_shared_waiting(wait_s)
    if claimed is None:
        return False
    claimed.release()
    return True


def _close_shared() -> None:
    if _SHARED is not None:
        _SHARED.close()


def _after_fork_in_child() -> None:
    global _SHARED, _STARTS
    if _SHARED is not None:
        _SHARED.forget()
    _SHARED, _STARTS = None, 0


atexit.register(_close_shared)
os.register_at_fork(after_in_child=_after_fork_in_child)


def _serve(request_fd: int, reply_fd: int, background: bool, text_cache: str | None) -> None:
    """The drawing process: draw what each message asks until the pipe closes or the parent dies."""
    parent = os.getppid()
    if background:
        with contextlib.suppress(OSError, AttributeError):
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))

    # Held from a reply until the text cache it may have grown is saved: a parent that exits as soon as it
    # has its reply (``eigenscope analyze``) must not end this process halfway through the save.
    saving = threading.Lock()

    def watch_parent() -> None:  # a parent killed while this process starts cannot close the pipe yet
        while os.getppid() == parent:
            time.sleep(0.1)
        with saving:
            os._exit(0)

    threading.Thread(target=watch_parent, name="parent-watch", daemon=True).start()
    from workers.pipeline import _agg, render

    _agg.cache_at_first_use()
    render.warm_up().join()
    # What every request needs, loaded before this process says it is ready rather than at its first
    # request: the classes the analysis unpickles into (the whole pipeline, OpenCV included) and the PNG
    # encoder.
    import cv2
    import numpy as np

    import workers.pipeline.analysis  # noqa: F401

    cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))
    if text_cache is not None:
        _agg.load_cache(text_cache)
    mark = saved = _agg.cache_mark()
    try:
        _send(reply_fd, ("ready",), time.monotonic() + REPLY_TIMEOUT_S)
    except _BrokenError:
        return  # the parent gave up on this process while it started
    while True:
        try:
            message = _receive(request_fd, None)
        except _BrokenError:
            return  # the parent closed the pipe or died
        _, analysis, out, keys = message
        error = None
        try:
            render._draw_and_write_all(analysis, Path(out), keys)
        except Exception as exc:  # reported to the parent, which draws the figures itself
            error = f"{type(exc).__name__}: {exc}"
        added = _agg.strings_added_since(mark)
        mark = _agg.cache_mark()
        with saving:
            try:
                _send(reply_fd, ("done", error, added), time.monotonic() + REPLY_TIMEOUT_S)
            except _BrokenError:
                return
            finally:  # after the reply, which the parent may be waiting for (and then exit)
                if text_cache is not None and mark != saved:
                    _agg.save_cache(text_cache)
                    saved = mark


def _main(argv: list[str]) -> None:
    """A drawing process started afresh: requests on stdin, replies on stdout (which the protocol has to
    itself: anything printed goes to stderr)."""
    text_cache = argv[argv.index(_TEXT_CACHE) + 1] if _TEXT_CACHE in argv else None
    reply_fd = os.dup(1)
    os.dup2(2, 1)
    _serve(0, reply_fd, _BACKGROUND in argv, text_cache)


if __name__ == "__main__":
    _main(sys.argv[1:])
