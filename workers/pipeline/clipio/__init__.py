"""Clip I/O: detect a clip's format from its content, validate it and stream its frames.

Use :func:`open_clip` for every format; it returns a :class:`ClipReader` whose ``frames()`` yields
:class:`Frame` objects (RGB uint8, depth in float32 metres) one at a time.
"""

from workers.pipeline.clipio.detect import detect_format, open_clip
from workers.pipeline.clipio.npz import NpzClip, write_npz
from workers.pipeline.clipio.types import (
    ClipInfo,
    ClipOverrides,
    ClipReader,
    Frame,
    Intrinsics,
    ReadLimits,
)

__all__ = [
    "ClipInfo",
    "ClipOverrides",
    "ClipReader",
    "Frame",
    "Intrinsics",
    "NpzClip",
    "ReadLimits",
    "detect_format",
    "open_clip",
    "write_npz",
]
