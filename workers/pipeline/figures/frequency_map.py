"""The frequency map: per-pixel dominant frequency over the frame, with a colour bar in Hz."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import (
    ColourBar,
    _colour_bar,
    _colour_index,
    _colour_lut,
    _draw_outlines,
    _figure,
    _finish,
    _frame,
    _note,
    _resize,
)
from workers.pipeline.figures.style import (
    _FONT,
    _SMALL,
    FREQUENCY_CMAP,
    MAP_MARGIN_PX,
    NO_OBJECT_NOTE,
    display_size,
    frequency_map_size,
    object_color,
)
from workers.pipeline.model import finite_or_none

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis


def draw_frequency_map(analysis: Analysis) -> NDArray[np.uint8]:
    """Per-pixel dominant frequency over the frame, with a colour bar in Hz.

    Pixels whose peak does not stand above the noise (``frequency_map_valid`` False) are shown as the
    faded grey frame; object outlines are drawn in their colours.

    Parameters
    ----------
    analysis : Analysis
        Uses ``frequency_map_hz`` (float32, (h, w), on the flow grid), ``frequency_map_valid`` (bool,
        (h, w)), ``band_hz``, ``frame_rgb`` (uint8, (H, W, 3)) and ``labels``.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, (W, H) = :func:`frequency_map_size` ``(W, H)`` pixels.
    """
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
        (f, object_color(o.id))
        for o in analysis.objects
        if (f := finite_or_none(o.eigenfrequency_hz)) is not None
    ]
    bar = _colour_bar(
        fig,
        size,
        ColourBar(
            x=left + dsize[0] + 16,
            y=top + 10,
            height=max(dsize[1] - 20, 20),
            vmin=lo,
            vmax=hi,
            cmap=FREQUENCY_CMAP,
            label="dominant frequency (Hz)",
            marks=marks,
        ),
    )
    if not analysis.objects:
        centre = ((left + dsize[0] / 2) / size[0], (size[1] - top - dsize[1] / 2) / size[1])
        _note(fig, NO_OBJECT_NOTE, color="0.1", xy=centre)
    return _finish(canvas, size, underlays=[(rgb8, left, top), bar])
