"""Text drawn from the per-process cache of rendered strings looks like matplotlib's own, and the cache is
what makes it cheaper: a string is drawn by matplotlib at its first use, rasterised once at its second,
and composited from the cache after that, whatever the figure; saved to a file, the cache gives a later
process the same pixels without rasterising again, and a bad file only costs that."""

from __future__ import annotations

import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg
from matplotlib.figure import Figure

from workers.pipeline import _agg
from workers.pipeline._agg import caching_canvas


def _figure() -> Figure:
    fig = Figure(figsize=(4, 3), dpi=100)
    ax = fig.add_axes((0.15, 0.15, 0.8, 0.7))
    ax.plot([0, 1, 2], [3, 1, 2], color="tab:orange", label="measured ± 0.1 N/m")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("displacement (mm)")  # rotated: matplotlib's own path
    ax.set_title("Ring-down of object #1")
    ax.text(0.5, 2.5, "k = 495.2 ± 3.0 N/m\nm = 0.50 kg", color="navy", fontsize=9)
    ax.text(1.5, 1.2, r"$10^{3}$", fontsize=9)  # mathtext: matplotlib's own path
    ax.legend(loc="lower right")
    return fig


def _pixels(canvas_class: type, *, draws: int = 1) -> np.ndarray:
    for _ in range(draws):  # the caching canvas draws from its cache from the third time on
        canvas = canvas_class(_figure())
        canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].astype(int)


def _ink_bounds(image: np.ndarray) -> tuple[int, int, int, int]:
    dark = np.argwhere(image.min(axis=2) < 128)
    return (*dark.min(axis=0), *dark.max(axis=0))


def test_cached_text_matches_matplotlibs_within_a_pixel():
    ours, theirs = _pixels(caching_canvas(), draws=3), _pixels(FigureCanvasAgg)
    assert ours.shape == theirs.shape
    # Strings land on whole pixels instead of 1/64 pixel: edges of glyphs may differ, nothing else.
    differs = np.abs(ours - theirs).max(axis=2) > 64
    ink = (ours.min(axis=2) < 200) | (theirs.min(axis=2) < 200)
    assert not (differs & ~_grown(ink)).any(), "a difference away from any text or line"
    assert differs.mean() < 0.4 * ink.mean()
    assert np.abs(np.subtract(_ink_bounds(ours), _ink_bounds(theirs))).max() <= 1
    # Every dark (text or line) pixel of matplotlib's image has a dark pixel within one pixel in ours.
    dark_theirs = theirs.min(axis=2) < 100
    dark_ours = ours.min(axis=2) < 160
    assert np.mean(dark_theirs & ~_grown(dark_ours)) < 0.002


def _grown(mask: np.ndarray) -> np.ndarray:
    """``mask`` dilated by one pixel."""
    grown = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            grown |= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return grown


def _count_matplotlib_text(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The strings matplotlib's own renderer draws from now on (directly, or to rasterise for the cache)."""
    drawn: list[str] = []
    original = RendererAgg.draw_text

    def spy(self, gc, x, y, s, prop, angle, ismath=False, mtext=None):
        drawn.append(s)
        return original(self, gc, x, y, s, prop, angle, ismath=ismath, mtext=mtext)

    monkeypatch.setattr(RendererAgg, "draw_text", spy)
    return drawn


def test_each_string_is_rasterised_once(monkeypatch: pytest.MonkeyPatch):
    drawn = _count_matplotlib_text(monkeypatch)
    canvas_class = caching_canvas()
    text = "a string only this test draws"
    counts = []
    for i in range(4):
        drawn.clear()
        fig = Figure(figsize=(2, 1), dpi=100)
        fig.text(0.1 + 0.05 * i, 0.5, text)
        canvas = canvas_class(fig)
        canvas.draw()
        counts.append(drawn.count(text))
        assert np.asarray(canvas.buffer_rgba())[..., 3].any(), "the string was drawn"
    # First use: drawn by matplotlib; second: rasterised once for the cache; then composited from it.
    assert counts == [1, 1, 0, 0]


@pytest.mark.parametrize("dpi", [72, 100, 150])
def test_text_layout_from_cached_font_heights_is_matplotlibs(dpi):
    """The caching renderer hands matplotlib's text layout each font's ascent, descent and line gap
    from a cache instead of the font's tables: every text's box (one line and several, sizes, weights)
    is exactly where matplotlib's own layout puts it."""
    from matplotlib.text import Text

    fig = Figure(figsize=(4, 3), dpi=dpi)
    texts = [
        fig.text(0.1, 0.2, "displacement (mm)", fontsize=8),
        fig.text(0.1, 0.5, "k = 495.2 ± 3.0 N/m\nm = 0.50 kg", fontsize=11, fontweight="bold"),
        fig.text(0.5, 0.8, "Ring-down", fontsize=14, family="monospace", rotation=90),
    ]
    plain = RendererAgg(400, 300, dpi)
    cached = caching_canvas()(fig).get_renderer()
    assert hasattr(cached, "_get_font_height_metrics")
    assert not hasattr(plain, "_get_font_height_metrics")
    for text in texts:
        expected = Text._get_layout(text, plain)
        got = Text._get_layout(text, cached)
        assert got[0].bounds == pytest.approx(expected[0].bounds, abs=1e-9)
        assert [line[:2] for line in got[1]] == [line[:2] for line in expected[1]]


@pytest.fixture
def cold(monkeypatch: pytest.MonkeyPatch) -> None:
    """This process's caches emptied for the test (and put back afterwards)."""
    for cache in (_agg._BITMAPS, _agg._METRICS):
        monkeypatch.setattr(cache, "_items", OrderedDict())


def test_saved_strings_give_a_later_process_the_same_pixels_without_rasterising(
    cold: None, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    warm = _pixels(caching_canvas(), draws=3)
    path = tmp_path / "cache" / "text.pickle"  # the folder is made
    assert _agg.save_cache(path)
    saved = len(_agg._BITMAPS.added_since(0))
    for cache in (_agg._BITMAPS, _agg._METRICS):  # a new process: nothing cached
        monkeypatch.setattr(cache, "_items", OrderedDict())
    assert _agg.load_cache(path) >= saved > 5
    drawn = _count_matplotlib_text(monkeypatch)
    first = _pixels(caching_canvas())
    assert drawn == [], "a loaded string is neither drawn nor rasterised by matplotlib again"
    assert np.array_equal(first, warm)
    assert not [p for p in path.parent.iterdir() if p != path], "no temporary file left behind"


def test_a_cache_file_cannot_run_code(cold: None, tmp_path: Path):
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (exec, (f"open({str(marker)!r}, 'w').close()",))

    path = tmp_path / "text.pickle"
    payload = {"format": _agg._CACHE_FORMAT, "matplotlib": _agg._matplotlib_version(), "metrics": Payload()}
    path.write_bytes(pickle.dumps(payload))
    assert _agg.load_cache(path) == 0
    assert not marker.exists()


@pytest.mark.parametrize(
    "content",
    [
        "missing",
        "empty",
        "garbage",
        "truncated",
        "other format",
        "other matplotlib",
        "wrong shape",
        "not a dict",
    ],
)
def test_a_missing_or_foreign_cache_file_adds_nothing(content: str, cold: None, tmp_path: Path):
    _pixels(caching_canvas(), draws=3)
    good = tmp_path / "good.pickle"
    assert _agg.save_cache(good)
    payload = pickle.loads(good.read_bytes())
    path = tmp_path / "text.pickle"
    if content == "empty":
        path.write_bytes(b"")
    elif content == "garbage":
        path.write_bytes(b"\x00not a pickle at all" * 10)
    elif content == "truncated":
        path.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    elif content == "other format":
        path.write_bytes(pickle.dumps({**payload, "format": _agg._CACHE_FORMAT + 1}))
    elif content == "other matplotlib":
        path.write_bytes(pickle.dumps({**payload, "matplotlib": "0.0.1"}))
    elif content == "wrong shape":
        key, (data, height, width, dx, dy) = payload["bitmaps"][0]
        bad = [(key, (data, height + 1, width, dx, dy))]
        path.write_bytes(pickle.dumps({**payload, "bitmaps": bad}))
    elif content == "not a dict":
        path.write_bytes(pickle.dumps([1, 2, 3]))
    before = (_agg._BITMAPS.generation, len(_agg._BITMAPS.added_since(0)))
    assert _agg.load_cache(path) == 0
    assert len(_agg._BITMAPS.added_since(0)) == before[1]


def test_a_cache_that_cannot_be_written_is_no_error(tmp_path: Path):
    _pixels(caching_canvas(), draws=3)
    blocker = tmp_path / "a file"
    blocker.write_text("")
    assert not _agg.save_cache(blocker / "text.pickle")  # its folder would be a file
