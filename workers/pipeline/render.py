"""Images of a result: the machine-readable label mask, an annotated overlay and four plots.

Every image is a PNG written atomically (temporary file + ``os.replace``), so a reader never sees half an
image. Plots are drawn with matplotlib's object API on the Agg canvas (``Figure`` + ``FigureCanvasAgg``,
never ``pyplot``): no display, no global state, safe to call from several threads at once. matplotlib is
imported inside the functions, so importing this module stays cheap.

One object has one colour in every image: :func:`object_color` is the palette.

Sizes (pixels, width x height), fixed so that tests and clients can rely on them:

* ``overlay.png`` - the frame's display size, :func:`display_size` (the frame size; small frames are
  upscaled by an integer factor to at least 640 px on their long side, wide frames shrunk to 1280 px wide).
* ``frequency_map.png`` - the display size plus :data:`MAP_MARGIN_PX` for the title and the colour bar.
* ``spectrum.png`` - :data:`PLOT_SIZE_PX` (1000 x 600).
* ``displacement.png`` and ``ringdown.png`` - one panel per object, :func:`panel_figure_size` (1000 x 600
  for one or two objects, taller for more).
* ``mask.png`` - the frame size, a palette image: 0 = background, i = object i, shown in its colour.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline import _drawing_process
from workers.pipeline._agg import add_strings, cache_mark, caching_canvas, load_added, save_added
from workers.pipeline._files import artifact_mode

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis, ObjectMeasurement

#: Resolution of every plot; sizes are given in pixels.
DPI = 100
#: (width, height) of ``spectrum.png`` and the minimum size of the per-object plots.
PLOT_SIZE_PX = (1000, 600)
#: Height of one object's panel in ``displacement.png`` / ``ringdown.png`` beyond two objects.
PANEL_HEIGHT_PX = 250
#: (extra width, extra height) of ``frequency_map.png`` around the frame: colour bar and title.
MAP_MARGIN_PX = (150, 50)
#: Long side below which a frame is upscaled (by an integer factor) for legible labels.
MIN_DISPLAY_PX = 640
#: Width above which a frame is shrunk for display.
MAX_DISPLAY_WIDTH_PX = 1280

#: Artifact key -> file name, in the order :func:`render_all` writes them.
ARTIFACT_FILES: dict[str, str] = {
    "mask": "mask.png",
    "overlay": "overlay.png",
    "frequency_map": "frequency_map.png",
    "spectrum": "spectrum.png",
    "displacement": "displacement.png",
    "ringdown": "ringdown.png",
}

NO_OBJECT_NOTE = "no object found"
#: Colour maps of the frequency map and of the spectrogram (dB).
FREQUENCY_CMAP = "viridis"
SPECTROGRAM_CMAP = "magma"
#: Dynamic range of the spectrogram, dB below its maximum.
SPECTROGRAM_RANGE_DB = 40.0

# Distinct, saturated colours that stay visible on white plots and (with a dark halo) on camera frames.
_PALETTE: tuple[tuple[int, int, int], ...] = (
    (255, 127, 14),  # orange
    (31, 119, 180),  # blue
    (44, 160, 44),  # green
    (214, 39, 40),  # red
    (148, 103, 189),  # purple
    (23, 190, 207),  # cyan
    (227, 119, 194),  # pink
    (188, 189, 34),  # olive
    (140, 86, 75),  # brown
)

_FONT = 12
_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
_SMALL = 10.5
_TITLE = 14


# --------------------------------------------------------------------------------------------- helpers


def object_color(object_id: int) -> tuple[int, int, int]:
    """The colour of object ``object_id`` in every image.

    Parameters
    ----------
    object_id : int
        The object's label (1, 2, ...).

    Returns
    -------
    (r, g, b) : tuple of int in [0, 255]
        Ids beyond the palette's nine colours reuse it cyclically.
    """
    return _PALETTE[(int(object_id) - 1) % len(_PALETTE)]


def _mpl_color(object_id: int) -> tuple[float, float, float]:
    r, g, b = object_color(object_id)
    return (r / 255.0, g / 255.0, b / 255.0)


def display_scale(width: int, height: int) -> float:
    """Factor from frame pixels to overlay / frequency-map pixels.

    An integer >= 2 when the frame's long side is below :data:`MIN_DISPLAY_PX` (so labels stay legible),
    ``MAX_DISPLAY_WIDTH_PX / width`` when the frame is wider than :data:`MAX_DISPLAY_WIDTH_PX`, else 1.
    """
    if width <= 0 or height <= 0:
        raise ValueError(f"frame size {width}x{height} is empty")
    long_side = max(width, height)
    if long_side < MIN_DISPLAY_PX:
        return float(math.ceil(MIN_DISPLAY_PX / long_side))
    if width > MAX_DISPLAY_WIDTH_PX:
        return MAX_DISPLAY_WIDTH_PX / width
    return 1.0


def display_size(width: int, height: int) -> tuple[int, int]:
    """(width, height) in pixels of ``overlay.png`` for a frame of ``width`` x ``height``."""
    s = display_scale(width, height)
    return (max(1, round(width * s)), max(1, round(height * s)))


def frequency_map_size(width: int, height: int) -> tuple[int, int]:
    """(width, height) in pixels of ``frequency_map.png`` for a frame of ``width`` x ``height``."""
    dw, dh = display_size(width, height)
    return (dw + MAP_MARGIN_PX[0], dh + MAP_MARGIN_PX[1])


def panel_figure_size(n_objects: int) -> tuple[int, int]:
    """(width, height) in pixels of ``displacement.png`` and ``ringdown.png`` for ``n_objects`` objects.

    1000 x 600 for zero to two objects, then :data:`PANEL_HEIGHT_PX` taller per object.
    """
    n = max(1, n_objects)
    return (PLOT_SIZE_PX[0], max(PLOT_SIZE_PX[1], 100 + PANEL_HEIGHT_PX * n))


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".png")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        # mkstemp creates 0600 files; artifacts are ordinary files, as the umask asks.
        os.chmod(tmp, artifact_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _write_rgb_png(path: Path, rgb: NDArray[np.uint8], *, photo: bool) -> None:
    """Encode fast: level 1, with the filter that suits the content (measured on typical images).

    Camera frames (``photo``) encode fastest and smallest with the SUB filter and run-length coding;
    plots (large flat areas) with no filter at all, for about the same size as the default.
    """
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER]
    if photo:
        params += [cv2.IMWRITE_PNG_FILTER_SUB, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    else:
        params += [cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
    if not ok:  # pragma: no cover - OpenCV always encodes 3-channel uint8 arrays
        raise OSError(f"could not encode {path.name}")
    _atomic_write_bytes(path, buf.tobytes())


@functools.cache
def _matplotlib() -> None:
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


#: Held while :func:`_matplotlib` imports, so that one thread's temporary changes are not taken by another
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
    _matplotlib()
    from matplotlib.figure import Figure

    face = (1.0, 1.0, 1.0, 0.0) if transparent else "white"
    fig = Figure(figsize=(size_px[0] / DPI, size_px[1] / DPI), dpi=DPI, facecolor=face)
    canvas = caching_canvas()(fig)  # an Agg canvas that rasterises each string once per process
    return fig, canvas


Underlay = tuple[NDArray[np.uint8], int, int]


@dataclass(frozen=True)
class _Image:
    """A rendered image: RGB pixels and whether it is photo-like (for the PNG filter)."""

    rgb: NDArray[np.uint8]
    photo: bool


def _finish(canvas: Any, size_px: tuple[int, int], *, underlays: Sequence[Underlay] = ()) -> _Image:
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
        return _Image(np.asarray(cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB), np.uint8), photo=False)
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
    return _Image(page, photo=bool(underlays))


def _write_image(path: Path, image: _Image) -> Path:
    _write_rgb_png(path, image.rgb, photo=image.photo)
    return path


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


def _colour_bar(
    fig: Any,
    size: tuple[int, int],
    *,
    x: int,
    y: int,
    height: int,
    vmin: float,
    vmax: float,
    cmap: str,
    label: str,
    marks: Sequence[tuple[float, tuple[int, int, int]]] = (),
    bins: int = 6,
    width: int = 20,
) -> Underlay:
    """A vertical colour bar as an underlay image (bar, frame, ticks, marks) plus figure texts.

    ``(x, y)`` is the bar's top-left pixel; ``marks`` are (value, rgb) lines across the bar (the
    objects' frequencies). Returns the underlay to pass to :func:`_finish`.
    """
    W, H = size
    tick_len = 6
    img = np.full((height, width + tick_len, 3), 255, np.uint8)
    rows = vmax - (np.arange(height) + 0.5) * ((vmax - vmin) / height)
    img[:, :width] = _colour_lut(cmap)[_colour_index(rows, vmin, vmax)][:, None, :]
    img[0, :width] = img[-1, :width] = 0
    img[:, 0] = img[:, width - 1] = 0

    def row_of(value: float) -> int:
        return round((vmax - value) / (vmax - vmin) * (height - 1))

    for value, rgb in marks:
        if vmin <= value <= vmax:
            r = row_of(value)
            img[max(r - 3, 0) : r + 4, :width] = 0
            img[max(r - 1, 0) : r + 2, 1 : width - 1] = rgb
    ticks, decimals = _tick_values(vmin, vmax, bins)
    for value in ticks:
        r = row_of(value)
        img[max(r - 1, 0) : r + 1, width:] = 0
        fig.text(
            (x + width + tick_len + 4) / W,
            1 - (y + r) / H,
            _tick_label(value, decimals),
            ha="left",
            va="center",
            fontsize=_SMALL,
        )
    fig.text(
        (x + width + tick_len + 40) / W,
        1 - (y + height / 2) / H,
        label,
        ha="left",
        va="center",
        rotation=90,
        fontsize=_FONT,
    )
    return (img, x, y)


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


def _finite(x: float | None) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def format_quantity(value: float | None, sd: float | None, unit: str) -> str:
    """``"4.998 ± 0.012 Hz"``: the value rounded to its uncertainty's second significant digit.

    Without a (finite, positive) uncertainty the value gets four significant digits; None or NaN gives
    ``"n/a"``. Very large or small values share a power of ten: ``"(1.50 ± 0.02)×10⁷ N/m"``.
    """
    v = _finite(value)
    if v is None:
        return "n/a"
    s = _finite(sd)
    if s is None or s <= 0:
        return f"{v:.4g} {unit}".rstrip()
    exponent = math.floor(math.log10(max(abs(v), s)))
    scale = 0
    if exponent >= 6 or exponent <= -4:
        scale = exponent
        v, s = v / 10.0**scale, s / 10.0**scale
    decimals = min(max(0, 1 - math.floor(math.log10(s))), 9)
    text = f"{v:.{decimals}f} ± {s:.{decimals}f}"
    if scale:
        text = f"({text})×10{str(scale).translate(_SUPERSCRIPT)}"
    return f"{text} {unit}".rstrip()


def object_label(obj: ObjectMeasurement) -> str:
    """The overlay's label of an object: id, f, k and m with units and uncertainties where known."""
    return "\n".join(
        (
            f"#{obj.id}  f = {format_quantity(obj.eigenfrequency_hz, obj.eigenfrequency_sd_hz, 'Hz')}",
            f"k = {format_quantity(obj.stiffness_n_per_m, obj.stiffness_sd, 'N/m')}",
            f"m = {format_quantity(obj.mass_kg, obj.mass_sd, 'kg')}",
        )
    )


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


def _axis(
    ax: Any,
    size: tuple[int, int],
    *,
    xlabel: str,
    ylabel: str,
    x_bins: int = 6,
    y_bins: int = 5,
    log_y: bool = False,
    grid: bool = True,
    y_ticks: bool = True,
) -> None:
    """Ticks, tick labels, grid and axis labels of ``ax`` as a handful of artists.

    matplotlib's own ticks cost about a millisecond and a half each to create and lay out; these are
    drawn as one line collection per axis and one text per label, at fixed pixel offsets. Call it
    once the axes' limits are final.
    """
    from matplotlib.ticker import NullLocator

    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(NullLocator())
        axis.set_minor_locator(NullLocator())
    W, H = size
    box = ax.get_position()
    ax_w, ax_h = box.width * W, box.height * H
    tick = 5.0
    x0, x1 = sorted(ax.get_xlim())
    y0, y1 = sorted(ax.get_ylim())
    ax.set_xlim(x0, x1)  # freeze: the artists below must not move the limits
    ax.set_ylim(y0, y1)
    xt, xd = _tick_values(x0, x1, x_bins)
    if log_y:
        lo_e, hi_e = math.ceil(math.log10(y0) - 1e-9), math.floor(math.log10(y1) + 1e-9)
        step = max(1, math.ceil((hi_e - lo_e + 1) / 8))
        yt = [10.0**e for e in range(lo_e, hi_e + 1, step)]
        ylabels = [_log_tick(v) for v in yt]
    elif y_ticks:
        yt, yd = _tick_values(y0, y1, y_bins)
        ylabels = [_tick_label(v, yd) for v in yt]
    else:
        yt, ylabels = [], []
    xtrans, ytrans = ax.get_xaxis_transform(), ax.get_yaxis_transform()
    nan = float("nan")
    if grid:
        gx = [v for x in xt for v in (x, x, nan)]
        gy = [v for _ in xt for v in (0.0, 1.0, nan)]
        ax.plot(gx, gy, transform=xtrans, color="0.88", linewidth=0.8, zorder=0.5)
        gx = [v for _ in yt for v in (0.0, 1.0, nan)]
        gy = [v for y in yt for v in (y, y, nan)]
        ax.plot(gx, gy, transform=ytrans, color="0.88", linewidth=0.8, zorder=0.5)
    mx = [v for x in xt for v in (x, x, nan)]
    my = [v for _ in xt for v in (0.0, -tick / ax_h, nan)]
    ax.plot(mx, my, transform=xtrans, color="black", linewidth=0.8, clip_on=False)
    mx = [v for _ in yt for v in (0.0, -tick / ax_w, nan)]
    my = [v for y in yt for v in (y, y, nan)]
    ax.plot(mx, my, transform=ytrans, color="black", linewidth=0.8, clip_on=False)
    for x in xt:
        ax.text(
            x,
            -(tick + 3) / ax_h,
            _tick_label(x, xd),
            transform=xtrans,
            ha="center",
            va="top",
            fontsize=_SMALL,
        )
    for y, label in zip(yt, ylabels, strict=True):
        ax.text(-(tick + 3) / ax_w, y, label, transform=ytrans, ha="right", va="center", fontsize=_SMALL)
    ax.text(0.5, -(tick + 24) / ax_h, xlabel, transform=ax.transAxes, ha="center", va="top", fontsize=_FONT)
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


def _legend(ax: Any, size: tuple[int, int], *, fontsize: float = _SMALL) -> None:
    """The labelled artists of ``ax`` listed in a box at its upper right corner.

    Equivalent to ``ax.legend(loc="upper right")`` for lines, markers and spans, at a fraction of the
    cost (matplotlib's legend lays out through a tree of offset boxes).
    """
    from matplotlib.font_manager import FontProperties
    from matplotlib.lines import Line2D
    from matplotlib.patches import FancyBboxPatch, Rectangle

    handles, labels = ax.get_legend_handles_labels()
    if not handles:
        return
    W, H = size
    box = ax.get_position()
    ax_w, ax_h = box.width * W, box.height * H
    renderer = ax.figure.canvas.get_renderer()
    prop = FontProperties(size=fontsize)
    widths = [renderer.get_text_width_height_descent(t, prop, ismath=False)[0] for t in labels]
    line_h = fontsize * DPI / 72 * 1.45
    pad, sample, gap, margin = 8.0, 30.0, 8.0, 10.0
    width = pad + sample + gap + max(widths) + pad
    height = 2 * pad + line_h * len(labels) - (line_h - fontsize * DPI / 72)
    right, top = ax_w - margin, ax_h - margin

    def at(x_px: float, y_px: float) -> tuple[float, float]:
        return (x_px / ax_w, y_px / ax_h)

    left, bottom = right - width, top - height
    ax.add_patch(
        FancyBboxPatch(
            at(left, bottom),
            width / ax_w,
            height / ax_h,
            boxstyle="round,pad=0,rounding_size=0.008",
            transform=ax.transAxes,
            facecolor="white",
            edgecolor="0.8",
            alpha=0.92,
            zorder=10,
            clip_on=False,
        )
    )
    for i, (handle, label) in enumerate(zip(handles, labels, strict=True)):
        y = top - pad - (i + 0.5) * line_h + (line_h - fontsize * DPI / 72) / 2
        x0 = left + pad
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
                    sample / ax_w,
                    12 / ax_h,
                    transform=ax.transAxes,
                    facecolor=handle.get_facecolor(),
                    edgecolor="none",
                    zorder=11,
                    clip_on=False,
                )
            )
        ax.text(
            *at(x0 + sample + gap, y),
            label,
            transform=ax.transAxes,
            ha="left",
            va="center",
            fontsize=fontsize,
            zorder=12,
            clip_on=False,
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


def write_label_png(path: str | Path, labels: NDArray[np.integer]) -> Path:
    """Write a label image as a palette PNG, atomically: pixel values are the labels, and any image viewer
    shows each object in its colour (:func:`object_color`) on black.

    Parameters
    ----------
    path : path-like
    labels : ndarray of int, shape (H, W)
        0 background, i = object i. Up to 255 objects: an 8-bit palette image (PNG colour type 3) whose
        index is the label; beyond that a 16-bit grey image of the labels (PNG allows no larger palette).

    Returns
    -------
    Path
    """
    import struct
    import zlib

    path = Path(path)
    top = int(labels.max()) if labels.size else 0
    if top >= 256:
        import cv2

        ok, buf = cv2.imencode(".png", labels.astype(np.uint16))
        if not ok:  # pragma: no cover - OpenCV always encodes 2-D integer arrays
            raise OSError(f"could not encode {path.name}")
        _atomic_write_bytes(path, buf.tobytes())
        return path
    if labels.ndim != 2:
        raise ValueError(f"labels must be 2-D (H, W), got shape {labels.shape}")
    height, width = labels.shape
    # One colour per possible label (index 0 black): viewers show objects beyond ``top`` consistently too.
    palette = bytes([0, 0, 0]) + b"".join(bytes(object_color(i)) for i in range(1, 256))
    rows = np.zeros((height, width + 1), np.uint8)  # filter type 0 (None) before each row
    rows[:, 1:] = labels
    body = zlib.compress(rows.tobytes(), 6)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 3, 0, 0, 0)  # 8-bit, colour type 3 (palette)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"PLTE", palette) + chunk(b"IDAT", body)
    _atomic_write_bytes(path, png + chunk(b"IEND", b""))
    return path


def write_overlay_png(path: str | Path, analysis: Analysis) -> Path:
    """The representative frame with each object outlined in its colour and labelled with id, f, k, m.

    Parameters
    ----------
    path : path-like
    analysis : Analysis
        Uses ``frame_rgb`` (uint8, (H, W, 3)), ``labels`` (uint16, (H, W)) and ``objects``.

    Returns
    -------
    Path
        An RGB PNG of :func:`display_size` ``(W, H)`` pixels. With no object, the frame carries a
        "no object found" note.
    """
    return _write_image(Path(path), _draw_overlay(analysis))


def _draw_overlay(analysis: Analysis) -> _Image:
    frame = _frame(analysis)
    h, w = frame.shape[:2]
    size = display_size(w, h)
    scale = size[0] / w
    rgb = np.array(_resize(frame, size, nearest=False), dtype=np.uint8, copy=True)
    ids = [o.id for o in analysis.objects]
    line = max(2, round(1.5 * max(1.0, scale)))
    _draw_outlines(rgb, analysis.labels, ids, scale=scale, width=line)

    fig, canvas = _figure(size, transparent=True)
    W, H = size
    fontsize = 11 if size[0] >= 600 else 9
    for obj in analysis.objects:
        x, y, _w, bh = obj.bbox_px
        # Label above the box when there is room, else inside its top; clamped to the image.
        tx = min(max(x * scale, 4.0), size[0] * 0.62)
        ty = y * scale - 6
        va = "bottom"
        if ty < 70:
            ty, va = (y + bh) * scale + 6, "top"
            if ty > size[1] - 70:
                ty, va = y * scale + 6, "top"
        fig.text(
            tx / W,
            1 - ty / H,
            object_label(obj),
            ha="left",
            va=va,
            fontsize=fontsize,
            color="white",
            family="DejaVu Sans",
            bbox={
                "boxstyle": "round,pad=0.35",
                "facecolor": (0, 0, 0, 0.65),
                "edgecolor": _mpl_color(obj.id),
                "linewidth": 2.0,
            },
        )
    header = f"{analysis.method} method · {analysis.fps:g} fps · frames {analysis.frames_used[0]}–" + (
        f"{analysis.frames_used[1]}"
    )
    fig.text(
        4 / W,
        4 / H,
        header,
        ha="left",
        va="bottom",
        fontsize=9,
        color="white",
        bbox={"boxstyle": "square,pad=0.25", "facecolor": (0, 0, 0, 0.5), "edgecolor": "none"},
    )
    if not analysis.objects:
        _note(fig, _no_object_message(analysis, width=max(30, W // 11)), color="0.1", fontsize=12)
    return _finish(canvas, size, underlays=[(rgb, 0, 0)])


def write_frequency_map_png(path: str | Path, analysis: Analysis) -> Path:
    """Per-pixel dominant frequency over the frame, with a colour bar in Hz.

    Pixels whose peak does not stand above the noise (``frequency_map_valid`` False) are shown as the
    faded grey frame; object outlines are drawn in their colours.

    Parameters
    ----------
    path : path-like
    analysis : Analysis
        Uses ``frequency_map_hz`` (float32, (h, w), on the flow grid), ``frequency_map_valid`` (bool,
        (h, w)), ``band_hz``, ``frame_rgb`` (uint8, (H, W, 3)) and ``labels``.

    Returns
    -------
    Path
        An RGB PNG of :func:`frequency_map_size` ``(W, H)`` pixels.
    """
    return _write_image(Path(path), _draw_frequency_map(analysis))


def _draw_frequency_map(analysis: Analysis) -> _Image:
    import cv2

    frame = _frame(analysis)
    h, w = frame.shape[:2]
    dsize = display_size(w, h)
    size = frequency_map_size(w, h)
    fmap = np.nan_to_num(np.asarray(analysis.frequency_map_hz, np.float32), nan=0.0)
    valid = np.asarray(analysis.frequency_map_valid, bool) & np.isfinite(
        np.asarray(analysis.frequency_map_hz, np.float32)
    )
    lo, hi = (float(b) for b in analysis.band_hz)
    if not hi > lo:
        hi = lo + 1.0
    gray = cv2.cvtColor(_resize(frame, dsize, nearest=False), cv2.COLOR_RGB2GRAY).astype(np.float32)
    # Colours on the flow grid, then nearest-neighbour up to the display: each grid cell stays one colour.
    grid_rgb = np.ascontiguousarray(_colour_lut(FREQUENCY_CMAP)[_colour_index(fmap, lo, hi)])
    colours = _resize(grid_rgb, dsize, nearest=True).astype(np.float32)
    valid_d = _resize(valid.astype(np.uint8), dsize, nearest=True).astype(bool)[..., None]
    shade = (0.55 + (0.45 / 255.0) * gray)[..., None]  # keep some of the frame's texture in the colours
    muted = (150.0 + 0.35 * gray)[..., None]
    rgb8 = np.where(valid_d, colours * shade, muted).astype(np.uint8)
    ids = [o.id for o in analysis.objects]
    _draw_outlines(rgb8, analysis.labels, ids, scale=dsize[0] / w, width=2)

    fig, canvas = _figure(size, transparent=True)
    top = MAP_MARGIN_PX[1] - 10
    left = 10
    frac = float(valid.mean()) if valid.size else 0.0
    fig.text(
        left / size[0],
        1 - 6 / size[1],
        f"Dominant frequency per pixel ({frac:.0%} above noise; grey = below the noise floor)",
        ha="left",
        va="top",
        fontsize=_FONT if size[0] >= 700 else _SMALL,
    )
    marks = [
        (f, object_color(o.id)) for o in analysis.objects if (f := _finite(o.eigenfrequency_hz)) is not None
    ]
    bar = _colour_bar(
        fig,
        size,
        x=left + dsize[0] + 16,
        y=top + 10,
        height=max(dsize[1] - 20, 20),
        vmin=lo,
        vmax=hi,
        cmap=FREQUENCY_CMAP,
        label="dominant frequency (Hz)",
        marks=marks,
    )
    if not analysis.objects:
        centre = ((left + dsize[0] / 2) / size[0], (size[1] - top - dsize[1] / 2) / size[1])
        _note(fig, NO_OBJECT_NOTE, color="0.1", xy=centre)
    return _finish(canvas, size, underlays=[(rgb8, left, top), bar])


def _noise_floor(analysis: Analysis) -> tuple[NDArray[np.float64] | None, float | None]:
    """(noise spectrum on ``frequencies_hz`` if the analysis has one, else a flat floor level)."""
    for name in ("noise_power", "noise_spectrum", "background_power", "noise"):
        value = getattr(analysis, name, None)
        if value is None:
            continue
        arr = np.asarray(value, np.float64)
        if arr.shape == np.shape(analysis.frequencies_hz):
            return arr, None
    freqs = np.asarray(analysis.frequencies_hz, np.float64)
    power = np.asarray(analysis.power, np.float64)
    lo, hi = analysis.band_hz
    inside = (freqs >= lo) & (freqs <= hi) & np.isfinite(power) & (power > 0)
    if not inside.any():
        return None, None
    # The median bin of the band: peaks occupy few bins, so this is the level of the floor.
    return None, float(np.median(power[inside]))


def _rejected_peaks(analysis: Analysis) -> list[tuple[float, str]]:
    """(frequency_hz, reason) of peaks the analysis rejected as artefacts, when it records them."""
    out: list[tuple[float, str]] = []
    for name in ("rejected_peaks", "artefact_peaks", "artifact_peaks"):
        for item in getattr(analysis, name, None) or []:
            f = getattr(item, "frequency_hz", None)
            if f is None and isinstance(item, int | float):
                f = float(item)
            if f is None and isinstance(item, Sequence) and item and isinstance(item[0], int | float):
                f = float(item[0])
            if f is None or not math.isfinite(f):
                continue
            reason = getattr(item, "reason", None) or getattr(item, "code", None) or ""
            out.append((float(f), str(reason)))
        if out:
            break
    return out


def write_spectrum_png(path: str | Path, analysis: Analysis) -> Path:
    """The summed motion spectrum on a log scale with its landmarks.

    Marks each object's eigenfrequency and harmonics (in the object's colour), the noise floor (the
    analysis's noise spectrum when it has one, else the band's median level), rejected artefact peaks
    (when the analysis records them) and the part of the spectrum outside the analysed band.

    Parameters
    ----------
    path : path-like
    analysis : Analysis
        Uses ``frequencies_hz`` and ``power`` (float64, (F,)), ``band_hz``, ``objects``, ``fps``.

    Returns
    -------
    Path
        An RGB PNG of :data:`PLOT_SIZE_PX` (1000 x 600) pixels.
    """
    return _write_image(Path(path), _draw_spectrum(analysis))


def _draw_spectrum(analysis: Analysis) -> _Image:
    fig, canvas = _figure(PLOT_SIZE_PX)
    ax = fig.add_axes((0.085, 0.11, 0.885, 0.8))
    freqs = np.asarray(analysis.frequencies_hz, np.float64)
    power = np.asarray(analysis.power, np.float64)
    ok = np.isfinite(power) & (power > 0)
    nyquist = _sample_rate(analysis) / 2
    ax.set_xlim(0, nyquist)
    ax.set_yscale("log")
    _title(
        ax,
        f"Summed motion spectrum ({analysis.method} method, {analysis.fps:g} fps, "
        f"{analysis.frames_used[1] - analysis.frames_used[0]} frames)",
        fontsize=_TITLE,
    )
    lo, hi = analysis.band_hz
    in_band = ok & (freqs >= lo) & (freqs <= hi)
    if ok.any():
        ax.plot(freqs[ok], power[ok], color="0.15", linewidth=1.6, label="summed spectrum", zorder=3)
        # The range follows the band: the DC bin and the edges outside it may be far below.
        ref = power[in_band] if in_band.any() else power[ok]
        top = float(ref.max())
        bottom = float(ref.min())
    else:
        top, bottom = 1.0, 1e-3
    if lo > 0:
        ax.axvspan(0, lo, color="0.9", zorder=0, label="outside analysed band")
    if hi < nyquist:
        ax.axvspan(hi, nyquist, color="0.9", zorder=0, label=None if lo > 0 else "outside analysed band")

    noise_curve, floor = _noise_floor(analysis)
    if noise_curve is not None:
        good = np.isfinite(noise_curve) & (noise_curve > 0)
        ax.plot(
            freqs[good], noise_curve[good], color="0.45", linestyle="--", linewidth=1.3, label="noise floor"
        )
        good_band = good & (freqs >= lo) & (freqs <= hi)
        if good_band.any():
            bottom = min(bottom, float(noise_curve[good_band].min()))
    elif floor is not None:
        ax.axhline(floor, color="0.45", linestyle="--", linewidth=1.3, label="noise floor (band median)")

    def power_at(f: float) -> float:
        if not ok.any():
            return top
        return float(np.interp(f, freqs[ok], power[ok]))

    for obj in analysis.objects:
        colour = _mpl_color(obj.id)
        f = _finite(obj.eigenfrequency_hz)
        if f is None:
            continue
        ax.axvline(f, color=colour, linewidth=2.2, zorder=2)
        ax.plot(
            [f],
            [power_at(f)],
            marker="o",
            markersize=9,
            color=colour,
            markeredgecolor="black",
            linestyle="none",
            zorder=4,
            label=f"#{obj.id} f = {format_quantity(f, obj.eigenfrequency_sd_hz, 'Hz')}",
        )
        harmonics = [h for h in obj.harmonics_hz if math.isfinite(h) and 0 < h <= nyquist]
        for i, hf in enumerate(harmonics):
            ax.axvline(
                hf,
                color=colour,
                linestyle=":",
                linewidth=2.0,
                zorder=2,
                label=f"#{obj.id} harmonics" if i == 0 else None,
            )
    rejected = [(f, r) for f, r in _rejected_peaks(analysis) if 0 <= f <= nyquist]
    if rejected:
        ax.plot(
            [f for f, _ in rejected],
            [power_at(f) * 1.6 for f, _ in rejected],
            marker="x",
            markersize=11,
            markeredgewidth=2.5,
            color="crimson",
            linestyle="none",
            zorder=5,
            label="rejected artefact peak",
        )
    # Headroom above the highest peak for the legend.
    ax.set_ylim(bottom / 3.0, top * (top / bottom) ** 0.35 * 3.0 if top > bottom else top * 10.0)
    _axis(
        ax,
        PLOT_SIZE_PX,
        xlabel="frequency (Hz)",
        ylabel="summed motion power (px², log scale)",
        x_bins=8,
        log_y=True,
    )
    if not analysis.objects:
        _note(ax, _no_object_message(analysis))
    _legend(ax, PLOT_SIZE_PX)
    return _finish(canvas, PLOT_SIZE_PX)


def _metres_per_px(obj: ObjectMeasurement) -> float | None:
    a_m, a_px = _finite(obj.amplitude_m), _finite(obj.amplitude_px)
    if a_m is None or a_px is None or a_m <= 0 or a_px <= 0:
        return None
    return a_m / a_px


def _displacement_series(
    obj: ObjectMeasurement,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, str, float] | None:
    """(measured, model, unit, factor from the stored series to the unit) or None without a series."""
    disp_m = getattr(obj, "displacement_m", None)
    if disp_m is not None:
        model_m = getattr(obj, "model_displacement_m", None)
        measured = np.asarray(disp_m, np.float64) * 1e3
        model = None if model_m is None else np.asarray(model_m, np.float64) * 1e3
        return measured, model, "mm", 1e3
    if obj.displacement_px is None:
        return None
    measured = np.asarray(obj.displacement_px, np.float64)
    model = None if obj.model_displacement_px is None else np.asarray(obj.model_displacement_px, np.float64)
    scale = _metres_per_px(obj)
    if scale is not None:
        factor = scale * 1e3
        return measured * factor, None if model is None else model * factor, "mm", factor
    return measured, model, "px", 1.0


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


def write_displacement_png(path: str | Path, analysis: Analysis) -> Path:
    """Each object's displacement against time with the fitted damped oscillation and the release instant.

    Displacement is in millimetres when the object's amplitude in metres is known (from
    ``displacement_m`` or ``amplitude_m / amplitude_px``), in image pixels otherwise.

    Parameters
    ----------
    path : path-like
    analysis : Analysis
        Uses each object's ``displacement_px`` and ``model_displacement_px`` (float64, (N + 1,); the model
        NaN before release), ``release_time_s``, ``fps`` and ``frames_used``.

    Returns
    -------
    Path
        An RGB PNG of :func:`panel_figure_size` ``(len(objects))`` pixels; objects without a series (e.g.
        the paper method) and clips without objects get a note instead of a curve.
    """
    return _write_image(Path(path), _draw_displacement(analysis))


def _draw_displacement(analysis: Analysis) -> _Image:
    size = panel_figure_size(len(analysis.objects))
    fig, canvas = _figure(size)
    fig.suptitle("Displacement along the motion axis", fontsize=_TITLE, y=1 - 12 / size[1], va="top")
    if not analysis.objects:
        ax = _panels(fig, 1)[0]
        ax.set_xlim(*_window_span_s(analysis))
        _axis(ax, size, xlabel="time (s)", ylabel="displacement (px)", y_ticks=False)
        _note(ax, _no_object_message(analysis))
        return _finish(canvas, size)
    axes = _panels(fig, len(analysis.objects))
    for ax, obj in zip(axes, analysis.objects, strict=True):
        colour = _mpl_color(obj.id)
        series = _displacement_series(obj)
        if series is None:
            ax.set_xlim(*_window_span_s(analysis))
            _axis(ax, size, xlabel="time (s)", ylabel="displacement", y_ticks=False)
            _note(ax, f"#{obj.id}: no displacement series ({analysis.method} method)")
            continue
        measured, model, unit, _ = series
        t = _times_s(analysis, len(measured))
        ax.plot(
            t,
            measured,
            color=colour,
            linewidth=2.0,
            marker="o",
            markersize=4,
            label=f"#{obj.id} measured",
            zorder=2,
        )
        if model is not None and len(model) == len(t) and np.isfinite(model).any():
            ax.plot(
                t,
                model,
                color="black",
                linestyle="--",
                linewidth=1.2,
                label="damped-oscillation fit",
                zorder=3,
            )
        release = _finite(obj.release_time_s)
        if release is not None:
            ax.axvline(release, color=colour, linestyle=":", linewidth=2.2, label=f"release {release:.3f} s")
        ax.set_xlim(float(t[0]), float(t[-1]))
        _axis(ax, size, xlabel="time (s)", ylabel=f"displacement ({unit})")
        zeta = _finite(obj.damping_ratio)
        info = f"#{obj.id}: f = {format_quantity(obj.eigenfrequency_hz, obj.eigenfrequency_sd_hz, 'Hz')}"
        if zeta is not None:
            info += f", ζ = {format_quantity(zeta, obj.damping_ratio_sd, '')}"
        _title(ax, info)
        _legend(ax, size)
    return _finish(canvas, size)


def ringdown_spectrogram(
    displacement: NDArray[np.floating[Any]],
    *,
    fps: float,
    window: int | None = None,
    hop: int = 1,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Short-time power spectrum of the velocity of a displacement series.

    The velocity (first difference times ``fps``, mean removed) is made analytic (negative frequencies
    removed, so an oscillation gives one ridge at f instead of beats between +f and -f in short
    windows), padded with ``window / 2`` zeros at both ends so that segments centre on every ``hop``-th
    sample, Hann-windowed, zero-padded to 4x the window and Fourier transformed.

    Parameters
    ----------
    displacement : ndarray of float, shape (N + 1,)
        Displacement per frame (any length unit); NaNs are treated as 0.
    fps : float
        Sample rate, frames per second.
    window : int, optional
        Segment length in samples; default the largest power of two <= N / 3, clipped to [8, 64].
    hop : int
        Samples between segment centres.

    Returns
    -------
    times_s : ndarray of float64, shape (T,)
        Segment centres, seconds from the series' first sample.
    frequencies_hz : ndarray of float64, shape (F,)
        0 to ``fps / 2``.
    power : ndarray of float64, shape (F, T)
        Power of the velocity, (unit/s)² per bin.
    """
    if not (math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps={fps} must be a positive number")
    x = np.nan_to_num(np.asarray(displacement, np.float64).ravel())
    v = np.diff(x) * fps
    n = len(v)
    if n < 4:
        raise ValueError(f"a spectrogram needs at least 5 displacement samples, got {len(x)}")
    v = v - v.mean()
    if window is None:
        window = 1 << max(3, min(6, int(math.log2(max(n // 3, 1)))))
    window = max(4, min(int(window), n))
    hop = max(1, int(hop))
    # Analytic signal: keep DC and Nyquist, double the positive frequencies, drop the negative ones.
    # Computed on the series zero-padded to twice its length, so its start does not wrap onto its end.
    m = 2 * n
    gain = np.zeros(m)
    gain[0] = gain[n] = 1.0
    gain[1:n] = 2.0
    analytic = np.fft.ifft(np.fft.fft(v, m) * gain)[:n]
    half = window // 2
    padded = np.concatenate([np.zeros(half, complex), analytic, np.zeros(window - half, complex)])
    centres = np.arange(0, n + 1, hop)
    segments = np.lib.stride_tricks.sliding_window_view(padded, window)[centres]
    nfft = 4 * window
    spec = np.fft.fft(segments * np.hanning(window), n=nfft, axis=1)[:, : nfft // 2 + 1]
    power = (np.abs(spec) ** 2).T
    freqs = np.arange(nfft // 2 + 1) * (fps / nfft)
    # Segment k spans velocity samples k - half .. k - half + window - 1; velocity sample i lies between
    # frames i and i + 1, so the segment's centre is at frame k (for an even window).
    times = centres / fps
    return times.astype(np.float64), freqs.astype(np.float64), power.astype(np.float64)


def write_ringdown_png(path: str | Path, analysis: Analysis) -> Path:
    """The spectrogram of each object's ring-down, with its eigenfrequency and release instant.

    The spectrogram comes from the analysis when it has one, else from :func:`ringdown_spectrogram` of
    the object's ``displacement_px``; power is shown in dB relative to each panel's maximum
    (:data:`SPECTROGRAM_RANGE_DB` range).

    Parameters
    ----------
    path : path-like
    analysis : Analysis

    Returns
    -------
    Path
        An RGB PNG of :func:`panel_figure_size` ``(len(objects))`` pixels; objects without a series (e.g.
        the paper method) and clips without objects get a note instead.
    """
    return _write_image(Path(path), _draw_ringdown(analysis))


def _draw_ringdown(analysis: Analysis) -> _Image:
    size = panel_figure_size(len(analysis.objects))
    fig, canvas = _figure(size, transparent=True)
    fig.suptitle(
        "Ring-down spectrogram (short-time spectrum of the velocity)",
        fontsize=_TITLE,
        y=1 - 12 / size[1],
        va="top",
    )
    nyquist = _sample_rate(analysis) / 2
    if not analysis.objects:
        ax = _panels(fig, 1, right_px=110.0)[0]
        ax.set_xlim(*_window_span_s(analysis))
        ax.set_ylim(0, nyquist)
        _axis(ax, size, xlabel="time (s)", ylabel="frequency (Hz)", y_bins=4, grid=False)
        _note(ax, _no_object_message(analysis))
        return _finish(canvas, size)
    axes = _panels(fig, len(analysis.objects), right_px=110.0)
    lut = _colour_lut(SPECTROGRAM_CMAP)
    underlays: list[Underlay] = []
    for ax, obj in zip(axes, analysis.objects, strict=True):
        colour = _mpl_color(obj.id)
        ax.set_ylim(0, nyquist)
        _title(ax, f"#{obj.id}")
        spectrogram = _spectrogram_of(analysis, obj)
        if spectrogram is None:
            ax.set_xlim(*_window_span_s(analysis))
            _axis(ax, size, xlabel="time (s)", ylabel="frequency (Hz)", y_bins=4, grid=False)
            _note(ax, f"#{obj.id}: no displacement series ({analysis.method} method)")
            continue
        times, freqs, power = spectrogram
        peak = float(np.max(power)) if power.size else 0.0
        db = 10 * np.log10(np.maximum(power, 1e-300) / max(peak, 1e-300))
        xlim = (float(times[0]), float(times[-1])) if len(times) > 1 else _window_span_s(analysis)
        ylim = (0.0, min(nyquist, float(freqs[-1])))
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        _axis(ax, size, xlabel="time (s)", ylabel="frequency (Hz)", y_bins=4, grid=False)
        # The spectrogram is rasterised here and laid under the (transparent) axes.
        ax.patch.set_visible(False)
        x0, y0, x1, y1 = _axes_box_px(ax, size)
        flat = _raster(db, times, freqs, xlim=xlim, ylim=ylim, shape=(y1 - y0, x1 - x0))
        shown = db.ravel()[flat]
        underlays.append((lut[_colour_index(shown, -SPECTROGRAM_RANGE_DB, 0.0)], x0, y0))
        f = _finite(obj.eigenfrequency_hz)
        if f is not None:
            ax.axhline(
                f,
                color=colour,
                linestyle="--",
                linewidth=2.0,
                label=f"#{obj.id} f = {format_quantity(f, obj.eigenfrequency_sd_hz, 'Hz')}",
            )
        release = _finite(obj.release_time_s)
        if release is not None:
            ax.axvline(release, color=colour, linestyle=":", linewidth=2.2, label=f"release {release:.3f} s")
        _legend(ax, size, fontsize=9.5)
    if underlays:
        width, height = size
        underlays.append(
            _colour_bar(
                fig,
                size,
                x=width - 92,
                y=70,
                height=height - 130,
                vmin=-SPECTROGRAM_RANGE_DB,
                vmax=0.0,
                cmap=SPECTROGRAM_CMAP,
                label="power (dB re. panel max)",
                bins=2,
                width=16,
            )
        )
    return _finish(canvas, size, underlays=underlays)


def _spectrogram_of(
    analysis: Analysis, obj: ObjectMeasurement
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """(times_s from the clip's start, frequencies_hz, power (F, T)) or None without a series."""
    given = getattr(obj, "spectrogram", None)
    if given is None:
        whole = getattr(analysis, "spectrogram", None)
        given = whole.get(obj.id) if isinstance(whole, dict) else None
    if given is not None:
        times = getattr(given, "times_s", None)
        freqs = getattr(given, "frequencies_hz", None)
        power = getattr(given, "power", None)
        if times is not None and freqs is not None and power is not None:
            p = np.asarray(power, np.float64)
            if p.shape == (len(freqs), len(times)):
                return np.asarray(times, np.float64), np.asarray(freqs, np.float64), p
    if obj.displacement_px is None or len(obj.displacement_px) < 5:
        return None
    times, freqs, power = ringdown_spectrogram(obj.displacement_px, fps=_sample_rate(analysis))
    t0 = float(_times_s(analysis, len(obj.displacement_px))[0])
    return times + t0, freqs, power


#: Artifact key -> the function that writes it (the mask is written by :func:`write_label_png`).
IMAGE_WRITERS: dict[str, Callable[[str | Path, Analysis], Path]] = {
    "overlay": write_overlay_png,
    "frequency_map": write_frequency_map_png,
    "spectrum": write_spectrum_png,
    "displacement": write_displacement_png,
    "ringdown": write_ringdown_png,
}

_DRAWERS: dict[str, Callable[[Analysis], _Image]] = {
    "overlay": _draw_overlay,
    "frequency_map": _draw_frequency_map,
    "spectrum": _draw_spectrum,
    "displacement": _draw_displacement,
    "ringdown": _draw_ringdown,
}


def render_all(
    analysis: Analysis,
    out_dir: str | Path,
    *,
    drawing_process: bool = True,
    everything_elsewhere: bool = False,
) -> dict[str, str]:
    """Write every image of an analysis into ``out_dir``.

    The displacement and ring-down figures are drawn in another process on the second core while the
    calling thread draws the others (matplotlib holds the GIL, so threads would not help): this
    process's drawing process when ``drawing_process`` (the first call starts it, in the background, and later
    calls use it; see :mod:`workers.pipeline._drawing_process`), else, or while it starts or serves
    another thread, a child forked for this call. If that process fails or overruns, the caller draws
    those figures too. PNG encoding and writing (which release the GIL) run on one helper thread
    meanwhile. Each file is written atomically.

    Parameters
    ----------
    analysis : Analysis
    out_dir : path-like
        Existing or new directory; files get the names of :data:`ARTIFACT_FILES`.
    drawing_process : bool, keyword-only
        Use (and start) the long-lived drawing process. A process that renders once and exits passes
        False, unless it started that process early (below): starting an interpreter now would cost more
        than it saves.
    everything_elsewhere : bool, keyword-only
        Have the drawing process draw every figure while this process writes the mask, waiting for it to
        be ready: for a process that started it in the background at its own start
        (:func:`start_drawing_process`) and draws nothing else, so that it never imports matplotlib.
        (Splitting the figures between it and a child it forks was no faster: right after a fork, both
        processes pay a copy-on-write fault for every page of objects they touch.) Where that process
        fails, the figures are drawn here as above.

    Returns
    -------
    dict of str to str
        Artifact key (``mask``, ``overlay``, ``frequency_map``, ``spectrum``, ``displacement``,
        ``ringdown``) -> file name relative to ``out_dir``.

    Raises
    ------
    OSError
        When a file cannot be written; images already written stay in place.
    """
    from concurrent.futures import Future, ThreadPoolExecutor

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if everything_elsewhere and _draw_everything_elsewhere(analysis, out):
        return {key: ARTIFACT_FILES[key] for key in ("mask", *_DRAWERS)}
    remote = _draw_elsewhere(analysis, out, _FORKED_DRAWERS, long_lived=drawing_process)
    here = [key for key in _DRAWERS if remote is None or key not in _FORKED_DRAWERS]
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="eigenscope-png") as pool:
        pending: list[Future[Path]] = [
            pool.submit(write_label_png, out / ARTIFACT_FILES["mask"], analysis.labels)
        ]
        try:
            try:
                for key in here:
                    image = _DRAWERS[key](analysis)
                    pending.append(pool.submit(_write_image, out / ARTIFACT_FILES[key], image))
            finally:  # the other process is waited for (and given back) whatever happened here
                written = remote is None or remote()
            if not written:
                for key in _FORKED_DRAWERS:
                    image = _DRAWERS[key](analysis)
                    pending.append(pool.submit(_write_image, out / ARTIFACT_FILES[key], image))
        finally:
            # Surface the first write error (after letting every submitted write finish).
            errors = [e for e in (f.exception() for f in pending) if e is not None]
        if errors:
            raise errors[0]
    return {key: ARTIFACT_FILES[key] for key in ("mask", *_DRAWERS)}


def start_drawing_process(
    *, wait_s: float = 0.0, background: bool = False, text_cache: str | Path | None = None
) -> bool:
    """Start this process's drawing process (see :func:`render_all`) unless it runs already.

    :func:`render_all` starts it at its first call and uses it from when it is ready; a process that
    will render many times can start it earlier.

    Parameters
    ----------
    wait_s : float, keyword-only
        How long to wait for it to be ready (it imports matplotlib: about a second).
    background : bool, keyword-only
        Start it at the lowest CPU priority, for its whole life: it then prepares on core time this
        process leaves idle. For a process that analyses once and then renders with
        ``everything_elsewhere``, started as that process starts.
    text_cache : path-like, optional, keyword-only
        A file of rendered strings the process starts with and keeps up to date: the figures' titles,
        labels and ticks repeat from run to run, and rasterising them is half of a first drawing's time.
        A missing or unreadable file is ignored (and written anew where it can be).

    Returns
    -------
    bool
        Whether it is ready to draw.
    """
    return _drawing_process.start_shared(wait_s, background=background, text_cache=text_cache)


def _draw_everything_elsewhere(analysis: Analysis, out: Path) -> bool:
    """Have this process's drawing process draw and write every figure but the mask, which is written
    here meanwhile; False (with the mask written) when it could not, and the figures are to be drawn here."""
    drawing = _drawing_process.claim_shared_waiting(_drawing_process.REPLY_TIMEOUT_S)
    sent = drawing is not None and drawing.submit(analysis, out, tuple(_DRAWERS))
    ok, added = False, None
    try:
        write_label_png(out / ARTIFACT_FILES["mask"], analysis.labels)
    finally:  # the process is waited for (and given back) whatever happened here
        if sent:
            assert drawing is not None
            ok, added = drawing.collect()
    if ok and added is not None:
        add_strings(added)
    return ok


def _draw_elsewhere(
    analysis: Analysis, out: Path, keys: tuple[str, ...], *, long_lived: bool
) -> Callable[[], bool] | None:
    """Start drawing the figures ``keys`` in another process: a function that waits for them (True when
    all were written, after adding the strings that process rendered to this process's text cache), or
    None when no other process can draw them (the caller draws them itself)."""
    drawing = _drawing_process.claim_shared() if long_lived else None
    if drawing is not None and drawing.submit(_without_images(analysis), out, keys):

        def collect() -> bool:
            ok, added = drawing.collect()
            if ok:
                add_strings(added)
            return ok

        return collect
    mark = cache_mark()
    fd, name = tempfile.mkstemp(prefix="eigenscope-text-cache-")  # the child's additions to the cache
    os.close(fd)
    learned = Path(name)
    child = _fork_drawer(analysis, out, keys, text_cache=(mark, learned))
    if child is None:
        learned.unlink(missing_ok=True)
        return None

    def wait() -> bool:
        try:
            ok = _child_succeeded(child)
            if ok:
                load_added(learned)  # the strings the child rendered: cached here for the next time
            return ok
        finally:
            learned.unlink(missing_ok=True)

    return wait


def _without_images(analysis: Analysis) -> Analysis:
    """``analysis`` without the frame-sized arrays, which the figures drawn elsewhere
    (:data:`_FORKED_DRAWERS`) do not read: less to send through the pipe."""
    from dataclasses import replace

    nothing = np.zeros((0, 0), np.uint8)
    return replace(
        analysis,
        labels=nothing.astype(np.uint16),
        frame_rgb=np.zeros((0, 0, 3), np.uint8),
        frequency_map_hz=nothing.astype(np.float32),
        frequency_map_valid=nothing.astype(bool),
    )


def _draw_and_write(analysis: Analysis, out: Path, key: str) -> Path:
    """Draw the figure ``key`` and write it into ``out`` (in a process drawing for another)."""
    return _write_image(out / ARTIFACT_FILES[key], _DRAWERS[key](analysis))


def _draw_and_write_all(analysis: Analysis, out: Path, keys: Sequence[str]) -> None:
    """Draw the figures ``keys`` and write them into ``out``, each figure's PNG encoded and written on a
    helper thread (which releases the GIL) while the next is drawn; the first write error is raised
    after every write has finished."""
    from concurrent.futures import Future, ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="eigenscope-png") as pool:
        pending: list[Future[Path]] = []
        try:
            for key in keys:
                pending.append(pool.submit(_write_image, out / ARTIFACT_FILES[key], _DRAWERS[key](analysis)))
        finally:
            errors = [e for e in (f.exception() for f in pending) if e is not None]
    if errors:
        raise errors[0]


#: Figures drawn in a forked child while the parent draws the others (about half of the drawing time).
_FORKED_DRAWERS = ("displacement", "ringdown")
#: A child that has not finished by then is killed and its figures are drawn by the parent (it normally
#: takes a twentieth of a second).
_CHILD_TIMEOUT_S = 10.0
#: Background threads that import libraries end their names with this; a fork waits for them.
WARM_UP_SUFFIX = "warm-up"


def _fork_drawer(
    analysis: Analysis,
    out: Path,
    keys: Sequence[str],
    *,
    text_cache: tuple[tuple[int, int], Path] | None = None,
) -> int | None:
    """Fork a child that draws and writes the figures ``keys``; its pid, or None where forking is not
    possible or not worth it (one core, no ``os.fork``). With ``text_cache`` = (mark, path), the child
    also saves the strings it rendered since ``mark`` to ``path`` (see :mod:`workers.pipeline._agg`)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if not hasattr(os, "fork") or cores < 2:
        return None
    # A thread still importing (this module's or the spectra's warm-up) would leave the child a module
    # lock held by a thread that does not exist in it: the child would wait on its first import of that
    # module until killed. Let such threads finish first.
    for thread in threading.enumerate():
        if thread.name.endswith(WARM_UP_SUFFIX) and thread is not threading.current_thread():
            thread.join(timeout=_CHILD_TIMEOUT_S)
            if thread.is_alive():  # pragma: no cover - an import that hangs: draw everything here
                return None
    from matplotlib.figure import Figure

    # Another thread may be drawing (a concurrent render, the warm-up): the child would inherit
    # matplotlib's render lock held by a thread that does not exist in it, and wait for it forever.
    # Forking while this thread holds the lock gives the child a lock it owns itself.
    render_lock: Any = getattr(Figure, "_render_lock", contextlib.nullcontext())
    with render_lock:
        try:
            pid = os.fork()
        except OSError:
            return None
        if pid:
            return pid
        code = 1
        try:  # the child: never returns, never raises into the caller's stack
            for key in keys:
                _draw_and_write(analysis, out, key)
            if text_cache is not None:
                save_added(*text_cache)
            code = 0
        finally:
            os._exit(code)


def _child_succeeded(pid: int) -> bool:
    """Wait for a drawing child; False (after killing it) when it failed or overran the timeout."""
    import signal
    import time

    deadline = time.monotonic() + _CHILD_TIMEOUT_S
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return False
        time.sleep(0.002)


__all__ = [
    "ARTIFACT_FILES",
    "DPI",
    "IMAGE_WRITERS",
    "PLOT_SIZE_PX",
    "display_scale",
    "display_size",
    "format_quantity",
    "frequency_map_size",
    "object_color",
    "object_label",
    "panel_figure_size",
    "render_all",
    "ringdown_spectrogram",
    "start_drawing_process",
    "write_displacement_png",
    "write_frequency_map_png",
    "write_label_png",
    "write_overlay_png",
    "write_ringdown_png",
    "write_spectrum_png",
]


def warm_up() -> threading.Thread:
    """Import matplotlib and load its fonts in a background thread.

    Importing matplotlib and its font cache costs about half a second; started when an analysis starts,
    it runs while the main thread waits on OpenCV and FFTW (which release the GIL), so the images that
    follow the analysis do not pay for it.

    Returns
    -------
    threading.Thread
        Already started (daemon); joining it is optional.
    """

    def load() -> None:
        _matplotlib()
        from matplotlib.figure import Figure

        fig = Figure(figsize=(1, 1), dpi=50)
        ax = fig.add_subplot()
        ax.plot([0, 1], [0, 1])
        ax.set_title("warm-up")
        caching_canvas()(fig).draw()

    thread = threading.Thread(target=load, name="render-warm-up", daemon=True)
    thread.start()
    return thread
