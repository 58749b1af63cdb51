"""The permissions of the files an analysis writes: those of any file the user's programs create.

The atomic writers create a temporary file (``tempfile.mkstemp``: mode 0600) and rename it into place; they
give it :func:`artifact_mode` first, so ``result.json`` and every image end up alike, and as the user's
``umask`` asks (0644 under the usual 022, 0640 under 027).
"""

from __future__ import annotations

import os
import threading

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
