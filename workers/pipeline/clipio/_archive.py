"""Safe access to the files of a zip archive or a folder: the containers of frame-folder clips.

Zip archives are checked before anything is read: entries with absolute paths, drive letters or ``..``
components are refused (zip slip), as are encrypted entries; the entry count and the total declared
uncompressed size are capped. Reads never go past an entry's declared size (``zipfile`` enforces it and
checks the CRC), so a forged header cannot expand past the cap either. Nothing is extracted to disk
except by :meth:`Archive.extract`, which writes only below a folder the caller owns and counts bytes.
"""

from __future__ import annotations

import os
import shutil
import stat
import zipfile
import zlib
from pathlib import Path
from typing import IO

from workers.pipeline.clipio._common import check_inflation
from workers.pipeline.clipio.types import ReadLimits
from workers.pipeline.errors import ClipError, ClipTooLargeError

#: What opening or reading a damaged zip archive raises: a bad CRC or header, a broken deflate stream, a
#: cut file, an unsupported zip version or method, an encrypted member.
ZIP_ERRORS = (
    zipfile.BadZipFile,
    zlib.error,
    OSError,
    EOFError,
    ValueError,
    NotImplementedError,
    RuntimeError,
)


def _safe_name(raw: str, fmt: str) -> str:
    """Normalise an entry name to a relative POSIX path, refusing anything that escapes the archive."""
    name = raw.replace("\\", "/")
    parts = name.split("/")  # as PurePosixPath's parts, once the empty and "." ones are dropped below
    if (
        name.startswith("/")
        or (len(name) > 1 and name[1] == ":")
        or any(p == ".." for p in parts)
        or "\x00" in name
    ):
        raise ClipError(
            f"{fmt}: archive entry {raw!r} points outside the archive (absolute path or '..'); "
            "refusing the upload -- re-create the zip with relative paths"
        )
    return "/".join(p for p in parts if p not in ("", "."))


class Archive:
    """Read-only view of the regular files in a zip archive or a folder, by relative POSIX name."""

    def __init__(self, path: str | Path, fmt: str, limits: ReadLimits) -> None:
        self.path = Path(path)
        self.fmt = fmt
        self.limits = limits
        self._zip: zipfile.ZipFile | None = None
        self._sizes: dict[str, int] = {}
        self._zinfo: dict[str, zipfile.ZipInfo] = {}
        if self.path.is_dir():
            self._scan_dir()
        else:
            self._scan_zip()

    def _scan_dir(self) -> None:
        root = self.path
        count = 0
        for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
            dirnames[:] = [d for d in dirnames if not os.path.islink(os.path.join(dirpath, d))]
            for fn in filenames:
                full = os.path.join(dirpath, fn)
                st = os.lstat(full)
                if not stat.S_ISREG(st.st_mode):
                    continue
                count += 1
                if count > self.limits.max_entries:
                    raise ClipTooLargeError(
                        f"{self.fmt}: folder holds more than {self.limits.max_entries} files; trim it"
                    )
                self._sizes[Path(full).relative_to(root).as_posix()] = st.st_size

    def _scan_zip(self) -> None:
        try:
            self._zip = zipfile.ZipFile(self.path)
            infos = self._zip.infolist()
        except ZIP_ERRORS as exc:
            raise ClipError(f"{self.fmt}: {self.path.name} is not a readable zip archive ({exc})") from exc
        if len(infos) > self.limits.max_entries:
            raise ClipTooLargeError(
                f"{self.fmt}: archive lists {len(infos)} entries, over the cap of {self.limits.max_entries}"
            )
        total = 0
        packed = 0
        for info in infos:
            name = _safe_name(info.filename, self.fmt)
            if not name or info.is_dir():
                continue
            if info.flag_bits & 0x1:
                raise ClipError(f"{self.fmt}: entry {name!r} is encrypted; upload an unencrypted zip")
            mode = info.external_attr >> 16
            if mode and stat.S_ISLNK(mode):
                raise ClipError(f"{self.fmt}: entry {name!r} is a symbolic link; zip the files themselves")
            check_inflation(self.fmt, f"entry {name!r}", info.file_size, info.compress_size, self.limits)
            total += info.file_size
            packed += info.compress_size
            if total > self.limits.max_uncompressed_bytes:
                raise ClipTooLargeError(
                    f"{self.fmt}: archive expands to more than {self.limits.max_uncompressed_bytes} bytes "
                    "(the cap on uncompressed size); refusing it -- split the clip or raise the cap"
                )
            if name in self._sizes:
                raise ClipError(f"{self.fmt}: entry {name!r} appears twice in the archive")
            self._sizes[name] = info.file_size
            self._zinfo[name] = info
        check_inflation(self.fmt, "the archive", total, packed, self.limits)

    @property
    def is_zip(self) -> bool:
        return self._zip is not None

    @property
    def names(self) -> list[str]:
        """The files' names (a new list each time: for lookups use ``name in archive``)."""
        return list(self._sizes)

    def __contains__(self, name: object) -> bool:
        """Whether the archive holds a file ``name``, in constant time."""
        return name in self._sizes

    def size(self, name: str) -> int:
        return self._sizes[name]

    def open(self, name: str) -> IO[bytes]:
        """Open a member for streaming reads (seekable)."""
        if self._zip is not None:
            try:
                return self._zip.open(self._zinfo[name])
            except ZIP_ERRORS as exc:
                raise ClipError(f"{self.fmt}: entry {name!r} is corrupt ({exc})") from exc
        return (self.path / name).open("rb")

    def read(self, name: str, max_bytes: int | None = None, *, head: int | None = None) -> bytes:
        """Read a member whole (``head``: only its first bytes), refusing members over ``max_bytes``."""
        size = self._sizes[name]
        if max_bytes is not None and size > max_bytes:
            raise ClipTooLargeError(
                f"{self.fmt}: entry {name!r} is {size} bytes, more than the {max_bytes} expected for it"
            )
        want = size if head is None else min(size, head)
        try:
            with self.open(name) as fh:
                data = fh.read(want)
        except ZIP_ERRORS as exc:
            raise ClipError(f"{self.fmt}: entry {name!r} is corrupt or truncated ({exc})") from exc
        if len(data) != want:
            raise ClipError(f"{self.fmt}: entry {name!r} is truncated ({len(data)} of {want} bytes)")
        return data

    def extract(self, names: list[str], dest: Path) -> None:
        """Copy members below ``dest`` (which must exist), counting bytes against the size cap."""
        dest = dest.resolve()
        written = 0
        for name in names:
            target = (dest / name).resolve()
            if dest not in target.parents:
                raise ClipError(f"{self.fmt}: entry {name!r} points outside the archive; refusing it")
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with self.open(name) as src, target.open("wb") as out:
                    while chunk := src.read(1 << 20):
                        written += len(chunk)
                        if written > self.limits.max_uncompressed_bytes:
                            raise ClipTooLargeError(
                                f"{self.fmt}: unpacking exceeds the cap of "
                                f"{self.limits.max_uncompressed_bytes} bytes; refusing it"
                            )
                        out.write(chunk)
            except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError) as exc:
                raise ClipError(f"{self.fmt}: entry {name!r} is corrupt or truncated ({exc})") from exc

    def close(self) -> None:
        if self._zip is not None:
            self._zip.close()
            self._zip = None


def common_root(names: list[str]) -> str:
    """The single top-level folder every name lives in (with trailing slash), or ``""``."""
    tops = {n.split("/", 1)[0] for n in names if not _ignorable(n)}
    if len(tops) == 1:
        top = tops.pop()
        if top in ("rgb", "depth"):  # the layout's own folder, not a wrapper
            return ""
        if all(n.startswith(top + "/") for n in names if not _ignorable(n)):
            return top + "/"
    return ""


def _ignorable(name: str) -> bool:
    base = name.rsplit("/", 1)[-1]
    return name.startswith("__MACOSX/") or base.startswith("._") or base in (".DS_Store", "Thumbs.db")


def visible(names: list[str]) -> list[str]:
    """Names without OS clutter (``__MACOSX/``, ``._*``, ``.DS_Store``)."""
    return [n for n in names if not _ignorable(n)]


def rmtree_quiet(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)
