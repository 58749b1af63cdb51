"""A clip upload as a streamed ``multipart/form-data`` body: known length, read in chunks, progress reported.

The body is made by a factory, so a retried request sends it again from the start.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

#: ``progress(sent_bytes, total_bytes)``, called as the body goes out.
ProgressCallback = Callable[[int, int], None]

CHUNK_BYTES = 256 * 1024


def _quote(name: str) -> str:
    return name.replace("\\", "\\\\").replace('"', "%22").replace("\r", "%0D").replace("\n", "%0A")


@dataclass(frozen=True)
class UploadBody:
    """The multipart body of one file in field ``file``."""

    path: Path
    filename: str
    boundary: str
    progress: ProgressCallback | None = None

    @classmethod
    def of(
        cls,
        path: str | os.PathLike[str],
        *,
        filename: str | None = None,
        progress: ProgressCallback | None = None,
    ) -> UploadBody:
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such file")
        return cls(p, filename or p.name, "eigenscope-" + secrets.token_hex(16), progress)

    @property
    def head(self) -> bytes:
        return (
            f"--{self.boundary}\r\n"
            f'Content-Disposition: form-data; name="file"; filename="{_quote(self.filename)}"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n"
        ).encode()

    @property
    def tail(self) -> bytes:
        return f"\r\n--{self.boundary}--\r\n".encode()

    @property
    def content_type(self) -> str:
        return f"multipart/form-data; boundary={self.boundary}"

    def length(self) -> int:
        return len(self.head) + self.path.stat().st_size + len(self.tail)

    def headers(self) -> dict[str, str]:
        return {"Content-Type": self.content_type, "Content-Length": str(self.length())}

    def chunks(self) -> Iterator[bytes]:
        """The body, from its start, calling ``progress`` after each chunk."""
        total = self.length()
        sent = 0

        def report(n: int) -> None:
            nonlocal sent
            sent += n
            if self.progress is not None:
                self.progress(sent, total)

        head = self.head
        yield head
        report(len(head))
        with self.path.open("rb") as fh:
            while chunk := fh.read(CHUNK_BYTES):
                yield chunk
                report(len(chunk))
        yield self.tail
        report(len(self.tail))

    async def achunks(self) -> AsyncIterator[bytes]:
        """:meth:`chunks` for an async client (chunks are small: a file read does not hold the loop)."""
        for chunk in self.chunks():
            yield chunk
