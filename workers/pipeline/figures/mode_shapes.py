"""The mode shapes: each object's modes drawn over its part of the frame, as arrows and a deformed outline.

One row per object with modes (in the analysis's order), one panel per mode (in the order of the
result's ``objects[].modes``). A panel is the representative frame cropped around the object's box with a
margin (widened to the aspect of :data:`~workers.pipeline.figures.style.MODE_CELL_PX`), in dimmed grey;
over it the object's outline at rest (light grey), its outline deformed by the mode's shape and the shape
itself as arrows on a grid, both in the object's colour. Shapes are magnified so that the longest arrow
(the 99th percentile of the object's displacement) is :data:`ARROW_SHARE` of the panel's width; the label
gives the factor, with the object's id, the mode's number, its frequency and its damping ratio (or its
regime when it does not ring down).

:mod:`~workers.pipeline.figures.mode_animation` animates the same panels (:func:`mode_panels`,
:func:`compose_page`, :func:`panel_origin`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import _figure, _finish, _frame, _note, _resize
from workers.pipeline.figures.style import (
    MODE_CELL_PX,
    MODE_GAP_PX,
    MODE_LABEL_PX,
    MODE_TITLE_PX,
    NO_MODES_NOTE,
    _mpl_color,
    format_quantity,
    mode_shapes_size,
    object_color,
)

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis
    from workers.pipeline.modes import Mode

#: The longest arrow (99th percentile of the object's displacement) is this share of the panel's width.
ARROW_SHARE = 0.12
#: Arrows start on a grid of this pitch, panel pixels (one per grid cell the object covers).
ARROW_STEP_PX = 32
#: The crop around an object's box: this share of its longer side on every side (at least
#: :data:`MIN_MARGIN_PX` input pixels), then widened to the panel's aspect.
MARGIN_SHARE = 0.2
MIN_MARGIN_PX = 8
#: Dimmed grey of the frame behind the shapes: grey level times this plus :data:`DIM_OFFSET`.
DIM_GAIN = 0.55
DIM_OFFSET = 60
#: The object's outline at rest.
REST_COLOUR = (235, 235, 235)
_TITLE_TEXT = "mode shapes (magnified)"
_LABEL_FONT = 9.5


@dataclass(frozen=True)
class ModePanel:
    """One mode of one object at panel resolution (:data:`MODE_CELL_PX`).

    Attributes
    ----------
    object_id : int
    number : int
        The mode's place among the object's modes, from 1.
    mode : Mode
    background : ndarray of uint8, shape (h, w, 3)
        The crop of the frame in dimmed grey.
    colour : ndarray of uint8, shape (h, w, 3)
        The same crop in colour.
    mask : ndarray of bool, shape (h, w)
        The object's pixels.
    field : ndarray of float32, shape (h, w, 2)
        The mode's displacement (x, y), panel pixels, magnified; extended from the object to the pixels
        around it it may move over (nearest measured value), 0 further away.
    magnification : float
        Shown displacement over the true one (both in panel pixels).
    """

    object_id: int
    number: int
    mode: Mode
    background: NDArray[np.uint8]
    colour: NDArray[np.uint8]
    mask: NDArray[np.bool_]
    field: NDArray[np.float32]
    magnification: float


def draw_mode_shapes(analysis: Analysis) -> NDArray[np.uint8]:
    """Each object's modes as arrows and a deformed outline over its crop of the frame.

    Parameters
    ----------
    analysis : Analysis
        Uses ``frame_rgb`` (uint8, (H, W, 3)), ``labels`` (uint16, (H, W)) and each object's ``modes``.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, (W, H) = :func:`~workers.pipeline.figures.style.mode_shapes_size` (objects with
        modes, most modes of one). When no object has modes, one panel of the whole frame with a
        "no modes found" note.
    """
    import cv2

    rows = mode_panels(analysis)
    if not rows:
        return _note_page(analysis)
    cells = [[_draw_panel(p, cv2) for p in row] for row in rows]
    return compose_page(rows, cells)


def mode_panels(analysis: Analysis) -> list[list[ModePanel]]:
    """The panels of ``modes.png``: one list per object with modes (in the analysis's order), one panel per
    mode. An object's modes need the box their shapes were measured in (``modes.roi``)."""
    frame = _frame(analysis)
    rows = []
    for obj in analysis.objects:
        modes = obj.modes
        if modes is None or not modes.found.modes or modes.roi is None:
            continue
        mask = np.asarray(analysis.labels) == obj.id
        box = crop_box(obj.bbox_px, mask.shape)
        scale = (MODE_CELL_PX[0] / box[2], MODE_CELL_PX[1] / box[3])
        cell_mask = _resize(_crop(mask.astype(np.uint8), box, 0), MODE_CELL_PX, nearest=True) > 0
        view = (*_crops(frame, box), cell_mask)
        shapes = modes.frame_shapes(mask)
        row = [
            _panel(obj.id, n + 1, mode, view, _crop(shapes[n], box, np.nan), scale)
            for n, mode in enumerate(modes.found.modes)
        ]
        rows.append(row)
    return rows


def crop_box(bbox_px: tuple[int, int, int, int], frame_shape: tuple[int, ...]) -> tuple[int, int, int, int]:
    """The part of the frame a panel shows: the object's box with a margin, widened to the panel's aspect.

    Parameters
    ----------
    bbox_px : (x, y, w, h)
        The object's box, input pixels.
    frame_shape : (H, W, ...)

    Returns
    -------
    (x, y, w, h) : tuple of int
        Input pixels; moved inside the frame where it fits, else centred on the object (the panel is
        padded beyond the frame).
    """
    x, y, w, h = (float(v) for v in bbox_px)
    aspect = MODE_CELL_PX[0] / MODE_CELL_PX[1]
    margin = max(MARGIN_SHARE * max(w, h), MIN_MARGIN_PX)
    width = max(w + 2 * margin, (h + 2 * margin) * aspect)
    cw, ch = max(4, round(width)), max(3, round(width / aspect))
    x0, y0 = round(x + w / 2 - cw / 2), round(y + h / 2 - ch / 2)
    frame_h, frame_w = frame_shape[:2]
    if cw <= frame_w:
        x0 = min(max(x0, 0), frame_w - cw)
    if ch <= frame_h:
        y0 = min(max(y0, 0), frame_h - ch)
    return (x0, y0, cw, ch)


def panel_origin(row: int, column: int) -> tuple[int, int]:
    """(x, y) of the top-left pixel of panel (``row``, ``column``) in ``modes.png``."""
    cell_w, cell_h = MODE_CELL_PX
    return (
        MODE_GAP_PX + column * (cell_w + MODE_GAP_PX),
        MODE_TITLE_PX + row * (MODE_LABEL_PX + cell_h + MODE_GAP_PX) + MODE_LABEL_PX,
    )


def panel_label(panel: ModePanel) -> str:
    """The label above a panel: ``"#1  mode 2   f = 25.07 ± 0.02 Hz"`` and the damping ratio (or the
    mode's regime, when it does not ring down) with the magnification."""
    mode = panel.mode
    f = format_quantity(mode.frequency_hz, mode.frequency_uncertainty_hz, "Hz")
    if mode.damping_ratio is not None:
        damping = f"ζ = {format_quantity(mode.damping_ratio, mode.damping_ratio_uncertainty, '')}"
    else:
        damping = "growing" if mode.regime == "growing" else "steady"
    m = panel.magnification
    shown = f"{m:.0f}" if m >= 100 else f"{m:.3g}"
    return f"#{panel.object_id}  mode {panel.number}   f = {f}\n{damping}   shown ×{shown}"


def compose_page(rows: list[list[ModePanel]], cells: list[list[NDArray[np.uint8]]]) -> NDArray[np.uint8]:
    """The page of ``modes.png``: the title, each panel's label and its pixels ``cells[r][c]``.

    Parameters
    ----------
    rows : list of list of ModePanel
    cells : list of list of ndarray of uint8, shape (h, w, 3)
        Each panel's pixels, :data:`MODE_CELL_PX`.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        (W, H) = :func:`mode_shapes_size` ``(len(rows), longest row)``; the labels lie outside the panels,
        so a panel's pixels can be replaced in place (the animation's frames).
    """
    size = mode_shapes_size(len(rows), max(len(row) for row in rows))
    fig, canvas = _figure(size, transparent=True)
    width, height = size
    fig.text(MODE_GAP_PX / width, 1 - 6 / height, _TITLE_TEXT, ha="left", va="top", fontsize=11, color="0.1")
    underlays = []
    for r, row in enumerate(rows):
        for c, panel in enumerate(row):
            x, y = panel_origin(r, c)
            underlays.append((cells[r][c], x, y))
            fig.text(
                (x + 2) / width,
                1 - (y - 5) / height,
                panel_label(panel),
                ha="left",
                va="bottom",
                fontsize=_LABEL_FONT,
                color="0.1",
                linespacing=1.25,
                bbox={
                    "boxstyle": "round,pad=0.2",
                    "facecolor": "white",
                    "edgecolor": _mpl_color(panel.object_id),
                    "linewidth": 1.5,
                },
            )
    return _finish(canvas, size, underlays=underlays)


# --------------------------------------------------------------------------------------------- panels


def _crop(image: NDArray[Any], box: tuple[int, int, int, int], fill: float) -> NDArray[Any]:
    """``box`` (x, y, w, h) of ``image`` (H, W, ...), ``fill`` where it lies beyond the frame."""
    x0, y0, cw, ch = box
    out = np.full((ch, cw, *image.shape[2:]), fill, image.dtype)
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + cw, image.shape[1]), min(y0 + ch, image.shape[0])
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = image[sy0:sy1, sx0:sx1]
    return out


def _crops(
    frame: NDArray[np.uint8], box: tuple[int, int, int, int]
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The crop ``box`` of ``frame`` at panel size: (dimmed grey, colour), each uint8 (h, w, 3)."""
    import cv2

    colour = np.ascontiguousarray(_resize(_crop(frame, box, 128), MODE_CELL_PX, nearest=False))
    grey = cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY)
    dim = cv2.convertScaleAbs(grey, alpha=DIM_GAIN, beta=DIM_OFFSET)
    return np.asarray(cv2.cvtColor(dim, cv2.COLOR_GRAY2RGB), np.uint8), np.asarray(colour, np.uint8)


def _panel(
    object_id: int,
    number: int,
    mode: Mode,
    view: tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.bool_]],
    shape: NDArray[np.float32],
    scale: tuple[float, float],
) -> ModePanel:
    """A mode's panel from its shape on the crop (h', w', 2), input pixels, NaN off the object."""
    background, colour, mask = view
    cell = _resize(np.ascontiguousarray(shape), MODE_CELL_PX, nearest=True) * np.asarray(scale, np.float32)
    known = mask & np.isfinite(cell).all(axis=2)
    cell[~known] = 0.0
    amplitude = np.hypot(cell[..., 0], cell[..., 1])[known]
    peak = float(np.percentile(amplitude, 99)) if amplitude.size else 0.0
    magnification = ARROW_SHARE * MODE_CELL_PX[0] / peak if peak > 0 and math.isfinite(peak) else 1.0
    field = _extend(cell * np.float32(magnification), known, radius=ARROW_SHARE * MODE_CELL_PX[0] + 4)
    return ModePanel(object_id, number, mode, background, colour, mask, field, magnification)


def _extend(field: NDArray[np.float32], known: NDArray[np.bool_], *, radius: float) -> NDArray[np.float32]:
    """``field`` (h, w, 2) carried from the ``known`` pixels to every pixel within ``radius`` of them (its
    nearest known value), 0 further away, smoothed over 3 pixels (the flow grid's blocks)."""
    import cv2

    if not known.any():
        return np.zeros_like(field)
    src = np.where(known, 0, 1).astype(np.uint8)
    distance, labels = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    lookup = np.zeros(int(labels.max()) + 1, np.intp)
    lookup[labels[known]] = np.flatnonzero(known)
    out = field.reshape(-1, 2)[lookup[labels.ravel()]].reshape(field.shape)
    out[distance > radius] = 0.0
    return np.asarray(cv2.GaussianBlur(out, (0, 0), 3.0), np.float32)


def _outlines(mask: NDArray[np.bool_], cv2: Any) -> list[NDArray[np.int32]]:
    """The outer contours of ``mask``, every pixel of them, each (n, 1, 2) int32 (x, y)."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return [np.asarray(c, np.int32) for c in contours]


def _arrow_starts(panel: ModePanel) -> NDArray[np.intp]:
    """Where arrows start: in every :data:`ARROW_STEP_PX` square the object covers, its pixel nearest the
    square's centre; (n, 2) int (x, y)."""
    ys, xs = np.nonzero(panel.mask)
    if xs.size == 0:
        return np.zeros((0, 2), np.intp)
    step = ARROW_STEP_PX
    block = (ys // step) * (panel.mask.shape[1] // step + 1) + xs // step
    distance = (ys % step - step / 2) ** 2 + (xs % step - step / 2) ** 2
    order = np.lexsort((distance, block))
    first = order[np.unique(block[order], return_index=True)[1]]
    return np.stack([xs[first], ys[first]], axis=1)


def _draw_panel(panel: ModePanel, cv2: Any) -> NDArray[np.uint8]:
    """A mode's still panel: the dimmed crop, the outline at rest, the deformed outline and the arrows."""
    shift = 4
    img = panel.background.copy()
    colour = object_color(panel.object_id)
    rest = _outlines(panel.mask, cv2)
    cv2.polylines(img, rest, True, REST_COLOUR, 1, cv2.LINE_AA)
    deformed = [
        np.round((c + panel.field[c[:, 0, 1], c[:, 0, 0]][:, None, :]) * (1 << shift)).astype(np.int32)
        for c in rest
    ]
    cv2.polylines(img, deformed, True, (0, 0, 0), 4, cv2.LINE_AA, shift)
    cv2.polylines(img, deformed, True, colour, 2, cv2.LINE_8, shift)
    for x, y in _arrow_starts(panel):
        dx, dy = (float(v) for v in panel.field[y, x])
        length = math.hypot(dx, dy)
        if length < 2.0:
            cv2.circle(img, (int(x), int(y)), 1, colour, -1, cv2.LINE_8)
            continue
        end = (round(x + dx), round(y + dy))
        tip = min(0.45, 6.0 / length)
        cv2.arrowedLine(img, (int(x), int(y)), end, (0, 0, 0), 4, cv2.LINE_AA, 0, tip)
        cv2.arrowedLine(img, (int(x), int(y)), end, colour, 2, cv2.LINE_8, 0, tip)
    return draw_border(img, panel.object_id, cv2)


def draw_border(img: NDArray[np.uint8], object_id: int, cv2: Any) -> NDArray[np.uint8]:
    """A 2-pixel frame in the object's colour around a panel's pixels ``img`` (h, w, 3), in place."""
    cv2.rectangle(img, (0, 0), (img.shape[1] - 1, img.shape[0] - 1), object_color(object_id), 2, cv2.LINE_8)
    return img


def _note_page(analysis: Analysis) -> NDArray[np.uint8]:
    """One panel of the whole frame, dimmed, with the "no modes found" note; :func:`mode_shapes_size`
    ``(0, 0)``."""
    frame = _frame(analysis)
    frame_h, frame_w = frame.shape[:2]
    cw = max(frame_w, round(frame_h * MODE_CELL_PX[0] / MODE_CELL_PX[1]))
    ch = round(cw * MODE_CELL_PX[1] / MODE_CELL_PX[0])
    background, _ = _crops(frame, ((frame_w - cw) // 2, (frame_h - ch) // 2, cw, ch))
    size = mode_shapes_size(0, 0)
    fig, canvas = _figure(size, transparent=True)
    width, height = size
    fig.text(MODE_GAP_PX / width, 1 - 6 / height, _TITLE_TEXT, ha="left", va="top", fontsize=11, color="0.1")
    x, y = panel_origin(0, 0)
    centre = ((x + MODE_CELL_PX[0] / 2) / width, 1 - (y + MODE_CELL_PX[1] / 2) / height)
    _note(fig, NO_MODES_NOTE, color="0.1", xy=centre, fontsize=12)
    return _finish(canvas, size, underlays=[(background, x, y)])


__all__ = [
    "ARROW_SHARE",
    "ModePanel",
    "compose_page",
    "crop_box",
    "draw_border",
    "draw_mode_shapes",
    "mode_panels",
    "panel_label",
    "panel_origin",
]
