"""The long-lived drawing process draws the displacement and ring-down figures (or, started in the
background for the command line, every figure) with the pixels this process would give them; whatever
happens to it (it dies, hangs, or its parent dies), every image is written and nothing is left running."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from collections import OrderedDict
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.unit.render.conftest import Analysed
from workers.pipeline import _agg, _drawing_process, render

ROOT = Path(__file__).resolve().parents[3]


def _images(folder: Path) -> dict[str, np.ndarray]:
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(folder.glob("*.png"))}


def _assert_same_images(got: Path, expected: Path) -> None:
    a, b = _images(got), _images(expected)
    assert sorted(a) == sorted(b)
    assert len(a) == 6
    for name, image in b.items():
        assert np.array_equal(a[name], image), name
    assert not list(got.glob(".*")), "no temporary files left behind"


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/status").read_text().split("State:")[1].split("\n")[0]
    except (OSError, IndexError):
        return True
    return "zombie" in state


def _break(victim: _drawing_process.DrawingProcess, fault: str) -> None:
    """``killed``: the process dies; ``stopped``: it no longer reads or answers."""
    if fault == "killed":
        os.kill(victim.pid, signal.SIGKILL)
        victim._proc.wait()
    else:
        os.kill(victim.pid, signal.SIGSTOP)


@pytest.fixture
def fresh(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """A drawing process of the test's own (this process's shared one is put back afterwards)."""
    monkeypatch.setattr(_drawing_process, "_SHARED", None)
    monkeypatch.setattr(_drawing_process, "_STARTS", 0)
    yield
    made = _drawing_process._SHARED
    if made is not None:
        made.close(kill=True)


@pytest.fixture
def reference(one_object: Analysed, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every image drawn in this process alone, from a warm text cache."""
    out = tmp_path_factory.mktemp("reference")
    for i in range(2):  # strings are drawn from the cache from their second use on
        render.render_all(one_object.analysis, out / f"warm-up-{i}", drawing_process=False)
    original = render._draw_elsewhere
    render._draw_elsewhere = lambda *args, **kwargs: None  # type: ignore[assignment]
    try:
        render.render_all(one_object.analysis, out / "here")
    finally:
        render._draw_elsewhere = original
    return out / "here"


def _spy_collect(monkeypatch: pytest.MonkeyPatch) -> list[bool]:
    results: list[bool] = []
    original = _drawing_process.DrawingProcess.collect

    def spy(self: _drawing_process.DrawingProcess) -> tuple[bool, object]:
        ok, added = original(self)
        results.append(ok)
        return ok, added

    monkeypatch.setattr(_drawing_process.DrawingProcess, "collect", spy)
    return results


def _assert_replaced(
    victim: _drawing_process.DrawingProcess,
    one_object: Analysed,
    reference: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The render after a broken process starts a new one, which then draws the right pixels."""
    render.render_all(one_object.analysis, tmp_path / "next")
    assert render.start_drawing_process(wait_s=60.0)
    assert _drawing_process._SHARED is not victim
    served = _spy_collect(monkeypatch)
    render.render_all(one_object.analysis, tmp_path / "again")
    assert served == [True]
    _assert_same_images(tmp_path / "again", reference)


def test_it_draws_the_pixels_this_process_draws(
    one_object: Analysed, reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    assert render.start_drawing_process(wait_s=60.0)
    served = _spy_collect(monkeypatch)
    for i in range(2):  # its first figures (strings it rasterises anew) and later ones
        render.render_all(one_object.analysis, tmp_path / f"there-{i}")
        _assert_same_images(tmp_path / f"there-{i}", reference)
    assert served == [True, True], "the drawing process did not draw the figures"


def test_the_first_render_starts_it_and_a_later_one_uses_it(
    fresh: None, one_object: Analysed, reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    served = _spy_collect(monkeypatch)
    render.render_all(one_object.analysis, tmp_path / "first")
    assert served == [], "the process cannot be ready at the first render"
    assert _drawing_process._SHARED is not None
    _assert_same_images(tmp_path / "first", reference)
    assert render.start_drawing_process(wait_s=60.0)
    render.render_all(one_object.analysis, tmp_path / "second")
    assert served == [True]
    _assert_same_images(tmp_path / "second", reference)


def test_strings_it_rendered_are_cached_here(
    fresh: None, one_object: Analysed, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    for cache in (_agg._BITMAPS, _agg._METRICS):  # start cold: earlier tests drew the same strings
        monkeypatch.setattr(cache, "_items", OrderedDict())
    assert render.start_drawing_process(wait_s=60.0)
    mark = _agg.cache_mark()
    render.render_all(one_object.analysis, tmp_path / "out")
    added = {key[0]: value for key, value in _agg._BITMAPS.added_since(mark[1])}
    releases = [s for s in added if s.startswith("release ")]
    assert releases, sorted(added)  # drawn only in the displacement figure, by the drawing process
    assert all(added[s] != _agg._SEEN_ONCE for s in releases), "it hands back rasterised strings"


@pytest.mark.parametrize("fault", ["killed", "stopped"])
def test_a_process_that_dies_or_hangs_costs_no_image(
    fault: str,
    fresh: None,
    one_object: Analysed,
    reference: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
):
    monkeypatch.setattr(_drawing_process, "REPLY_TIMEOUT_S", 1.0)
    assert render.start_drawing_process(wait_s=60.0)
    victim = _drawing_process._SHARED
    assert victim is not None
    _break(victim, fault)
    started = time.perf_counter()
    names = render.render_all(one_object.analysis, tmp_path / "out")
    elapsed = time.perf_counter() - started
    assert set(names) == {"mask", "overlay", "frequency_map", "spectrum", "displacement", "ringdown"}
    _assert_same_images(tmp_path / "out", reference)
    assert victim.failed
    assert _gone(victim.pid), "the broken process is ended"
    assert elapsed < 5.0, f"rendering took {elapsed:.1f} s"
    _assert_replaced(victim, one_object, reference, tmp_path, monkeypatch)


def test_an_error_raised_while_it_draws_ends_it(
    fresh: None, one_object: Analysed, reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    """An exception raised into the caller while it waits for the reply (a task's time limit, say) ends
    the process: its late reply must never be taken for the next render's."""

    class TimeLimitError(Exception):
        pass

    assert render.start_drawing_process(wait_s=60.0)
    victim = _drawing_process._SHARED
    assert victim is not None
    original = _drawing_process._receive

    def interrupted(fd: int, deadline: float | None) -> object:
        raise TimeLimitError

    monkeypatch.setattr(_drawing_process, "_receive", interrupted)
    with pytest.raises(TimeLimitError):
        render.render_all(one_object.analysis, tmp_path / "cut")
    monkeypatch.setattr(_drawing_process, "_receive", original)
    assert victim.failed
    assert _gone(victim.pid)
    _assert_replaced(victim, one_object, reference, tmp_path, monkeypatch)


def test_an_analysis_that_cannot_be_sent_is_drawn_here_and_the_process_kept(
    fresh: None, one_object: Analysed, reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    assert render.start_drawing_process(wait_s=60.0)
    kept = _drawing_process._SHARED
    assert kept is not None

    def unpicklable(message: object) -> bytes:
        raise pickle.PicklingError("a field that does not pickle")

    original = _drawing_process._frame
    monkeypatch.setattr(_drawing_process, "_frame", unpicklable)
    render.render_all(one_object.analysis, tmp_path / "here")
    _assert_same_images(tmp_path / "here", reference)
    monkeypatch.setattr(_drawing_process, "_frame", original)
    assert not kept.failed, "nothing was sent: the process is still in step"
    served = _spy_collect(monkeypatch)
    render.render_all(one_object.analysis, tmp_path / "there")
    assert served == [True]
    assert _drawing_process._SHARED is kept


def test_a_process_that_keeps_failing_is_not_started_again(fresh: None, monkeypatch: pytest.MonkeyPatch):
    for _ in range(_drawing_process.MAX_STARTS):
        assert _drawing_process.claim_shared() is None  # starts one
        made = _drawing_process._SHARED
        assert made is not None
        made._fail()
    assert _drawing_process.claim_shared() is None
    assert _drawing_process._SHARED is None, "no process is started past MAX_STARTS"


@pytest.mark.parametrize("when", ["starting", "ready"])
def test_it_ends_with_its_parent(when: str):
    """A parent killed without a word (SIGKILL) leaves no drawing process behind, even one that was
    still importing matplotlib and so not yet reading its pipe."""
    wait = "60.0" if when == "ready" else "0.0"
    script = (
        "import eigenscope, time\n"
        "from workers.pipeline import _drawing_process, render\n"
        f"ready = render.start_drawing_process(wait_s={wait})\n"
        "print(_drawing_process._SHARED.pid, ready, flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert parent.stdout is not None
        pid_text, ready = parent.stdout.readline().split()
        assert ready == ("True" if when == "ready" else "False")
        pid = int(pid_text)
        assert not _gone(pid)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 3.0  # it checks for its parent ten times a second
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid), "the drawing process outlived its parent"


def test_in_the_background_it_runs_on_idle_time_in_the_callers_session(fresh: None):
    """SCHED_IDLE, and in this session (a session is a scheduling group: in one of its own, it would
    take half the CPU from this process whatever its priority) but its own process group (Ctrl-C in a
    terminal is the caller's)."""
    assert render.start_drawing_process(wait_s=60.0, background=True)
    made = _drawing_process._SHARED
    assert made is not None
    assert os.sched_getscheduler(made.pid) == os.SCHED_IDLE
    assert os.getsid(made.pid) == os.getsid(0)
    assert os.getpgid(made.pid) == made.pid != os.getpgid(0)


def test_everything_elsewhere_draws_every_figure_with_this_processs_pixels(
    fresh: None, one_object: Analysed, reference: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    cache = tmp_path / "cache" / "text.pickle"
    assert render.start_drawing_process(wait_s=60.0, background=True, text_cache=cache)
    served = _spy_collect(monkeypatch)
    drawn_here: list[str] = []
    original = dict(render._DRAWERS)
    for key, draw in original.items():
        monkeypatch.setitem(
            render._DRAWERS, key, lambda a, key=key, draw=draw: drawn_here.append(key) or draw(a)
        )
    for i in range(2):
        names = render.render_all(one_object.analysis, tmp_path / f"out-{i}", everything_elsewhere=True)
        assert set(names) == {"mask", "overlay", "frequency_map", "spectrum", "displacement", "ringdown"}
        _assert_same_images(tmp_path / f"out-{i}", reference)
    assert served == [True, True]
    assert drawn_here == [], "no figure is drawn in this process"
    # The strings of every figure were saved for the next process.
    deadline = time.monotonic() + 10.0
    while not cache.is_file() and time.monotonic() < deadline:
        time.sleep(0.02)
    saved = {key[0] for key, _ in pickle.loads(cache.read_bytes())["bitmaps"]}
    assert any(s.startswith("release ") for s in saved), "the displacement figure's strings"
    assert any("Hz" in s for s in saved), "the spectrum's strings"


@pytest.mark.parametrize("fault", ["killed", "stopped"])
def test_everything_elsewhere_without_a_working_process_draws_here(
    fault: str,
    fresh: None,
    one_object: Analysed,
    reference: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
):
    monkeypatch.setattr(_drawing_process, "REPLY_TIMEOUT_S", 1.0)
    monkeypatch.setattr(_drawing_process, "MAX_STARTS", 1)  # no second process to fall back on
    assert render.start_drawing_process(wait_s=60.0, background=True)
    victim = _drawing_process._SHARED
    assert victim is not None
    _break(victim, fault)
    started = time.perf_counter()
    render.render_all(one_object.analysis, tmp_path / "out", everything_elsewhere=True)
    elapsed = time.perf_counter() - started
    _assert_same_images(tmp_path / "out", reference)
    assert victim.failed
    assert _gone(victim.pid), "the broken process is ended"
    assert elapsed < 5.0, f"rendering took {elapsed:.1f} s"


def test_a_command_line_analysis_never_imports_matplotlib(one_object: Analysed, tmp_path: Path):
    """What ``eigenscope analyze`` does: the drawing process started in the background first, every
    figure drawn there."""
    script = (
        "import eigenscope, sys\n"
        "from workers.pipeline.render import start_drawing_process\n"
        "from workers.runner import run_analysis\n"
        "start_drawing_process(background=True, text_cache=sys.argv[3])\n"
        "run_analysis(sys.argv[1], sys.argv[2], draw_elsewhere=True)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))\n"
    )
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-c", script, str(one_object.clip_path), str(out), str(tmp_path / "text.pickle")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
    assert len(list(out.glob("*.png"))) == 6
