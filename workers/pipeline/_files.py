"""Files written whole or not at all (a temporary file in the target's folder, then ``os.replace``), with
the permissions of any file the user's programs create.

The temporary file (``tempfile.mkstemp``: mode 0600) gets :func:`artifact_mode` before it is renamed into
place, so ``result.json`` and every image end up alike, and as the user's ``umask`` asks (0644 under the
usual 022, 0640 under 027).
"""

from __future__ import annotations

import os
import tempfile
import threading
from pathlib import Path

_lock = threading.Lock()


def current_umask() -> int:
    """This process's umask, read without changing it where ``/proc`` says it (Linux 4.7 and later)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _lock:  # elsewhere the only way to read it is to set it
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def artifact_mode() -> int:
    """Mode of a written artifact: read-write as ``open()`` would create it under the current umask."""
    return 0o666 & ~current_umask()


def write_atomically(path: str | Path, data: bytes | str, *, mode: int | None = None) -> Path:
    """Write ``data`` to ``path`` so that a reader sees the old file or the new one, never half of one.

    Parameters
    ----------
    path : path-like
        The file to write; its folder must exist.
    data : bytes or str
        The whole content; str is written as UTF-8.
    mode : int, optional, keyword-only
        Permission bits of the new file; default :func:`artifact_mode` (as any file the user creates).

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
        os.chmod(tmp, artifact_mode() if mode is None else mode)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


__all__ = ["artifact_mode", "current_umask", "write_atomically"]
