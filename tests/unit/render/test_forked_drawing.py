"""Part of the figures is drawn in a forked child on the second core when no drawing process serves the
render (``drawing_process=False`` here; see test_drawing_process.py for that process); whatever happens
to the child, every image is written, with the same pixels as when the parent draws them all."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.unit.render.conftest import Analysed
from workers.pipeline import render


def _images(folder: Path) -> dict[str, np.ndarray]:
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(folder.glob("*.png"))}


def _failing_child(*_args: object, **_kwargs: object) -> int:
    pid = os.fork()
    if pid == 0:
        os._exit(3)  # a child that dies before drawing anything
    return pid


@pytest.mark.parametrize("child", ["forked", "fails", "none"])
def test_every_image_is_written_whatever_the_child_does(child, one_object: Analysed, tmp_path, monkeypatch):
    reference = tmp_path / "parent-only"
    monkeypatch.setattr(render, "_fork_drawer", lambda *a, **kw: None)
    # Text is drawn by matplotlib at a string's first use and from the text cache after that, which
    # differs from it on glyph edges (see test_text_cache.py): both renders compared here draw their
    # text from the cache, whichever tests ran before in this process.
    for warm_up in range(2):
        render.render_all(one_object.analysis, tmp_path / f"warm-up-{warm_up}", drawing_process=False)
    render.render_all(one_object.analysis, reference, drawing_process=False)
    monkeypatch.undo()
    if child == "fails":
        monkeypatch.setattr(render, "_fork_drawer", _failing_child)
    elif child == "none":
        monkeypatch.setattr(render, "_fork_drawer", lambda *a, **kw: None)
    out = tmp_path / child
    names = render.render_all(one_object.analysis, out, drawing_process=False)
    assert set(names) == {"mask", "overlay", "frequency_map", "spectrum", "displacement", "ringdown"}
    got, expected = _images(out), _images(reference)
    assert got.keys() == expected.keys()
    assert len(got) == 6
    for name, image in expected.items():
        assert np.array_equal(got[name], image), name
    assert not list(out.glob("*.tmp*")), "no temporary files left behind"


def test_a_drawing_thread_elsewhere_does_not_stall_the_child(one_object: Analysed, tmp_path, monkeypatch):
    """Forking while another thread draws (a concurrent render, the matplotlib warm-up) must not hand the
    child matplotlib's render lock held by a thread that does not exist in it: the child would wait for
    it until the timeout and the parent would draw everything again, tens of seconds later."""
    import threading
    import time

    from matplotlib.figure import Figure

    results: list[bool] = []
    original = render._child_succeeded

    def spy(pid: int) -> bool:
        ok = original(pid)
        results.append(ok)
        return ok

    monkeypatch.setattr(render, "_child_succeeded", spy)
    monkeypatch.setattr(render, "_CHILD_TIMEOUT_S", 10.0)
    holding = threading.Event()

    def draw_elsewhere() -> None:
        with Figure._render_lock:  # what another thread's figure.draw() holds
            holding.set()
            time.sleep(0.5)

    other = threading.Thread(target=draw_elsewhere)
    other.start()
    holding.wait()
    started = time.perf_counter()
    render.render_all(one_object.analysis, tmp_path / "out", drawing_process=False)
    elapsed = time.perf_counter() - started
    other.join()
    assert results == [True], "the forked child failed or was killed"
    assert elapsed < 5.0, f"rendering took {elapsed:.1f} s"


def test_strings_the_child_rendered_are_cached_in_the_parent(one_object: Analysed, tmp_path, monkeypatch):
    """The child's copy of the text cache dies with it; what it rendered (the displacement figure's
    release label, say) is handed back, so the next render's child starts warm. No file is left over."""
    import tempfile
    from collections import OrderedDict

    from workers.pipeline import _agg

    for cache in (_agg._BITMAPS, _agg._METRICS):  # start cold: earlier tests drew the same strings
        monkeypatch.setattr(cache, "_items", OrderedDict())
    before = set(Path(tempfile.gettempdir()).glob("eigenscope-text-cache-*"))
    mark = _agg.cache_mark()
    render.render_all(one_object.analysis, tmp_path / "first", drawing_process=False)
    added = [key[0] for key, _ in _agg._BITMAPS.added_since(mark[1])]
    assert any(s.startswith("release ") for s in added), added  # drawn only in the displacement figure
    assert set(Path(tempfile.gettempdir()).glob("eigenscope-text-cache-*")) == before
    assert _agg.load_added(tmp_path / "missing") == 0


def test_the_fork_waits_for_a_warm_up_thread_still_importing(one_object: Analysed, tmp_path, monkeypatch):
    """A warm-up thread in the middle of an import holds that module's lock; a child forked then would
    wait on its own import of the module forever (the paper method hit the child's timeout this way,
    because its images follow the matplotlib warm-up at once)."""
    import sys
    import threading
    import time

    (tmp_path / "slow_to_import_for_the_fork_test.py").write_text("import time\ntime.sleep(1.0)\nVALUE = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("slow_to_import_for_the_fork_test", None)
    draw_displacement = render._DRAWERS["displacement"]

    def drawing_that_imports(analysis):
        import slow_to_import_for_the_fork_test  # noqa: F401 - the module the warm-up is importing

        return draw_displacement(analysis)

    monkeypatch.setitem(render._DRAWERS, "displacement", drawing_that_imports)
    results: list[bool] = []
    original = render._child_succeeded
    monkeypatch.setattr(render, "_child_succeeded", lambda pid: results.append(original(pid)) or results[-1])
    importing = threading.Thread(
        target=lambda: __import__("slow_to_import_for_the_fork_test"), name="test-warm-up", daemon=True
    )
    importing.start()
    time.sleep(0.2)  # the thread is inside the import now
    started = time.perf_counter()
    render.render_all(one_object.analysis, tmp_path / "out", drawing_process=False)
    elapsed = time.perf_counter() - started
    assert results == [True], "the forked child failed or was killed"
    assert elapsed < 5.0, f"rendering took {elapsed:.1f} s"
