"""Reading rendered PNGs back for the render tests."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray


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
