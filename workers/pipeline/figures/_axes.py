"""Drawing helpers shared by the figures: matplotlib's import, a figure of exact pixel size, its
rasterisation (with images composited under it), colour bars and tables, axes, ticks, legends and notes.

Plots are drawn with matplotlib's object API on the Agg canvas (``Figure`` + ``FigureCanvasAgg``, never
``pyplot``): no display, no global state, safe to call from several threads at once. matplotlib is
imported inside the functions, so importing this module stays cheap.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures.style import (
    _FONT,
    _SMALL,
    _SUPERSCRIPT,
    _TITLE,
    DPI,
    NO_OBJECT_NOTE,
    object_color,
)

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis


@functools.cache
def load_matplotlib() -> None:
    """Import matplotlib for drawing, once per process.

    - Without writing ``set`` signatures for help() (see below), and without its 3-D toolkit:
      ``matplotlib.figure`` registers every projection, and importing
      ``mpl_toolkits.mplot3d`` is a sixth of matplotlib's import, for a projection never drawn here. The
      toolkit is marked absent for the length of the import (matplotlib then leaves "3d" out, with a
      warning that is silenced) unless something has loaded it already; it stays importable after.
    - Text without hinting: a third cheaper to lay out and draw than matplotlib's forced auto-hinting
      (text is most of a plot's drawing time), and as legible at these sizes. matplotlib reads the
      setting from its global rcParams at draw time, so it is set once (the process draws nothing else)
      rather than toggled around each draw, which threads would race on.
    """
    with _MATPLOTLIB_IMPORT:  # the warm-up thread and a render may both get here first
        _import_matplotlib()


#: Held while :func:`load_matplotlib` imports, so that one thread's temporary changes are not taken by another
#: for the originals.
_MATPLOTLIB_IMPORT = threading.Lock()


def _import_matplotlib() -> None:
    import sys
    import warnings

    import matplotlib.artist

    hide = "mpl_toolkits.mplot3d" not in sys.modules and "matplotlib.projections" not in sys.modules
    artist = matplotlib.artist.Artist
    hook = "_update_set_signature_and_docstring"
    signatures = artist.__dict__.get(hook)
    if hide:
        warnings.filterwarnings("ignore", message="Unable to import Axes3D", category=UserWarning)
        sys.modules["mpl_toolkits.mplot3d"] = None  # type: ignore[assignment]
        if isinstance(signatures, classmethod):
            # Every Artist subclass defined during the import inspects all its setters to write the
            # signature and docstring of its ``set`` method, for help() only: a third of the import's
            # time. ``set`` itself is defined as before and accepts the same keywords.
            setattr(artist, hook, classmethod(lambda cls: None))
    try:
        import matplotlib
        import matplotlib.figure
    finally:
        if hide and sys.modules.get("mpl_toolkits.mplot3d", False) is None:
            del sys.modules["mpl_toolkits.mplot3d"]
        if hide and isinstance(signatures, classmethod):
            setattr(artist, hook, signatures)
    matplotlib.rcParams["text.hinting"] = "no_hinting"


def _figure(size_px: tuple[int, int], *, transparent: bool = False) -> tuple[Any, Any]:
    """A Figure of exactly ``size_px`` pixels on its own Agg canvas (no pyplot, no global state)."""
    load_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    face = (1.0, 1.0, 1.0, 0.0) if transparent else "white"
    fig = Figure(figsize=(size_px[0] / DPI, size_px[1] / DPI), dpi=DPI, facecolor=face)
    canvas = FigureCanvasAgg(fig)
    return fig, canvas


Underlay = tuple[NDArray[np.uint8], int, int]


def _finish(
    canvas: Any, size_px: tuple[int, int], *, underlays: Sequence[Underlay] = ()
) -> NDArray[np.uint8]:
    """Draw the figure into RGB pixels.

    Each underlay ``(rgb, x, y)`` is an image placed with its top-left corner at pixel (x, y) of a white
    page; the figure (created transparent) is composited over the page. Much cheaper than ``figimage``,
    ``imshow`` or colour-bar axes, which resample and lay out in Python.
    """
    import cv2

    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    if rgba.shape[:2] != (size_px[1], size_px[0]):  # pragma: no cover - guards the stated sizes
        raise RuntimeError(f"rendered {rgba.shape[1]}x{rgba.shape[0]} pixels, expected {size_px}")
    # OpenCV drops and tests the alpha channel ten times faster than numpy's strided copies.
    alpha = cv2.extractChannel(rgba, 3)
    if not underlays and cv2.minMaxLoc(alpha)[0] == 255:
        return np.asarray(cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), np.uint8)
    page = np.full((size_px[1], size_px[0], 3), 255, np.uint8)
    for image, x, y in underlays:
        page[y : y + image.shape[0], x : x + image.shape[1]] = image[: size_px[1] - y, : size_px[0] - x]
    # Agg's buffer holds straight (not premultiplied) alpha; only the drawn pixels need blending.
    flat_page = page.reshape(-1, 3)
    flat_rgba = rgba.reshape(-1, 4)
    drawn = np.flatnonzero(alpha)
    src = flat_rgba[drawn].astype(np.uint16)
    a = src[:, 3:4]
    blended = (src[:, :3] * a + flat_page[drawn].astype(np.uint16) * (255 - a) + 127) // 255
    flat_page[drawn] = blended.astype(np.uint8)
    return page


def _colour_lut(name: str) -> NDArray[np.uint8]:
    """(256, 3) uint8 RGB table of a matplotlib colour map."""
    from matplotlib import colormaps

    lut: NDArray[np.uint8] = colormaps[name](np.linspace(0.0, 1.0, 256), bytes=True)[:, :3]
    return np.ascontiguousarray(lut)


def _colour_index(values: NDArray[np.floating[Any]], vmin: float, vmax: float) -> NDArray[np.uint8]:
    """Index into a 256-entry colour table; NaN maps to the bottom of the scale."""
    scaled = (np.asarray(values, np.float32) - np.float32(vmin)) * np.float32(255.0 / (vmax - vmin))
    np.nan_to_num(scaled, copy=False, nan=0.0)
    np.clip(scaled, 0.0, 255.0, out=scaled)
    return scaled.astype(np.uint8)


def _tick_values(vmin: float, vmax: float, bins: int) -> tuple[list[float], int]:
    """'Nice' tick values inside [vmin, vmax] and the fewest decimals that print them exactly."""
    from matplotlib.ticker import MaxNLocator

    span = abs(vmax - vmin) or 1.0
    ticks = [float(t) for t in MaxNLocator(nbins=bins).tick_values(vmin, vmax)]
    ticks = [t for t in ticks if vmin - 1e-9 * span <= t <= vmax + 1e-9 * span]
    step = ticks[1] - ticks[0] if len(ticks) > 1 else span
    for decimals in range(0, 10):
        if all(abs(round(t, decimals) - t) <= 1e-6 * step for t in ticks):
            return ticks, decimals
    return ticks, 10


@dataclass(frozen=True)
class ColourBar:
    """A vertical colour bar: where it goes, the scale it shows and how it is labelled.

    Attributes
    ----------
    x, y : int
        The bar's top-left pixel in the figure (top-left origin).
    height : int
        The bar's height, pixels.
    vmin, vmax : float
        The values at the bottom and the top of the bar.
    cmap : str
        matplotlib colour map name.
    label : str
        Text along the bar's right side.
    marks : sequence of (float, (int, int, int))
        (value, rgb) lines across the bar (the objects' frequencies).
    bins : int
        At most this many tick intervals.
    width : int
        The bar's width, pixels (ticks extend to its right).
    """

    x: int
    y: int
    height: int
    vmin: float
    vmax: float
    cmap: str
    label: str
    marks: Sequence[tuple[float, tuple[int, int, int]]] = ()
    bins: int = 6
    width: int = 20

    def row_of(self, value: float) -> int:
        """The bar's pixel row (from its top) of ``value``."""
        return round((self.vmax - value) / (self.vmax - self.vmin) * (self.height - 1))


#: Length of the colour bar's ticks, pixels.
_BAR_TICK_PX = 6


def _colour_bar(fig: Any, size: tuple[int, int], bar: ColourBar) -> Underlay:
    """A vertical colour bar as an underlay image (bar, frame, ticks, marks) plus figure texts.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Gets the tick labels and the bar's label, as figure texts.
    size : (int, int)
        The figure's (width, height), pixels.
    bar : ColourBar

    Returns
    -------
    Underlay
        The bar's image at ``(bar.x, bar.y)``, to pass to :func:`_finish`.
    """
    W, H = size
    img = _colour_bar_image(bar)
    ticks, decimals = _tick_values(bar.vmin, bar.vmax, bar.bins)
    for value in ticks:
        r = bar.row_of(value)
        img[max(r - 1, 0) : r + 1, bar.width :] = 0
        fig.text(
            (bar.x + bar.width + _BAR_TICK_PX + 4) / W,
            1 - (bar.y + r) / H,
            _tick_label(value, decimals),
            ha="left",
            va="center",
            fontsize=_SMALL,
        )
    fig.text(
        (bar.x + bar.width + _BAR_TICK_PX + 40) / W,
        1 - (bar.y + bar.height / 2) / H,
        bar.label,
        ha="left",
        va="center",
        rotation=90,
        fontsize=_FONT,
    )
    return (img, bar.x, bar.y)


def _colour_bar_image(bar: ColourBar) -> NDArray[np.uint8]:
    """The bar's pixels: the colour scale framed in black, its marks, and white room for the ticks."""
    width, height = bar.width, bar.height
    img = np.full((height, width + _BAR_TICK_PX, 3), 255, np.uint8)
    rows = bar.vmax - (np.arange(height) + 0.5) * ((bar.vmax - bar.vmin) / height)
    img[:, :width] = _colour_lut(bar.cmap)[_colour_index(rows, bar.vmin, bar.vmax)][:, None, :]
    img[0, :width] = img[-1, :width] = 0
    img[:, 0] = img[:, width - 1] = 0
    for value, rgb in bar.marks:
        if bar.vmin <= value <= bar.vmax:
            r = bar.row_of(value)
            img[max(r - 3, 0) : r + 4, :width] = 0
            img[max(r - 1, 0) : r + 2, 1 : width - 1] = rgb
    return img


def _axes_box_px(ax: Any, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) pixel edges of an axes, top-left origin."""
    b = ax.get_position()
    W, H = size
    return (round(b.x0 * W), round((1 - b.y1) * H), round(b.x1 * W), round((1 - b.y0) * H))


def _raster(
    values: NDArray[np.floating[Any]],
    xs: NDArray[np.floating[Any]],
    ys: NDArray[np.floating[Any]],
    *,
    xlim: tuple[float, float],
    ylim: tuple[float, float],
    shape: tuple[int, int],
) -> NDArray[np.intp]:
    """Nearest-sample lookup of ``values[y, x]`` at the centres of a (rows, cols) pixel grid.

    ``xs`` and ``ys`` are the (increasing) sample positions; the grid spans ``xlim`` left to right and
    ``ylim`` bottom to top. Returns the flat indices into ``values``.
    """
    rows, cols = shape
    cx = xlim[0] + (np.arange(cols) + 0.5) * ((xlim[1] - xlim[0]) / cols)
    cy = ylim[1] - (np.arange(rows) + 0.5) * ((ylim[1] - ylim[0]) / rows)
    xi = np.searchsorted((xs[1:] + xs[:-1]) / 2, cx) if len(xs) > 1 else np.zeros(cols, np.intp)
    yi = np.searchsorted((ys[1:] + ys[:-1]) / 2, cy) if len(ys) > 1 else np.zeros(rows, np.intp)
    flat: NDArray[np.intp] = yi[:, None] * values.shape[1] + xi[None, :]
    return flat


def _frame(analysis: Analysis) -> NDArray[np.uint8]:
    frame = np.asarray(analysis.frame_rgb)
    if frame.ndim == 2:
        frame = np.repeat(frame[..., None], 3, axis=2)
    if frame.ndim != 3 or frame.shape[2] < 3:
        raise ValueError(f"frame_rgb has shape {frame.shape}; expected (H, W, 3)")
    return np.ascontiguousarray(frame[..., :3].astype(np.uint8, copy=False))


def _resize(img: NDArray[Any], size: tuple[int, int], *, nearest: bool) -> NDArray[Any]:
    import cv2

    if (img.shape[1], img.shape[0]) == size:
        return img
    if nearest:
        interp = cv2.INTER_NEAREST
    elif size[0] > img.shape[1]:
        interp = cv2.INTER_LINEAR
    else:
        interp = cv2.INTER_AREA
    out: NDArray[Any] = cv2.resize(img, size, interpolation=interp)
    return out


def _draw_outlines(
    rgb: NDArray[np.uint8],
    labels: NDArray[np.integer[Any]],
    ids: Sequence[int],
    *,
    scale: float,
    width: int,
) -> NDArray[np.uint8]:
    """Draw each object's outline (dark halo + its colour) onto ``rgb`` in place.

    Contours are traced on ``labels`` at frame resolution and scaled by ``scale`` with sub-pixel
    precision, so upscaled frames get smooth outlines rather than blocky ones.
    """
    import cv2

    shift = 4
    labels = np.asarray(labels)
    for oid in ids:
        mask = (labels == oid).astype(np.uint8)
        if not mask.any():
            continue
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        # Pixel centres: frame pixel (x, y) covers [x, x + 1) and maps to ((x + 0.5) * scale - 0.5).
        fixed = [
            np.round(((c.astype(np.float64) + 0.5) * scale - 0.5) * (1 << shift)).astype(np.int32)
            for c in contours
        ]
        cv2.polylines(rgb, fixed, True, (0, 0, 0), width + 2, cv2.LINE_AA, shift)
        cv2.polylines(rgb, fixed, True, object_color(oid), width, cv2.LINE_8, shift)
    return rgb


def _times_s(analysis: Analysis, n_samples: int) -> NDArray[np.float64]:
    """Capture times (s from the clip's first frame) of the window's first ``n_samples`` frames."""
    times = getattr(analysis, "times_s", None)
    if times is not None:
        t = np.asarray(times, np.float64)
        if t.shape == (n_samples,):
            return t
    start = analysis.frames_used[0] if analysis.frames_used else 0
    return (start + analysis.frame_step * np.arange(n_samples, dtype=np.float64)) / analysis.fps


def _sample_rate(analysis: Analysis) -> float:
    """Rate of the analysed samples: the clip's frame rate over the frame step (every k-th frame)."""
    return analysis.sample_rate_hz


def _note(
    target: Any,
    text: str,
    *,
    color: str = "0.3",
    xy: tuple[float, float] = (0.5, 0.5),
    fontsize: float = _TITLE,
) -> None:
    """A boxed note at ``xy`` (axes or figure fraction) of an axes or a figure."""
    transform = target.transAxes if hasattr(target, "transAxes") else target.transFigure
    target.text(
        xy[0],
        xy[1],
        text,
        transform=transform,
        ha="center",
        va="center",
        fontsize=fontsize,
        color=color,
        bbox={"boxstyle": "round,pad=0.5", "facecolor": "white", "edgecolor": "0.6", "alpha": 0.9},
    )


def _log_tick(value: float, _pos: object = None) -> str:
    """``10³``-style log-axis labels in plain unicode (mathtext costs tens of ms per figure)."""
    if not (value > 0 and math.isfinite(value)):
        return ""
    exponent = math.log10(value)
    if abs(exponent - round(exponent)) > 1e-6:
        return ""
    return "10" + str(round(exponent)).translate(_SUPERSCRIPT)


@dataclass(frozen=True)
class AxisStyle:
    """How :func:`_axis` ticks and grids an axes.

    Attributes
    ----------
    x_bins, y_bins : int
        At most this many tick intervals along x and along y.
    log_y : bool
        y is on a log scale: ticks at powers of ten (at most 8 labelled decades).
    grid : bool
        Grey grid lines at the ticks.
    y_ticks : bool
        Ticks and tick labels on y (ignored when ``log_y``).
    """

    x_bins: int = 6
    y_bins: int = 5
    log_y: bool = False
    grid: bool = True
    y_ticks: bool = True


#: Length of an axis's ticks, pixels.
_TICK_PX = 5.0


def _axis(
    ax: Any, size: tuple[int, int], *, xlabel: str, ylabel: str, style: AxisStyle = AxisStyle()
) -> None:
    """Ticks, tick labels, grid and axis labels of ``ax`` as a handful of artists.

    matplotlib's own ticks cost about a millisecond and a half each to create and lay out; these are
    drawn as one line collection per axis and one text per label, at fixed pixel offsets. Call it
    once the axes' limits are final.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    size : (int, int)
        The figure's (width, height), pixels.
    xlabel, ylabel : str
        The axis labels.
    style : AxisStyle
        Tick counts, log scale, grid.
    """
    from matplotlib.ticker import NullLocator

    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(NullLocator())
        axis.set_minor_locator(NullLocator())
    W, H = size
    box = ax.get_position()
    ax_px = (box.width * W, box.height * H)
    x0, x1 = sorted(ax.get_xlim())
    y0, y1 = sorted(ax.get_ylim())
    ax.set_xlim(x0, x1)  # freeze: the artists below must not move the limits
    ax.set_ylim(y0, y1)
    xt, xd = _tick_values(x0, x1, style.x_bins)
    xlabels = [_tick_label(x, xd) for x in xt]
    yt, ylabels = _y_ticks(y0, y1, style)
    if style.grid:
        _grid_lines(ax, xt, yt)
    _tick_marks(ax, xt, yt, ax_px)
    _tick_texts(ax, list(zip(xt, xlabels, strict=True)), list(zip(yt, ylabels, strict=True)), ax_px)
    ax_w, ax_h = ax_px
    ax.text(
        0.5, -(_TICK_PX + 24) / ax_h, xlabel, transform=ax.transAxes, ha="center", va="top", fontsize=_FONT
    )
    ax.text(
        -66 / ax_w,
        0.5,
        ylabel,
        transform=ax.transAxes,
        ha="center",
        va="center",
        rotation=90,
        fontsize=_FONT,
    )


def _y_ticks(y0: float, y1: float, style: AxisStyle) -> tuple[list[float], list[str]]:
    """The y ticks of [y0, y1] and their labels: decades on a log scale, none without ``y_ticks``."""
    if style.log_y:
        lo_e, hi_e = math.ceil(math.log10(y0) - 1e-9), math.floor(math.log10(y1) + 1e-9)
        step = max(1, math.ceil((hi_e - lo_e + 1) / 8))
        yt = [10.0**e for e in range(lo_e, hi_e + 1, step)]
        return yt, [_log_tick(v) for v in yt]
    if style.y_ticks:
        yt, yd = _tick_values(y0, y1, style.y_bins)
        return yt, [_tick_label(v, yd) for v in yt]
    return [], []


def _grid_lines(ax: Any, xt: Sequence[float], yt: Sequence[float]) -> None:
    """Light grey lines across ``ax`` at the x ticks ``xt`` and the y ticks ``yt``, under the data."""
    nan = float("nan")
    gx = [v for x in xt for v in (x, x, nan)]
    gy = [v for _ in xt for v in (0.0, 1.0, nan)]
    ax.plot(gx, gy, transform=ax.get_xaxis_transform(), color="0.88", linewidth=0.8, zorder=0.5)
    gx = [v for _ in yt for v in (0.0, 1.0, nan)]
    gy = [v for y in yt for v in (y, y, nan)]
    ax.plot(gx, gy, transform=ax.get_yaxis_transform(), color="0.88", linewidth=0.8, zorder=0.5)


def _tick_marks(ax: Any, xt: Sequence[float], yt: Sequence[float], ax_px: tuple[float, float]) -> None:
    """The tick marks below the x axis and left of the y axis; ``ax_px`` is the axes' size in pixels."""
    ax_w, ax_h = ax_px
    nan = float("nan")
    mx = [v for x in xt for v in (x, x, nan)]
    my = [v for _ in xt for v in (0.0, -_TICK_PX / ax_h, nan)]
    ax.plot(mx, my, transform=ax.get_xaxis_transform(), color="black", linewidth=0.8, clip_on=False)
    mx = [v for _ in yt for v in (0.0, -_TICK_PX / ax_w, nan)]
    my = [v for y in yt for v in (y, y, nan)]
    ax.plot(mx, my, transform=ax.get_yaxis_transform(), color="black", linewidth=0.8, clip_on=False)


def _tick_texts(
    ax: Any,
    x_labels: Sequence[tuple[float, str]],
    y_labels: Sequence[tuple[float, str]],
    ax_px: tuple[float, float],
) -> None:
    """The (value, text) tick labels below the x axis and left of the y axis."""
    ax_w, ax_h = ax_px
    xtrans, ytrans = ax.get_xaxis_transform(), ax.get_yaxis_transform()
    for x, label in x_labels:
        ax.text(x, -(_TICK_PX + 3) / ax_h, label, transform=xtrans, ha="center", va="top", fontsize=_SMALL)
    for y, label in y_labels:
        ax.text(-(_TICK_PX + 3) / ax_w, y, label, transform=ytrans, ha="right", va="center", fontsize=_SMALL)


#: A legend's inner padding, sample length, gap between sample and text, and margin from the axes' corner,
#: pixels.
_LEGEND_PAD, _LEGEND_SAMPLE, _LEGEND_GAP, _LEGEND_MARGIN = 8.0, 30.0, 8.0, 10.0


@dataclass(frozen=True)
class _LegendBox:
    """Where a legend goes in its axes, in pixels from the axes' bottom-left corner.

    Attributes
    ----------
    ax_w, ax_h : float
        The axes' size, pixels.
    left, top, width, height : float
        The legend's box.
    line_h : float
        Distance between the entries' baselines.
    fontsize : float
        Points.
    """

    ax_w: float
    ax_h: float
    left: float
    top: float
    width: float
    height: float
    line_h: float
    fontsize: float

    def at(self, x_px: float, y_px: float) -> tuple[float, float]:
        """Axes fraction of a pixel position."""
        return (x_px / self.ax_w, y_px / self.ax_h)

    def row_y(self, i: int) -> float:
        """The vertical centre of entry ``i`` (0 at the top), pixels."""
        text_h = self.fontsize * DPI / 72
        return self.top - _LEGEND_PAD - (i + 0.5) * self.line_h + (self.line_h - text_h) / 2


def _legend(ax: Any, size: tuple[int, int], *, fontsize: float = _SMALL) -> None:
    """The labelled artists of ``ax`` listed in a box at its upper right corner.

    Equivalent to ``ax.legend(loc="upper right")`` for lines, markers and spans, at a fraction of the
    cost (matplotlib's legend lays out through a tree of offset boxes).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    size : (int, int)
        The figure's (width, height), pixels.
    fontsize : float
        Of the entries' labels, points.
    """
    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    box = _legend_box(ax, size, labels, fontsize)
    _legend_frame(ax, box)
    for i, (handle, label) in enumerate(zip(handles, labels, strict=True)):
        y = box.row_y(i)
        x0 = box.left + _LEGEND_PAD
        _legend_sample(ax, handle, box, x0, y)
        ax.text(
            *box.at(x0 + _LEGEND_SAMPLE + _LEGEND_GAP, y),
            label,
            transform=ax.transAxes,
            ha="left",
            va="center",
            fontsize=fontsize,
            zorder=12,
            clip_on=False,
        )


def _legend_box(ax: Any, size: tuple[int, int], labels: Sequence[str], fontsize: float) -> _LegendBox:
    """The box that fits ``labels`` (measured with the figure's renderer) at the axes' upper right."""
    from matplotlib.font_manager import FontProperties

    W, H = size
    bounds = ax.get_position()
    ax_w, ax_h = bounds.width * W, bounds.height * H
    renderer = ax.figure.canvas.get_renderer()
    prop = FontProperties(size=fontsize)
    widths = [renderer.get_text_width_height_descent(t, prop, ismath=False)[0] for t in labels]
    line_h = fontsize * DPI / 72 * 1.45
    width = _LEGEND_PAD + _LEGEND_SAMPLE + _LEGEND_GAP + max(widths) + _LEGEND_PAD
    height = 2 * _LEGEND_PAD + line_h * len(labels) - (line_h - fontsize * DPI / 72)
    right, top = ax_w - _LEGEND_MARGIN, ax_h - _LEGEND_MARGIN
    return _LegendBox(ax_w, ax_h, right - width, top, width, height, line_h, fontsize)


def _legend_frame(ax: Any, box: _LegendBox) -> None:
    """The legend's white, rounded, grey-edged background."""
    from matplotlib.patches import FancyBboxPatch

    ax.add_patch(
        FancyBboxPatch(
            box.at(box.left, box.top - box.height),
            box.width / box.ax_w,
            box.height / box.ax_h,
            boxstyle="round,pad=0,rounding_size=0.008",
            transform=ax.transAxes,
            facecolor="white",
            edgecolor="0.8",
            alpha=0.92,
            zorder=10,
            clip_on=False,
        )
    )


def _legend_sample(ax: Any, handle: Any, box: _LegendBox, x0: float, y: float) -> None:
    """A legend entry's sample from pixel (x0, y) of the axes: a short line with its marker, or a patch."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Rectangle

    at, sample = box.at, _LEGEND_SAMPLE
    if isinstance(handle, Line2D):
        ax.add_line(
            Line2D(
                [at(x0, y)[0], at(x0 + sample / 2, y)[0], at(x0 + sample, y)[0]],
                [at(x0, y)[1]] * 3,
                transform=ax.transAxes,
                color=handle.get_color(),
                linestyle=handle.get_linestyle(),
                linewidth=handle.get_linewidth(),
                marker=handle.get_marker(),
                markersize=handle.get_markersize(),
                markeredgecolor=handle.get_markeredgecolor(),
                markerfacecolor=handle.get_markerfacecolor(),
                markeredgewidth=handle.get_markeredgewidth(),
                markevery=[1],
                zorder=11,
                clip_on=False,
            )
        )
    else:
        ax.add_patch(
            Rectangle(
                at(x0, y - 6),
                sample / box.ax_w,
                12 / box.ax_h,
                transform=ax.transAxes,
                facecolor=handle.get_facecolor(),
                edgecolor="none",
                zorder=11,
                clip_on=False,
            )
        )


def _tick_label(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return text.replace("-", "−")


def _title(ax: Any, text: str, *, fontsize: float = _FONT) -> None:
    """A left-aligned title above ``ax`` (a plain text artist: no title auto-positioning pass)."""
    ax.text(
        0.0,
        1.0 + 6 / ax.bbox.height,
        text,
        transform=ax.transAxes,
        ha="left",
        va="bottom",
        fontsize=fontsize,
        color="0.1",
    )


def _no_object_message(analysis: Analysis, *, width: int = 70) -> str:
    """ "no object found" and, when the analysis says why, its reason wrapped to ``width`` characters."""
    for q in analysis.quality:
        if q.code == "no_motion":
            return f"{NO_OBJECT_NOTE}:\n{_wrap(q.message, width)}"
    return NO_OBJECT_NOTE


def _window_span_s(analysis: Analysis) -> tuple[float, float]:
    """(start, end) capture time of the analysed window, seconds from the clip's first frame."""
    first, last = analysis.frames_used
    samples = max((last - first - 1) // analysis.frame_step + 1, 1)
    t = _times_s(analysis, samples)
    end = float(t[-1]) if samples > 1 else float(t[0]) + 1.0 / analysis.fps
    return float(t[0]), end


def _wrap(text: str, width: int) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


# --------------------------------------------------------------------------------------------- images


def _panels(fig: Any, n: int, *, right_px: float = 30.0) -> list[Any]:
    """``n`` stacked axes, laid out in fixed pixel margins (room for a title above each)."""
    width, height = fig.bbox.width, fig.bbox.height
    left, top, bottom, gap = 85.0, 70.0, 60.0, 70.0
    h = (height - top - bottom - gap * (n - 1)) / n
    axes = []
    for i in range(n):
        y = height - top - (i + 1) * h - i * gap
        axes.append(fig.add_axes((left / width, y / height, 1 - (left + right_px) / width, h / height)))
    return axes
