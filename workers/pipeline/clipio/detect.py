"""Format detection from file content (magic bytes and archive layout), not only the extension."""

from __future__ import annotations

import zipfile
from pathlib import Path

from workers.pipeline.clipio.npz import NpzClip
from workers.pipeline.clipio.types import ClipOverrides, ClipReader, ReadLimits
from workers.pipeline.errors import ClipError, UnsupportedFormatError


def detect_format(path: str | Path) -> str:
    """Name the clip format of the file at ``path``.

    Returns
    -------
    str
        One of ``npz``.

    Raises
    ------
    UnsupportedFormatError
        When the content matches no supported format.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise ClipError(f"cannot read {path.name}: {exc.strerror or exc}") from exc
    if not head:
        raise ClipError(f"{path.name} is empty")
    if head.startswith(b"PK"):
        try:
            with zipfile.ZipFile(path) as zf:
                names = zf.namelist()
        except zipfile.BadZipFile as exc:
            raise ClipError(f"{path.name} looks like a zip archive but is corrupt or truncated ({exc})") from exc
        if any(n.removesuffix(".npy") == "rgb" for n in names):
            return "npz"
    raise UnsupportedFormatError(
        f"{path.name}: not a clip format Eigenscope reads (supported: .npz bundle with an 'rgb' array)"
    )


def open_clip(
    path: str | Path,
    *,
    overrides: ClipOverrides | None = None,
    limits: ReadLimits | None = None,
) -> ClipReader:
    """Open a clip of any supported format for streaming.

    Parameters
    ----------
    path : path-like
    overrides : ClipOverrides, optional
        User-given metadata (fps, intrinsics, depth scale); each given field wins over the file.
    limits : ReadLimits, optional
        Caps on frames, pixels and decompressed size.

    Returns
    -------
    ClipReader
        Use as a context manager; ``reader.info`` describes the clip, ``reader.frames()`` streams it.
    """
    fmt = detect_format(path)
    if fmt == "npz":
        return NpzClip(path, overrides=overrides, limits=limits)
    raise UnsupportedFormatError(f"{Path(path).name}: format {fmt!r} has no reader")  # pragma: no cover
