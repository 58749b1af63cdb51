"""Reading rendered PNGs (and the mode animation's GIF) back for the render tests."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis


def decode(path: Path) -> NDArray[np.uint8]:
    """The PNG at ``path`` as RGB, or the indices of a palette PNG (the mask); fails if it does not decode."""
    data = np.fromfile(str(path), np.uint8)
    assert data.size > 0, f"{path.name} is empty"
    if data.size > 25 and bytes(data[:8]) == b"\x89PNG\r\n\x1a\n" and int(data[25]) == 3:
        return palette_indices(path)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    assert img is not None, f"{path.name} does not decode as an image"
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return np.asarray(img)


def size_of(img: NDArray[np.uint8]) -> tuple[int, int]:
    return (img.shape[1], img.shape[0])


def assert_not_blank(img: NDArray[np.uint8], name: str, *, min_ink: float = 0.02) -> None:
    """Real content: varied pixels, many colours, and (for plots on white) some ink but not all."""
    assert img.ndim == 3, f"{name}: expected RGB, got shape {img.shape}"
    assert img.shape[2] == 3, f"{name}: expected RGB, got shape {img.shape}"
    assert float(img.std()) > 10.0, f"{name}: nearly uniform (std {img.std():.1f})"
    colours = np.unique(img.reshape(-1, 3)[::7], axis=0)
    assert len(colours) > 30, f"{name}: only {len(colours)} distinct colours"
    ink = float((img.min(axis=2) < 235).mean())
    assert ink > min_ink, f"{name}: only {ink:.1%} of the pixels are not white"


def colour_mask(img: NDArray[np.uint8], rgb: tuple[int, int, int], *, tol: int = 3) -> NDArray[np.bool_]:
    """Pixels within ``tol`` levels of ``rgb`` on every channel."""
    diff = np.abs(img.astype(np.int16) - np.asarray(rgb, np.int16)[None, None, :])
    mask: NDArray[np.bool_] = (diff <= tol).all(axis=2)
    return mask


def palette_indices(path: Path) -> NDArray[np.uint8]:
    """The indices of a palette PNG (OpenCV would expand them to colours), read with Pillow."""
    from PIL import Image

    with Image.open(path) as img:
        assert img.mode == "P", f"{path.name}: expected a palette image, got mode {img.mode}"
        return np.asarray(img, dtype=np.uint8)


def gif_frames(path: Path) -> tuple[list[NDArray[np.uint8]], dict[str, object]]:
    """Every frame of the GIF at ``path`` as RGB (each as a viewer shows it, over the frames before it) and
    the file's info (``loop``, ``duration``), read with Pillow; fails if it does not decode."""
    from PIL import Image, ImageSequence

    with Image.open(path) as img:
        assert img.format == "GIF", f"{path.name}: expected a GIF, got {img.format}"
        info = dict(img.info)
        frames = [np.asarray(frame.convert("RGB"), np.uint8) for frame in ImageSequence.Iterator(img)]
    return frames, info


def mode_panels_of(analysis: Analysis) -> tuple[int, int]:
    """(rows, columns) of ``modes.png``: the objects with modes, and the most modes one of them has."""
    counts = [
        len(o.modes.found.modes)
        for o in analysis.objects
        if o.modes is not None and o.modes.found.modes and o.modes.roi is not None
    ]
    return (len(counts), max(counts, default=0))
