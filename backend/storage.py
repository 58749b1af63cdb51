"""The storage directory: uploaded clips and each job's artifacts.

Layout under the data directory::

    clips/<clip id>/clip<.ext>     uploaded clips
    jobs/<job id>/                 result.json, mask.png and the other images of a finished job
    tmp/                           uploads and job outputs being written (same filesystem: atomic renames)

Files are written to ``tmp/`` first and renamed into place, so a reader never sees half a file.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import socket
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from backend.errors import (
    InsufficientStorageError,
    NotFoundError,
    PayloadTooLargeError,
    StorageUnavailableError,
)

_ARTIFACT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
#: This host, as uploads in ``tmp/`` name it (8 hex digits of a hash of its name).
_HOST = hashlib.sha256(socket.gethostname().encode()).hexdigest()[:8]
#: ``tmp/upload-<host>-<pid>-<random>[.d]``: an upload being received (or validated, ``.d``).
_UPLOAD = re.compile(r"^upload-([0-9a-f]{8})-(\d+)-[0-9a-f]{32}(?:\.d)?$")
#: ``tmp/job-<job id>-<attempt>-<random>[-scratch]``: one attempt's outputs (and scratch) being written.
_WORKDIR = re.compile(r"^job-([0-9A-Za-z]+)-\d+-[0-9a-f]{8}(?:-scratch)?$")


#: The stored clip's extension, by the format its content was detected as (never the client's name).
_FORMAT_SUFFIX = {
    "npz": ".npz",
    "zip-frames": ".zip",
    "tum": ".zip",
    "open3d": ".zip",
    "k4a-mkv": ".mkv",
    "ros1-bag": ".bag",
}
#: ... and for the formats whose files come in several containers, by the content's magic bytes.
_MAGIC_SUFFIX = (
    (b"PK", ".zip"),
    (b"\x89MCAP", ".mcap"),
    (b"SQLite format 3\x00", ".db3"),
    (b"\x1a\x45\xdf\xa3", ".mkv"),
    (b"RIFF", ".avi"),
)


#: Extensions of a client's file name that the file being validated keeps, as a hint for the readers'
#: messages (e.g. "npz: ... is truncated" rather than "zip: ..."); nothing else of the name is used.
HINT_SUFFIXES = frozenset(
    {".npz", ".zip", ".bag", ".mcap", ".db3", ".mkv", ".mp4", ".m4v", ".mov", ".avi", ".webm"}
    | {".mpg", ".mpeg", ".wmv", ".flv", ".ts"}
)


def hint_suffix(filename: str | None) -> str:
    """The client's extension if it is one of :data:`HINT_SUFFIXES`, else ``""``."""
    suffix = Path((filename or "").replace("\\", "/")).suffix.lower()
    return suffix if suffix in HINT_SUFFIXES else ""


def stored_suffix(fmt: str | None, head: bytes) -> str:
    """The extension of a stored clip of format ``fmt`` whose file starts with ``head``.

    Chosen by the server from what the probe found in the content: the client's file name never names
    a file on the server (a reader given ``x.m3u8`` could be led to open other files).
    """
    if fmt in _FORMAT_SUFFIX:
        return _FORMAT_SUFFIX[fmt]
    if head[4:8] == b"ftyp":
        return ".mp4"
    for magic, suffix in _MAGIC_SUFFIX:
        if head.startswith(magic):
            return suffix
    return ""


class Reservations:
    """The bytes of the uploads being received now, per tenant (in this process): the running count a
    storage quota is checked against as a body arrives, so that a body without ``Content-Length`` (or
    several at once) stops at the quota instead of being written whole first."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._held: dict[str, int] = {}

    def take(self, tenant: str, size: int, allowed: int, refuse: Callable[[int], Exception]) -> None:
        """Count ``size`` more bytes of ``tenant``'s; raise ``refuse(held)`` past ``allowed`` in all."""
        with self._lock:
            held = self._held.get(tenant, 0)
            if held + size > allowed:
                raise refuse(held)
            self._held[tenant] = held + size

    def release(self, tenant: str, size: int) -> None:
        with self._lock:
            left = self._held.get(tenant, 0) - size
            if left > 0:
                self._held[tenant] = left
            else:
                self._held.pop(tenant, None)

    def held(self, tenant: str) -> int:
        with self._lock:
            return self._held.get(tenant, 0)


@dataclass
class Quota:
    """What an upload may add to its tenant's storage: ``allowed`` bytes, counted in ``reservations``
    with the tenant's other uploads; ``refuse(held)`` is the error past it."""

    reservations: Reservations
    tenant: str
    allowed: int
    refuse: Callable[[int], Exception]


class UploadSink:
    """A file being uploaded into ``tmp/``: write chunks, then :meth:`commit` or :meth:`discard`."""

    def __init__(
        self, path: Path, limit_bytes: int, *, hashing: bool = False, quota: Quota | None = None
    ) -> None:
        self.path = path
        self.limit_bytes = limit_bytes
        self.size = 0
        self.quota = quota
        self._hash = hashlib.sha256() if hashing else None
        self._fh: BinaryIO | None = path.open("xb")

    def release_quota(self) -> None:
        """Stop counting this upload against its tenant's quota (it was kept, and is counted as a clip
        now, or discarded)."""
        if self.quota is not None:
            self.quota.reservations.release(self.quota.tenant, self.size)
            self.quota = None

    def write(self, chunk: bytes) -> None:
        if self._fh is None:
            raise ValueError("upload already closed")
        if self.quota is not None:
            q = self.quota
            q.reservations.take(q.tenant, len(chunk), q.allowed, q.refuse)
        self.size += len(chunk)
        if self.size > self.limit_bytes:
            raise PayloadTooLargeError(
                f"the upload exceeds the limit of {self.limit_bytes // (1024 * 1024)} MiB "
                "(EIGENSCOPE_MAX_UPLOAD_MB); trim the clip or raise the limit",
                code="upload-too-large",
                max_bytes=self.limit_bytes,
            )
        if self._hash is not None:
            self._hash.update(chunk)
        try:
            self._fh.write(chunk)
        except OSError as exc:
            if exc.errno == 28:  # ENOSPC
                raise InsufficientStorageError("the server's storage is full; try again later") from exc
            raise

    @property
    def sha256(self) -> str | None:
        """Hex SHA-256 of the bytes written (None unless made with ``hashing=True``)."""
        return self._hash.hexdigest() if self._hash is not None else None

    def close(self) -> None:
        if self._fh is not None:
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()
            self._fh = None

    def discard(self) -> None:
        self.release_quota()
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        self.path.unlink(missing_ok=True)
        if self.path.parent.name.startswith("upload-"):
            shutil.rmtree(self.path.parent, ignore_errors=True)

    def give_name(self, filename: str | None) -> None:
        """Move the closed upload to ``tmp/upload-<random>.d/clip-<random><ext>`` for validation: a name
        of the server's own, so that the readers' messages name neither an internal nor a client path
        (the caller puts the client's name in their place). ``<ext>`` is one of :data:`HINT_SUFFIXES`
        when the client's name ends with it (the readers detect the format from the content and take
        the extension only as a hint for their messages), else none."""
        self.close()
        folder = self.path.with_name(self.path.name + ".d")
        folder.mkdir()
        target = folder / f"clip-{uuid.uuid4().hex[:12]}{hint_suffix(filename)}"
        os.replace(self.path, target)
        self.path = target

    def head(self, size: int = 64) -> bytes:
        """The first ``size`` bytes of the (closed) upload."""
        with self.path.open("rb") as fh:
            return fh.read(size)


class Storage:
    """Clips and artifacts in a directory tree (see the module docstring)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root).expanduser().resolve()

    def ensure(self) -> None:
        """Create the directory tree."""
        for sub in ("clips", "jobs", "tmp"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    def check(self) -> None:
        """Raise ``OSError`` unless the storage is writable."""
        probe = self.root / "tmp" / f".ready-{uuid.uuid4().hex}"
        probe.write_bytes(b"ok")
        probe.unlink()

    def free_bytes(self) -> int:
        """Free bytes on the storage's filesystem; :class:`StorageUnavailableError` if it is gone."""
        try:
            return shutil.disk_usage(self.root).free
        except OSError as exc:
            raise StorageUnavailableError(
                f"the clip storage is unavailable ({exc.strerror or type(exc).__name__}); try again later"
            ) from exc

    # Clips -----------------------------------------------------------------------------------

    def new_upload(
        self, limit_bytes: int, *, hashing: bool = False, quota: Quota | None = None
    ) -> UploadSink:
        """A new file in ``tmp/`` (hashed as it is written with ``hashing``); :class:`StorageUnavailableError`
        if the storage cannot be written.

        Its name, ``upload-<host>-<pid>-<random>``, says which process writes it, so that an upload a
        crashed process left is known as such (:meth:`remove_abandoned_uploads`)."""
        name = f"upload-{_HOST}-{os.getpid()}-{uuid.uuid4().hex}"
        try:
            return UploadSink(self.root / "tmp" / name, limit_bytes, hashing=hashing, quota=quota)
        except OSError as exc:
            raise StorageUnavailableError(
                f"the clip storage cannot be written ({exc.strerror or type(exc).__name__}); try again later"
            ) from exc

    def remove_abandoned_uploads(self, *, idle_s: float) -> int:
        """Remove the uploads in ``tmp/`` (being received or validated) whose process on this host is gone,
        and any untouched for ``idle_s`` (a body stalls for less before it is refused, a validation
        lasts less); returns how many were removed."""
        removed = 0
        cutoff = time.time() - idle_s
        try:
            entries = list(os.scandir(self.root / "tmp"))
        except FileNotFoundError:
            return 0
        for entry in entries:
            if not entry.name.startswith("upload-"):
                continue
            match = _UPLOAD.match(entry.name)
            try:
                dead = match is not None and match.group(1) == _HOST and not pid_alive(int(match.group(2)))
                if dead or entry.stat(follow_symlinks=False).st_mtime < cutoff:
                    if entry.is_dir(follow_symlinks=False):
                        shutil.rmtree(entry.path, ignore_errors=True)
                    else:
                        os.unlink(entry.path)
                    removed += 1
            except OSError:
                continue
        return removed

    def keep_clip(self, sink: UploadSink, clip_id: str, fmt: str | None) -> str:
        """Move a finished upload of format ``fmt`` (as the probe detected it) into place as
        ``clips/<id>/clip<ext>``, the extension the server's (:func:`stored_suffix`); returns its path
        relative to the root.

        On failure nothing is left in ``clips/`` (the caller discards the upload).
        """
        folder = self.root / "clips" / clip_id
        try:
            sink.close()
            folder.mkdir(parents=True, exist_ok=False)
            target = folder / f"clip{stored_suffix(fmt, sink.head())}"
            os.replace(sink.path, target)
            if sink.path.parent.name.startswith("upload-"):
                shutil.rmtree(sink.path.parent, ignore_errors=True)
        except OSError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            if exc.errno == 28:  # ENOSPC
                raise InsufficientStorageError("the server's storage is full; try again later") from exc
            raise StorageUnavailableError(
                f"the clip storage cannot be written ({exc.strerror or type(exc).__name__}); try again later"
            ) from exc
        return target.relative_to(self.root).as_posix()

    def clip_path(self, relative: str) -> Path:
        path = (self.root / relative).resolve()
        if not path.is_relative_to(self.root):
            raise ValueError(f"clip path {relative!r} escapes the data directory")
        return path

    def delete_clip(self, clip_id: str) -> None:
        shutil.rmtree(self.root / "clips" / clip_id, ignore_errors=True)

    # Job outputs -----------------------------------------------------------------------------

    def job_dir(self, job_id: str) -> Path:
        return self.root / "jobs" / job_id

    def new_job_workdir(self, job_id: str, attempt: int) -> Path:
        """An empty directory for one attempt's outputs, on the same filesystem as ``jobs/``."""
        path = self.root / "tmp" / f"job-{job_id}-{attempt}-{uuid.uuid4().hex[:8]}"
        path.mkdir(parents=True)
        return path

    def job_workdirs(self) -> dict[str, list[Path]]:
        """The attempt folders in ``tmp/`` (outputs and scratch being written), by job id."""
        found: dict[str, list[Path]] = {}
        try:
            entries = list(os.scandir(self.root / "tmp"))
        except FileNotFoundError:
            return found
        for entry in entries:
            match = _WORKDIR.match(entry.name)
            if match:
                found.setdefault(match.group(1), []).append(Path(entry.path))
        return found

    def remove_job_workdirs(self, job_id: str, *, keep: Path | None = None) -> int:
        """Remove the attempt folders of ``job_id`` (but ``keep``); returns how many were removed.

        Called when an attempt is abandoned (its worker was killed or lost its lease) and when the job is
        claimed again, so a killed attempt leaves nothing behind.
        """
        removed = 0
        for path in self.job_workdirs().get(job_id, []):
            if keep is not None and path == keep:
                continue
            shutil.rmtree(path, ignore_errors=True)
            removed += 1
        return removed

    def publish_job_outputs(self, job_id: str, workdir: Path) -> Path:
        """Atomically make ``workdir`` the job's output directory (replacing an older attempt's)."""
        target = self.job_dir(job_id)
        if target.exists():
            old = self.root / "tmp" / f"old-{job_id}-{uuid.uuid4().hex[:8]}"
            os.replace(target, old)
            shutil.rmtree(old, ignore_errors=True)
        os.replace(workdir, target)
        return target

    def artifact_path(self, job_id: str, name: str) -> Path:
        """The path of artifact ``name`` of a job; 404 for odd names or missing files."""
        if not _ARTIFACT_NAME.match(name) or ".." in name:
            raise NotFoundError(f"job {job_id} has no artifact {name!r}", code="artifact-not-found")
        path = self.job_dir(job_id) / name
        if not path.is_file():
            raise NotFoundError(f"job {job_id} has no artifact {name!r}", code="artifact-not-found")
        return path

    def delete_job_outputs(self, job_id: str) -> None:
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)

    # Retention -------------------------------------------------------------------------------

    def entries_older_than(self, kind: str, cutoff: float) -> list[str]:
        """Names of the ``clips/`` or ``jobs/`` folders last changed before ``cutoff`` (epoch seconds)."""
        folder = self.root / kind
        names = []
        try:
            entries = list(os.scandir(folder))
        except FileNotFoundError:
            return []
        for entry in entries:
            try:
                if entry.stat(follow_symlinks=False).st_mtime < cutoff:
                    names.append(entry.name)
            except OSError:
                continue
        return names

    def remove_entry(self, kind: str, name: str) -> None:
        """Remove ``clips/<name>`` or ``jobs/<name>`` (a folder or a stray file)."""
        if kind not in ("clips", "jobs") or "/" in name or name in ("", ".", ".."):
            raise ValueError(f"not a storage entry: {kind}/{name}")
        path = self.root / kind / name
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this host (this process always does)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def tree_bytes(path: Path) -> int:
    """Total size of the files under ``path``."""
    total = 0
    for dirpath, _dirs, files in os.walk(path):
        for name in files:
            try:
                total += (Path(dirpath) / name).stat().st_size
            except OSError:
                continue
    return total
