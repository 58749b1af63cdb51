"""PNG encoding of figures and of the label mask, written atomically.

Every image is a PNG written to a temporary file and renamed
(:func:`workers.pipeline._files.write_atomically`), so a reader never sees half an image.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from workers.pipeline._files import write_atomically
from workers.pipeline.figures.style import object_color

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis

#: Figures that are mostly a camera frame (or a spectrogram): encoded with the filter that suits photos.
PHOTO_FIGURES = frozenset({"overlay", "frequency_map", "ringdown"})


def encode_png(rgb: NDArray[np.uint8], *, photo: bool) -> bytes:
    """A figure's pixels as PNG bytes, encoded fast: level 1, with the filter that suits the content.

    Camera frames (``photo``) encode fastest and smallest with the SUB filter and run-length coding;
    plots (large flat areas) with no filter at all, for about the same size as the default (measured on
    typical images).

    Parameters
    ----------
    rgb : ndarray of uint8, shape (H, W, 3)
    photo : bool, keyword-only
        Whether the image is mostly a camera frame (see :data:`PHOTO_FIGURES`).

    Returns
    -------
    bytes
    """
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER]
    if photo:
        params += [cv2.IMWRITE_PNG_FILTER_SUB, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    else:
        params += [cv2.IMWRITE_PNG_FILTER_NONE]
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
    if not ok:  # pragma: no cover - OpenCV always encodes 3-channel uint8 arrays
        raise OSError(f"could not encode an image of shape {rgb.shape}")
    return bytes(buf.tobytes())


def write_png(path: str | Path, rgb: NDArray[np.uint8], *, photo: bool) -> Path:
    """Write a figure's pixels (:func:`encode_png`) to ``path`` atomically; returns ``path`` as a Path.

    Parameters
    ----------
    path : path-like
    rgb : ndarray of uint8, shape (H, W, 3)
    photo : bool, keyword-only
        As for :func:`encode_png`.

    Returns
    -------
    Path
    """
    return write_atomically(path, encode_png(rgb, photo=photo))


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
        write_atomically(path, buf.tobytes())
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
    write_atomically(path, png + chunk(b"IEND", b""))
    return path


def _writer(
    key: str, draw: Callable[[Analysis], NDArray[np.uint8]]
) -> Callable[[str | Path, Analysis], Path]:
    def write(path: str | Path, analysis: Analysis) -> Path:
        return write_png(path, draw(analysis), photo=key in PHOTO_FIGURES)

    write.__name__ = write.__qualname__ = f"write_{key}_png"
    write.__doc__ = f"""Draw the figure ``{key}`` of ``analysis`` and write it to ``path`` as a PNG.

    Parameters
    ----------
    path : path-like
    analysis : Analysis

    Returns
    -------
    Path
        ``path``; the image is :func:`{draw.__module__}.{draw.__name__}`'s.
    """
    return write
