"""A drawing child for a one-shot command: a performance device (issue 18).

A process that analyses one clip and exits (``eigenscope analyze``) would otherwise import matplotlib (a
quarter of a second of interpreter time) while its own analysis runs, holding the interpreter lock against
it, and then draw every figure itself. :meth:`DrawingChild.fork` forks a child as the command starts,
before any thread exists. The child imports matplotlib on the core the analysis leaves idle (start-up,
segmentation, registration are single-threaded), then waits; :meth:`DrawingChild.draw_all` sends it the
analysis (about 2 MB pickled) and the folder, and it draws and writes the images there while the parent
waits. Measured at 640x480x256 on an idle machine (``bench/README.md``), this saves about a seventh of the
command end to end.

Whatever goes wrong with the child (it cannot start, dies, or does not answer within
:data:`REPLY_TIMEOUT_S`) the parent draws the images itself: the device can cost time, never a result.
An error of the drawing itself (an ``OSError`` writing into the folder) reaches the caller as if the
caller had drawn. A worker draws in its own process (:mod:`workers.drawing`); only one-shot commands fork.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import select
import signal
import struct
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis

#: Seconds the parent waits for the child's images before it kills the child and draws them itself.
REPLY_TIMEOUT_S = 60.0

_HEADER = struct.Struct("<Q")
_READY = b"r"


def _read_exactly(fd: int, size: int, deadline: float | None) -> bytes | None:
    """``size`` bytes from ``fd``, or None at end of file or past ``deadline`` (None: no deadline)."""
    chunks, got = [], 0
    while got < size:
        timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
        if not select.select([fd], [], [], timeout)[0]:
            return None
        chunk = os.read(fd, min(size - got, 1 << 20))
        if not chunk:
            return None
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def _send(fd: int, obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(_HEADER.pack(len(data)) + data)
    while view:
        view = view[os.write(fd, view) :]


def _receive(fd: int, deadline: float | None) -> Any:
    header = _read_exactly(fd, _HEADER.size, deadline)
    if header is None:
        raise EOFError
    data = _read_exactly(fd, _HEADER.unpack(header)[0], deadline)
    if data is None:
        raise EOFError
    return pickle.loads(data)


class DrawingChild:
    """The forked child, seen from the parent; see the module docstring.

    Use :meth:`fork` to start one, then :meth:`draw_all` once (the child exits after it), or
    :meth:`close` to end it without drawing.
    """

    def __init__(self, pid: int, to_child: int, from_child: int) -> None:
        self.pid = pid
        self._to_child = to_child
        self._from_child = from_child

    def warm_up(self) -> None:
        """Nothing to do: the child has been importing matplotlib since it was forked."""

    @classmethod
    def fork(cls) -> DrawingChild | None:
        """Fork the child now; None where ``os.fork`` is missing or fails (the caller draws itself).

        Call it before the process starts any thread: a forked child holds only the calling thread.
        """
        if not hasattr(os, "fork"):
            return None
        down_r, down_w = os.pipe()
        up_r, up_w = os.pipe()
        try:
            pid = os.fork()
        except OSError:
            for fd in (down_r, down_w, up_r, up_w):
                os.close(fd)
            return None
        if pid == 0:  # pragma: no cover - the child's code; its effects are tested from the parent
            os.close(down_w)
            os.close(up_r)
            _child_main(down_r, up_w)
        os.close(down_r)
        os.close(up_w)
        return cls(pid, down_w, up_r)

    def draw_all(self, analysis: Analysis, out_dir: str | Path) -> dict[str, str]:
        """Have the child draw and write every image of ``analysis`` into ``out_dir``; the same contract as
        :func:`workers.drawing.draw_all`. Where the child fails, the images are drawn here."""
        from workers.drawing import draw_all

        reply: Any = None
        try:
            # A child that is not ready yet (a loaded machine left it no idle core) is not waited for.
            if _read_exactly(self._from_child, len(_READY), time.monotonic()) == _READY:
                _send(self._to_child, (analysis, str(out_dir)))
                reply = _receive(self._from_child, time.monotonic() + REPLY_TIMEOUT_S)
        except (OSError, EOFError, pickle.PickleError):
            reply = None
        finally:
            self.close()
        if isinstance(reply, tuple) and len(reply) == 2:
            status, value = reply
            if status == "ok":
                return dict(value)
            if status == "error" and isinstance(value, OSError):
                raise value
        return draw_all(analysis, out_dir)

    def close(self) -> None:
        """End the child (idempotent): close the pipes, kill it if it is still running, reap it."""
        for fd in (self._to_child, self._from_child):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._to_child = self._from_child = -1
        if self.pid:
            with contextlib.suppress(OSError):
                if os.waitpid(self.pid, os.WNOHANG)[0] == 0:
                    os.kill(self.pid, signal.SIGKILL)
                    os.waitpid(self.pid, 0)
            self.pid = 0


def _child_main(requests: int, replies: int) -> None:  # pragma: no cover - runs in the forked child
    """The child: import matplotlib, draw the one analysis it is sent, answer, and leave at once."""
    code = 0
    try:
        # The terminal's Ctrl-C is the parent's to handle (it then kills this child); nothing to print.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        null = os.open(os.devnull, os.O_RDWR)
        os.dup2(null, 0)
        os.dup2(null, 1)  # a reader of the parent's output must not wait for this process
        # Only the core time the analysis leaves idle: the parent does not wait for a child not ready.
        with contextlib.suppress(OSError):
            os.nice(19)
        from workers.drawing import draw_all, warm_up

        warm_up().join()
        os.write(replies, _READY)
        try:
            analysis, out_dir = _receive(requests, None)
        except EOFError:  # the parent ended without needing the images
            os._exit(0)
        try:
            reply: tuple[str, Any] = ("ok", draw_all(analysis, out_dir))
        except OSError as exc:
            reply = ("error", exc)
        _send(replies, reply)
    except BaseException:
        code = 1
    finally:
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        os._exit(code)


__all__ = ["REPLY_TIMEOUT_S", "DrawingChild"]
