"""Images of a result: the machine-readable label mask (and, later, overlays and plots)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray


def write_label_png(path: str | Path, labels: NDArray[np.integer]) -> Path:
    """Write a label image as a single-channel PNG, atomically.

    Parameters
    ----------
    path : path-like
    labels : ndarray of int, shape (H, W)
        0 background, i = object i. Written as 8-bit when every label fits, else 16-bit.

    Returns
    -------
    Path
    """
    import cv2

    path = Path(path)
    top = int(labels.max()) if labels.size else 0
    data = labels.astype(np.uint8 if top < 256 else np.uint16)
    ok, buf = cv2.imencode(".png", data)
    if not ok:  # pragma: no cover - OpenCV always encodes 2-D integer arrays
        raise OSError(f"could not encode {path.name}")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".png")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(buf.tobytes())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
