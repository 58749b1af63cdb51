"""The one-shot command's drawing child (``workers.drawing_child``, a performance device): its images are
the ones this process would draw, byte for byte, whatever becomes of the child; a write error reaches the
caller; the child never outlives its use."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from tests.unit.render.conftest import Analysed
from workers.drawing import draw_all
from workers.drawing_child import DrawingChild

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork (POSIX)")


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def _reaped(pid: int) -> bool:
    try:
        os.waitpid(pid, os.WNOHANG)
    except ChildProcessError:
        return True
    return False


def _wait_ready(child: DrawingChild, timeout_s: float = 60.0) -> None:
    """Give the child time to import matplotlib (on a loaded machine it is not waited for otherwise)."""
    import select

    assert select.select([child._from_child], [], [], timeout_s)[0], "the child never got ready"


def test_the_child_draws_what_this_process_draws_and_is_gone_after(small: Analysed, tmp_path: Path):
    expected = draw_all(small.analysis, tmp_path / "here")
    child = DrawingChild.fork()
    assert child is not None
    pid = child.pid
    _wait_ready(child)
    got = child.draw_all(small.analysis, tmp_path / "child")
    assert got == expected
    assert _files(tmp_path / "child") == _files(tmp_path / "here")
    assert _reaped(pid)


def test_a_child_that_died_leaves_the_drawing_to_this_process(small: Analysed, tmp_path: Path):
    expected = draw_all(small.analysis, tmp_path / "here")
    child = DrawingChild.fork()
    assert child is not None
    os.kill(child.pid, signal.SIGKILL)
    time.sleep(0.05)
    assert child.draw_all(small.analysis, tmp_path / "fallback") == expected
    assert _files(tmp_path / "fallback") == _files(tmp_path / "here")


def test_a_write_error_reaches_the_caller(small: Analysed, tmp_path: Path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    child = DrawingChild.fork()
    assert child is not None
    _wait_ready(child)
    with pytest.raises(FileExistsError):  # as when this process draws (test_images)
        child.draw_all(small.analysis, blocker)
    assert blocker.read_text() == "not a folder"


def test_closing_without_drawing_ends_the_child():
    child = DrawingChild.fork()
    assert child is not None
    pid = child.pid
    child.close()
    child.close()  # idempotent
    assert _reaped(pid)
