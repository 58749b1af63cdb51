"""Files written whole or not at all: a temporary file in the target's folder, then ``os.replace``."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def write_atomically(path: str | Path, data: bytes | str, *, mode: int = 0o644) -> Path:
    """Write ``data`` to ``path`` so that a reader sees the old file or the new one, never half of one.

    Parameters
    ----------
    path : path-like
        The file to write; its folder must exist.
    data : bytes or str
        The whole content; str is written as UTF-8.
    mode : int, keyword-only
        Permission bits of the new file (default readable by all, as any ordinary file; a temporary
        file would otherwise keep ``mkstemp``'s 0600).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        When the folder is missing or not writable; no temporary file is left behind.
    """
    path = Path(path)
    payload = data.encode("utf-8") if isinstance(data, str) else data
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(payload)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


__all__ = ["write_atomically"]
