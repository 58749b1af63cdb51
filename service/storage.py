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
import uuid
from pathlib import Path
from typing import BinaryIO

from service.errors import (
    InsufficientStorageError,
    NotFoundError,
    PayloadTooLargeError,
    StorageUnavailableError,
)

_SUFFIX = re.compile(r"^\.[A-Za-z0-9]{1,12}(\.[A-Za-z0-9]{1,6})?$")
_ARTIFACT_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
#: ``tmp/job-<job id>-<attempt>-<random>[-scratch]``: one attempt's outputs (and scratch) being written.
_WORKDIR = re.compile(r"^job-([0-9A-Za-z]+)-\d+-[0-9a-f]{8}(?:-scratch)?$")


def safe_suffix(filename: str | None) -> str:
    """The file name's extension(s) if they are plain (``.npz``, ``.tar.gz``), else ``""``.

    Some readers look at the extension as a hint (bags, videos), so it is kept; the name is not.
    """
    if not filename:
        return ""
    name = Path(filename.replace("\\", "/")).name
    suffixes = "".join(Path(name).suffixes[-2:]).lower()
    if _SUFFIX.match(suffixes):
        return suffixes
    last = Path(name).suffix.lower()
    return last if _SUFFIX.match(last) else ""


class UploadSink:
    """A file being uploaded into ``tmp/``: write chunks, then :meth:`commit` or :meth:`discard`."""

    def __init__(self, path: Path, limit_bytes: int, *, hashing: bool = False) -> None:
        self.path = path
        self.limit_bytes = limit_bytes
        self.size = 0
        self._hash = hashlib.sha256() if hashing else None
        self._fh: BinaryIO | None = path.open("xb")

    def write(self, chunk: bytes) -> None:
        if self._fh is None:
            raise ValueError("upload already closed")
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
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        self.path.unlink(missing_ok=True)
        if self.path.parent.name.startswith("upload-"):
            shutil.rmtree(self.path.parent, ignore_errors=True)

    def give_name(self, filename: str | None) -> None:
        """Move the closed upload to ``tmp/upload-<random>/clip<ext>``: readers see the extension of the
        client's file name (a format hint) and report ``clip<ext>``, never an internal or client path."""
        self.close()
        folder = self.path.with_name(self.path.name + ".d")
        folder.mkdir()
        target = folder / f"clip{safe_suffix(filename)}"
        os.replace(self.path, target)
        self.path = target


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

    def new_upload(self, limit_bytes: int, *, hashing: bool = False) -> UploadSink:
        """A new file in ``tmp/`` (hashed as it is written with ``hashing``); :class:`StorageUnavailableError`
        if the storage cannot be written."""
        try:
            return UploadSink(self.root / "tmp" / f"upload-{uuid.uuid4().hex}", limit_bytes, hashing=hashing)
        except OSError as exc:
            raise StorageUnavailableError(
                f"the clip storage cannot be written ({exc.strerror or type(exc).__name__}); try again later"
            ) from exc

    def keep_clip(self, sink: UploadSink, clip_id: str, filename: str | None) -> str:
        """Move a finished upload into place; returns its path relative to the root.

        On failure nothing is left in ``clips/`` (the caller discards the upload).
        """
        folder = self.root / "clips" / clip_id
        try:
            sink.close()
            folder.mkdir(parents=True, exist_ok=False)
            target = folder / f"clip{safe_suffix(filename)}"
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
