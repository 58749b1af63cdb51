"""The mode animation: ``modes.png``'s panels, each object's pixels moving in its mode's magnified shape.

Each panel of :mod:`~workers.pipeline.figures.mode_shapes` becomes a loop: the object's pixels (in its
colour, shaded by their grey level, outlined) are warped by the mode's magnified shape times sin(2π k / K)
over the dimmed frame, K = :data:`ANIMATION_FRAMES` frames a cycle, every panel in step (one cycle is no
period of the mode: the modes' frequencies are in the labels). The frames are encoded as a looping GIF
with one palette; frames larger than :data:`~workers.pipeline.figures.style.MAX_ANIMATION_PIXELS` are
shrunk, and pixels that do not change from one frame to the next are left transparent, so the file stays
small.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline._files import write_atomically
from workers.pipeline.figures.mode_shapes import (
    ModePanel,
    compose_page,
    draw_border,
    draw_mode_shapes,
    mode_panels,
    panel_origin,
)
from workers.pipeline.figures.style import MAX_ANIMATION_PIXELS, MODE_CELL_PX, object_color

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis

#: Frames per cycle of the animation, and how long each is shown.
ANIMATION_FRAMES = 16
FRAME_MS = 70
#: Colours of the GIF's one palette (one more index is left free for the unchanged pixels).
GIF_COLOURS = 64
#: Grey levels of the moving object's shading.
SHADES = 6


def animation_size(width: int, height: int) -> tuple[int, int]:
    """(width, height) of a ``modes.gif`` frame whose page is ``width`` x ``height``: the same, or shrunk
    (aspect kept) to at most :data:`MAX_ANIMATION_PIXELS` pixels."""
    scale = min(1.0, math.sqrt(MAX_ANIMATION_PIXELS / max(width * height, 1)))
    return (max(1, math.floor(width * scale)), max(1, math.floor(height * scale)))


def mode_animation_frames(analysis: Analysis, *, frames: int = ANIMATION_FRAMES) -> list[NDArray[np.uint8]]:
    """The frames of ``modes.gif``: one cycle of every object's modes, each in its panel.

    Parameters
    ----------
    analysis : Analysis
        As for :func:`~workers.pipeline.figures.mode_shapes.draw_mode_shapes`.
    frames : int, keyword-only
        Frames per cycle (at least 2); frame k shows the shapes times sin(2π k / frames).

    Returns
    -------
    list of ndarray of uint8, shape (H, W, 3)
        RGB frames of :func:`animation_size` of the ``modes.png`` page. With no modes, one frame: the
        note of ``modes.png``.
    """
    import cv2

    rows = mode_panels(analysis)
    if not rows:
        return [_shrink(draw_mode_shapes(analysis), cv2)]
    page = compose_page(rows, [[p.background for p in row] for row in rows])
    xs, ys = np.meshgrid(np.arange(MODE_CELL_PX[0]), np.arange(MODE_CELL_PX[1]))
    grid = np.stack([xs, ys], axis=-1).astype(np.float32)
    sprites = [[object_sprite(p, cv2) for p in row] for row in rows]
    out = []
    for k in range(max(2, frames)):
        phase = math.sin(2 * math.pi * k / max(2, frames))
        image = page.copy()
        for r, row in enumerate(rows):
            for c, panel in enumerate(row):
                x, y = panel_origin(r, c)
                moved = moved_panel(panel, sprites[r][c], phase, grid, cv2)
                image[y : y + MODE_CELL_PX[1], x : x + MODE_CELL_PX[0]] = moved
        out.append(_shrink(image, cv2))
    return out


def object_sprite(panel: ModePanel, cv2: Any) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """What moves in a panel: the object's pixels in its colour, shaded by their grey level in
    :data:`SHADES` steps (few colours: a small GIF), and its mask softened (a smooth outline once
    displaced, not a staircase).

    Returns
    -------
    shaded : ndarray of uint8, shape (h, w, 3)
    soft_mask : ndarray of float32, shape (h, w)
        0 to 1.
    """
    grey = cv2.cvtColor(panel.colour, cv2.COLOR_RGB2GRAY).astype(np.float32)
    level = np.floor(cv2.GaussianBlur(grey, (0, 0), 1.0) / 256.0 * SHADES) / (SHADES - 1)
    shade = 0.45 + 0.55 * level[..., None]
    shaded = np.asarray(shade * np.asarray(object_color(panel.object_id), np.float32), np.float32)
    soft = cv2.GaussianBlur(panel.mask.astype(np.float32), (0, 0), 1.5)
    return np.clip(shaded + 0.5, 0, 255).astype(np.uint8), np.asarray(soft, np.float32)


def moved_panel(
    panel: ModePanel,
    sprite: tuple[NDArray[np.uint8], NDArray[np.float32]],
    phase: float,
    grid: NDArray[np.float32],
    cv2: Any,
) -> NDArray[np.uint8]:
    """A panel with the object's pixels displaced by ``phase`` times the magnified shape.

    Parameters
    ----------
    panel : ModePanel
    sprite : (shaded, soft_mask)
        The object's pixels and mask, :func:`object_sprite`.
    phase : float
        -1 to 1.
    grid : ndarray of float32, shape (h, w, 2)
        Each panel pixel's (x, y).
    cv2 : module

    Returns
    -------
    ndarray of uint8, shape (h, w, 3)
        The dimmed crop with the displaced object in its colour, outlined.
    """
    source = grid - np.float32(phase) * panel.field  # where each pixel's content comes from
    mx, my = np.ascontiguousarray(source[..., 0]), np.ascontiguousarray(source[..., 1])
    shaded = cv2.remap(sprite[0], mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
    inside = cv2.remap(sprite[1], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) >= 0.5
    image = panel.background.copy()
    image[inside] = shaded[inside]
    contours, _ = cv2.findContours(inside.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.polylines(image, contours, True, (0, 0, 0), 2, cv2.LINE_8)
    return draw_border(image, panel.object_id, cv2)


def encode_gif(frames: list[NDArray[np.uint8]], *, frame_ms: int = FRAME_MS) -> bytes:
    """Frames as a looping GIF: one palette of :data:`GIF_COLOURS` colours (median cut of every other
    pixel of the first frame and of the one a quarter of the cycle on; not dithered), unchanged pixels
    transparent.

    Parameters
    ----------
    frames : list of ndarray of uint8, shape (H, W, 3)
        RGB, all of one size; at least one.
    frame_ms : int, keyword-only
        Time each frame is shown, milliseconds.

    Returns
    -------
    bytes
    """
    from PIL import Image

    sample = np.concatenate([frames[0][::2, ::2], frames[len(frames) // 4][::2, ::2]], axis=0)
    palette = Image.fromarray(sample).quantize(
        colors=GIF_COLOURS, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
    )
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    buffer = io.BytesIO()
    images[0].save(
        buffer,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        loop=0,
        duration=frame_ms,
        disposal=1,  # each frame is drawn over the last: its unchanged pixels are left transparent
        optimize=True,
    )
    return buffer.getvalue()


def write_gif(path: str | Path, frames: list[NDArray[np.uint8]]) -> Path:
    """Write frames (:func:`encode_gif`) to ``path`` atomically; returns ``path`` as a Path."""
    return write_atomically(path, encode_gif(frames))


def write_mode_animation(path: str | Path, analysis: Analysis) -> Path:
    """Draw the ``mode_animation`` artifact of ``analysis`` (:func:`mode_animation_frames`) and write it to
    ``path`` as a looping GIF, atomically.

    Parameters
    ----------
    path : path-like
    analysis : Analysis

    Returns
    -------
    Path
        ``path``.
    """
    return write_gif(path, mode_animation_frames(analysis))


def _shrink(image: NDArray[np.uint8], cv2: Any) -> NDArray[np.uint8]:
    """``image`` (H, W, 3) at :func:`animation_size`."""
    size = animation_size(image.shape[1], image.shape[0])
    if size == (image.shape[1], image.shape[0]):
        return image
    return np.asarray(cv2.resize(image, size, interpolation=cv2.INTER_AREA), np.uint8)


__all__ = [
    "ANIMATION_FRAMES",
    "FRAME_MS",
    "animation_size",
    "encode_gif",
    "mode_animation_frames",
    "moved_panel",
    "object_sprite",
    "write_gif",
    "write_mode_animation",
]
