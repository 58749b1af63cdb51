"""An Agg canvas whose text is drawn from a process-wide cache of rendered strings.

matplotlib (3.11) lays out and rasterises every string glyph by glyph at each draw, and measures it
again for each new renderer: text was about half the drawing time of a plot. The figures here repeat the
same tick labels, legends and titles from analysis to analysis, so each (string, font, size) is
measured once per process and, from its second use on, composited as one bitmap rasterised once.
Strings are placed at whole pixels (matplotlib places glyphs at 1/64 pixel), which is invisible at these
sizes. Rotated text and mathtext are cached the same way; TeX and text with font features or a language
set take matplotlib's own path.

matplotlib is imported only when :func:`caching_canvas` is first called.
"""

from __future__ import annotations

import functools
import os
import pickle
import threading
from collections import OrderedDict
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Rendered strings kept per process (least recently used dropped first).
MAX_CACHED_STRINGS = 4096


class _LRU:
    def __init__(self, size: int) -> None:
        self._items: OrderedDict[tuple[Any, ...], tuple[int, Any]] = OrderedDict()
        self._size = size
        self._lock = threading.Lock()
        self.generation = 0  # counts insertions, so a forked drawer can hand back what it added

    def get(self, key: tuple[Any, ...]) -> Any:
        with self._lock:
            found = self._items.get(key)
            if found is None:
                return None
            self._items.move_to_end(key)
            return found[1]

    def put(self, key: tuple[Any, ...], value: Any) -> None:
        with self._lock:
            self.generation += 1
            self._items[key] = (self.generation, value)
            self._items.move_to_end(key)
            while len(self._items) > self._size:
                self._items.popitem(last=False)

    def added_since(self, generation: int) -> list[tuple[tuple[Any, ...], Any]]:
        with self._lock:
            return [(k, v) for k, (g, v) in self._items.items() if g > generation]


#: What the bitmap cache holds for a string drawn once so far (rasterised for the cache at its second use).
_SEEN_ONCE: tuple[()] = ()

_METRICS = _LRU(MAX_CACHED_STRINGS)
_BITMAPS = _LRU(MAX_CACHED_STRINGS)


def cache_mark() -> tuple[int, int]:
    """Where the caches stand now (see :func:`save_added`)."""
    return _METRICS.generation, _BITMAPS.generation


#: Strings added since a mark: (metrics, bitmaps), each a list of (key, value).
Added = tuple[list[tuple[tuple[Any, ...], Any]], list[tuple[tuple[Any, ...], Any]]]


def strings_added_since(mark: tuple[int, int]) -> Added:
    """The strings measured or rendered since ``mark``: what a drawer in another process hands back to
    the process that asked it to draw (its own copy of the caches never sees them)."""
    return _METRICS.added_since(mark[0]), _BITMAPS.added_since(mark[1])


def add_strings(added: Added) -> int:
    """Add another process's :func:`strings_added_since` to this process's caches; how many strings."""
    metrics, bitmaps = added
    for key, value in metrics:
        _METRICS.put(key, value)
    for key, value in bitmaps:
        _BITMAPS.put(key, value)
    return len(metrics) + len(bitmaps)


def save_added(mark: tuple[int, int], path: str | os.PathLike[str]) -> None:
    """Write :func:`strings_added_since` ``mark`` to ``path``: a forked drawer's additions, which its
    parent then loads with :func:`load_added`."""
    with open(path, "wb") as fh:
        pickle.dump(strings_added_since(mark), fh, protocol=pickle.HIGHEST_PROTOCOL)


def load_added(path: str | os.PathLike[str]) -> int:
    """Add what :func:`save_added` wrote to this process's caches; how many strings. A missing or
    unreadable file adds nothing (the caches only make drawing faster)."""
    try:
        with open(path, "rb") as fh:
            added = pickle.load(fh)
    except (OSError, EOFError, pickle.UnpicklingError, ValueError):
        return 0
    return add_strings(added)


#: Format of the file :func:`save_cache` writes (one of another format, or matplotlib, is not read).
_CACHE_FORMAT = 1


class _BuiltinsOnly(pickle.Unpickler):
    """Unpickles str, numbers, bytes, tuples, lists and dicts only: a cache file cannot name a class."""

    def find_class(self, module: str, name: str) -> Any:
        raise pickle.UnpicklingError(f"a text cache holds no {module}.{name}")


def _matplotlib_version() -> str:
    from importlib.metadata import version

    return version("matplotlib")


def save_cache(path: str | os.PathLike[str]) -> bool:
    """Write every string in this process's caches to ``path``, atomically, so that a later process can
    start with them (:func:`load_cache`): the figures' strings repeat from run to run, and rasterising
    them is half of a first drawing's time. Whether the file was written (a cache that cannot be
    saved, such as one in a read-only folder, only makes a later start slower)."""
    import tempfile
    from pathlib import Path

    # Builtins only (a measurement may be a numpy scalar): the file is read without naming any class.
    metrics = [(k, tuple(float(x) for x in v)) for k, v in _METRICS.added_since(0) if _plain(k)]
    bitmaps = [
        (k, (v[0].tobytes(), *(int(n) for n in v[0].shape), int(v[1]), int(v[2])))
        for k, v in _BITMAPS.added_since(0)
        if v != _SEEN_ONCE and _plain(k)
    ]
    payload = {
        "format": _CACHE_FORMAT,
        "matplotlib": _matplotlib_version(),
        "metrics": metrics,
        "bitmaps": bitmaps,
    }
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
        try:
            with os.fdopen(fd, "wb") as fh:
                pickle.dump(payload, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, target)
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        return False
    return True


def _plain(key: tuple[Any, ...]) -> bool:
    """Whether a key holds builtins only (a cache file holds nothing else)."""
    return all(
        _plain(item) if isinstance(item, tuple) else item is None or type(item) in (str, int, float, bool)
        for item in key
    )


def load_cache(path: str | os.PathLike[str]) -> int:
    """Add the strings :func:`save_cache` wrote to ``path`` to this process's caches; how many. A missing,
    unreadable or foreign file (another format or matplotlib) adds nothing."""
    try:
        with open(path, "rb") as fh:
            payload = _BuiltinsOnly(fh).load()
        if payload["format"] != _CACHE_FORMAT or payload["matplotlib"] != _matplotlib_version():
            return 0
        metrics = [(tuple(k), tuple(float(x) for x in v)) for k, v in payload["metrics"]]
        bitmaps = []
        for key, (data, height, width, dx, dy) in payload["bitmaps"]:
            coverage = np.frombuffer(data, np.uint8).reshape(height, width).copy()
            bitmaps.append((tuple(key), (coverage, int(dx), int(dy))))
    except (OSError, EOFError, pickle.UnpicklingError, ValueError, TypeError, KeyError, IndexError):
        return 0
    return add_strings((metrics, bitmaps))


_EAGER = False


def cache_at_first_use() -> None:
    """Rasterise each string for the cache at its first use instead of its second, for the rest of this
    process: for a drawing process, whose figures then have the pixels its caller's warm cache gives."""
    global _EAGER
    _EAGER = True


def _font_height_metrics(
    paths: tuple[str, ...], size_pt: float, dpi: float
) -> tuple[float | None, float | None, float | None]:
    """What ``matplotlib.text.Text._get_layout`` reads from a font: (ascent, descent, line gap) in pixels
    from its OS/2 or hhea table, or Nones (matplotlib then measures the text)."""
    from matplotlib.font_manager import get_font

    font: Any = get_font(list(paths))  # its table lookups are typed per literal table name
    for table_name, gap, ascent, descent in (
        ("OS/2", "sTypoLineGap", "sTypoAscender", "sTypoDescender"),
        ("hhea", "lineGap", "ascent", "descent"),
    ):
        table = font.get_sfnt_table(table_name)
        if table is None:
            continue
        scale = size_pt * dpi / 72 / font.get_sfnt_table("head")["unitsPerEm"]
        return table[ascent] * scale, -table[descent] * scale, table[gap] * scale
    return None, None, None


@functools.cache
def caching_canvas() -> type[Any]:
    """The ``FigureCanvasAgg`` subclass whose renderer caches text; use it as ``canvas_class(figure)``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg, get_hinting_flag
    from matplotlib.font_manager import fontManager

    metrics, bitmaps = _METRICS, _BITMAPS

    fonts: dict[tuple[Any, ...], tuple[str, ...]] = {}

    def font_key(prop: Any, dpi: float) -> tuple[Any, ...]:
        # What FontProperties hashes (family, slant, variant, weight, stretch, size, file, math family)
        # decides the font files; looking those up costs more than drawing a cached string.
        props = (
            tuple(prop.get_family()),
            prop.get_slant(),
            prop.get_variant(),
            prop.get_weight(),
            prop.get_stretch(),
            prop.get_size(),
            prop.get_file(),
            prop.get_math_fontfamily(),
        )
        paths = fonts.get(props)
        if paths is None:
            paths = tuple(str(p) for p in fontManager._find_fonts_by_props(prop))
            fonts[props] = paths
        flag = get_hinting_flag()  # an enum member: its value keeps keys to builtins (see save_cache)
        return (props, paths, float(dpi), getattr(flag, "value", flag))

    heights: dict[tuple[Any, ...], tuple[float | None, float | None, float | None]] = {}

    class CachingRenderer(RendererAgg):  # type: ignore[misc]
        def _get_font_height_metrics(self, prop: Any) -> tuple[float | None, float | None, float | None]:
            """(ascent, descent, line gap) of the font, in pixels, which matplotlib's text layout
            otherwise reads from the font's tables for every string it lays out (it asks a renderer
            first, and falls back to measuring when this gives None)."""
            key = font_key(prop, self.dpi)
            found = heights.get(key)
            if found is None:
                found = _font_height_metrics(key[1], prop.get_size_in_points(), self.dpi)
                heights[key] = found
            return found

        def get_text_width_height_descent(self, s: str, prop: Any, ismath: Any) -> tuple[float, float, float]:
            if ismath == "TeX":
                w, h, d = super().get_text_width_height_descent(s, prop, ismath)
                return w, h, d
            key = (s, bool(ismath), *font_key(prop, self.dpi))
            found = metrics.get(key)
            if found is None:
                found = tuple(super().get_text_width_height_descent(s, prop, ismath))
                metrics.put(key, found)
            return found  # type: ignore[no-any-return]

        def draw_text(
            self,
            gc: Any,
            x: float,
            y: float,
            s: str,
            prop: Any,
            angle: float,
            ismath: Any = False,
            mtext: Any = None,
        ) -> None:
            plain = ismath != "TeX" and (
                mtext is None or (mtext.get_fontfeatures() is None and mtext.get_language() is None)
            )
            if not plain or not s:
                super().draw_text(gc, x, y, s, prop, angle, ismath=ismath, mtext=mtext)
                return
            antialiased = bool(gc.get_antialiased())
            key = (s, bool(ismath), float(angle), antialiased, *font_key(prop, self.dpi))
            found = bitmaps.get(key)
            if found is None and not _EAGER:
                # First sight: draw it directly (rasterising for the cache costs more than drawing once,
                # and a one-shot process draws most strings once); cache it when it comes back.
                bitmaps.put(key, _SEEN_ONCE)
                super().draw_text(gc, x, y, s, prop, angle, ismath=ismath, mtext=mtext)
                return
            if found is None or found == _SEEN_ONCE:
                found = self._rasterise(s, prop, angle, bool(ismath), antialiased)
                bitmaps.put(key, found)
            coverage, dx, dy = found
            if coverage.size == 0:
                return
            left = round(x) + dx
            top = round(y) + dy
            # draw_text_image takes the bitmap's left column and the row below its bottom (y downwards).
            self._renderer.draw_text_image(coverage, left, top + coverage.shape[0], 0, gc)

        def _rasterise(
            self, s: str, prop: Any, angle: float, ismath: bool, antialiased: bool
        ) -> tuple[NDArray[np.uint8], int, int]:
            """Coverage bitmap of ``s`` and its top-left corner relative to the text's origin (the
            left end of its baseline, y downwards), drawn once by matplotlib around a known origin."""
            width, height, _ = self.get_text_width_height_descent(s, prop, ismath)
            reach = int(width + height) + 4 + int(prop.get_size_in_points() * self.dpi / 72)
            scratch = RendererAgg(2 * reach, 2 * reach, self.dpi)
            gc = scratch.new_gc()
            gc.set_foreground((0.0, 0.0, 0.0, 1.0))
            gc.set_antialiased(antialiased)
            RendererAgg.draw_text(scratch, gc, reach, reach, s, prop, angle, ismath=ismath)
            gc.restore()
            alpha = np.asarray(scratch.buffer_rgba())[..., 3]
            rows = np.flatnonzero(alpha.any(axis=1))
            cols = np.flatnonzero(alpha.any(axis=0))
            if len(rows) == 0:
                return np.zeros((0, 0), np.uint8), 0, 0
            r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
            coverage = np.ascontiguousarray(alpha[r0:r1, c0:c1])
            return coverage, int(c0 - reach), int(r0 - reach)

    class CachingCanvas(FigureCanvasAgg):  # type: ignore[misc]
        def get_renderer(self) -> Any:
            w, h = self.get_width_height(physical=True)
            key = w, h, self.figure.dpi
            if getattr(self, "_lastKey", None) != key:
                self.renderer = CachingRenderer(w, h, self.figure.dpi)
                self._lastKey = key
            return self.renderer

    return CachingCanvas
