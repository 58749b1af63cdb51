"""What every figure shares: sizes, the objects' palette, fonts and number formatting.

Sizes (pixels, width x height), fixed so that tests and clients can rely on them:

* ``overlay.png`` - the frame's display size, :func:`display_size` (the frame size; small frames are
  upscaled by an integer factor to at least 640 px on their long side, wide frames shrunk to 1280 px wide).
* ``frequency_map.png`` - the display size plus :data:`MAP_MARGIN_PX` for the title and the colour bar.
* ``spectrum.png`` - :data:`PLOT_SIZE_PX` (1000 x 600).
* ``displacement.png`` and ``ringdown.png`` - one panel per object, :func:`panel_figure_size` (1000 x 600
  for one or two objects, taller for more).
* ``modes.png`` - one row per object with modes, one :data:`MODE_CELL_PX` panel per mode under a
  :data:`MODE_LABEL_PX` label, :func:`mode_shapes_size` (one panel with a note when no object has modes).
* ``modes.gif`` - the same layout, shrunk to at most :data:`MAX_ANIMATION_PIXELS` pixels a frame.
* ``mask.png`` - the frame size, a palette image: 0 = background, i = object i, shown in its colour.

One object has one colour in every image: :func:`object_color` is the palette.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from workers.pipeline.model import finite_or_none

if TYPE_CHECKING:
    from workers.pipeline.model import ObjectMeasurement


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
#: (width, height) of one mode's panel in ``modes.png`` / ``modes.gif``: the object's box, cropped with a
#: margin to this aspect; the label strip above it, the gap between panels and the title strip, pixels.
MODE_CELL_PX = (320, 240)
MODE_LABEL_PX = 40
MODE_GAP_PX = 10
MODE_TITLE_PX = 30
#: A ``modes.gif`` frame larger than this many pixels is shrunk to it (the file stays small).
MAX_ANIMATION_PIXELS = 360_000

#: Artifact key -> file name, in the order :func:`workers.drawing.draw_all` writes them.
ARTIFACT_FILES: dict[str, str] = {
    "mask": "mask.png",
    "overlay": "overlay.png",
    "frequency_map": "frequency_map.png",
    "spectrum": "spectrum.png",
    "displacement": "displacement.png",
    "ringdown": "ringdown.png",
    "modes": "modes.npz",
    "mode_shapes": "modes.png",
    "mode_animation": "modes.gif",
}

NO_OBJECT_NOTE = "no object found"
NO_MODES_NOTE = "no modes found"
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


def mode_shapes_size(rows: int, columns: int) -> tuple[int, int]:
    """(width, height) in pixels of ``modes.png`` with ``rows`` objects of at most ``columns`` modes.

    Each panel is :data:`MODE_CELL_PX` under a :data:`MODE_LABEL_PX` label, :data:`MODE_GAP_PX` apart, under
    a :data:`MODE_TITLE_PX` title; no row (no object has modes) gives the size of one panel (the note).
    """
    rows, columns = (rows, columns) if rows > 0 and columns > 0 else (1, 1)
    cell_w, cell_h = MODE_CELL_PX
    return (
        MODE_GAP_PX + columns * (cell_w + MODE_GAP_PX),
        MODE_TITLE_PX + rows * (MODE_LABEL_PX + cell_h + MODE_GAP_PX),
    )


def format_quantity(value: float | None, sd: float | None, unit: str) -> str:
    """``"4.998 ± 0.012 Hz"``: the value rounded to its uncertainty's second significant digit.

    Without a (finite, positive) uncertainty the value gets four significant digits; None or NaN gives
    ``"n/a"``. Very large or small values share a power of ten: ``"(1.50 ± 0.02)×10⁷ N/m"``.
    """
    v = finite_or_none(value)
    if v is None:
        return "n/a"
    s = finite_or_none(sd)
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
    f = format_quantity(obj.eigenfrequency_hz, obj.eigenfrequency_uncertainty_hz, "Hz")
    return "\n".join(
        (
            f"#{obj.id}  f = {f}",
            f"k = {format_quantity(obj.stiffness_n_per_m, obj.stiffness_uncertainty_n_per_m, 'N/m')}",
            f"m = {format_quantity(obj.mass_kg, obj.mass_uncertainty_kg, 'kg')}",
        )
    )
