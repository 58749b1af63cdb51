"""The overlay: the representative frame with each object outlined in its colour and labelled."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import (
    _draw_outlines,
    _figure,
    _finish,
    _frame,
    _no_object_message,
    _note,
    _resize,
)
from workers.pipeline.figures.style import (
    _mpl_color,
    display_size,
    object_label,
)

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis


def draw_overlay(analysis: Analysis) -> NDArray[np.uint8]:
    """The representative frame with each object outlined in its colour and labelled with id, f, k, m.

    Parameters
    ----------
    analysis : Analysis
        Uses ``frame_rgb`` (uint8, (H, W, 3)), ``labels`` (uint16, (H, W)) and ``objects``.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, (W, H) = :func:`display_size` ``(W, H)`` pixels. With no object, the frame carries a
        "no object found" note.
    """
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
