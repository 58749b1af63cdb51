"""How live-stream frames and messages travel between the API process and the stream workers.

The API never decodes a frame: it relays the client's binary messages to the worker that runs the
session, and the worker's JSON messages back. Two transports with one interface:

- :class:`RedisTransport` (``EIGENSCOPE_REDIS_URL``): sessions are handed out through a Redis list,
  frames go through a Redis stream per session (``XADD MAXLEN``: bounded; the worker deletes each entry
  as it reads it), messages come back through another. Both are deleted when the session ends (and
  the session's entry of the pending list with them, should it have ended before a worker took it up)
  and expire an hour after their last write in any case, so no frame stays in Redis after its session.
- :class:`LocalTransport` (embedded mode): the same through files in ``DATA_DIR/streams`` (atomic
  renames), for an API and workers on one machine.

Flow control is the relay's: it never has more than ``Settings.stream_window`` frame messages in flight,
so the bounds above never drop a message the worker has not read.

Worker side (blocking): :meth:`claim`, :meth:`read`, :meth:`send`, :meth:`cleanup`. API side (asyncio):
:meth:`dispatch`, :meth:`push`, :meth:`receive`, :meth:`acleanup`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import secrets
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Protocol

from backend.settings import Settings

#: Keys of a session's Redis entries expire this long after their last write (insurance: a session that
#: ends normally deletes them at once).
KEY_TTL_S = 3600
#: Worker messages kept per session (older ones are trimmed; a relay reads them within milliseconds).
OUT_KEEP = 1024
#: A stream's analysis window when ``parameters.frames`` is not given: what its worker keeps
#: (``workers/streams.py``) and what the API checks against the job memory budget when the stream is
#: created (``service/streams.py``).
DEFAULT_WINDOW_FRAMES = 256


@dataclass(frozen=True, slots=True)
class Item:
    """One entry of a session's input: a client frame message (``data``) or a control message."""

    kind: Literal["frame", "control"]
    data: bytes
    control: dict[str, Any] | None = None


def _control(message: dict[str, Any]) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode()


class StreamTransport(Protocol):
    """See the module docstring."""

    def claim(self, timeout_s: float) -> str | None: ...
    def read(self, stream_id: str, timeout_s: float) -> list[Item]: ...
    def send(self, stream_id: str, message: dict[str, Any]) -> None: ...
    def cleanup(self, stream_id: str) -> None: ...
    async def dispatch(self, stream_id: str) -> None: ...
    async def push(
        self, stream_id: str, *, frame: bytes | None = None, control: dict[str, Any] | None = None
    ) -> None: ...
    async def receive(
        self, stream_id: str, cursor: str, timeout_s: float
    ) -> tuple[list[dict[str, Any]], str]: ...
    async def acleanup(self, stream_id: str) -> None: ...
    async def last_cursor(self, stream_id: str) -> str: ...
    def close(self) -> None: ...


def transport_for(settings: Settings) -> StreamTransport:
    """The transport of these settings: Redis when ``redis_url`` is set, else the local one."""
    if settings.redis_url:
        return RedisTransport(settings.redis_url, window=settings.stream_window, namespace=settings.queue)
    return LocalTransport(settings.data_path / "streams")


# Redis ---------------------------------------------------------------------------------------------


class RedisTransport:
    """Sessions, frames and messages in Redis (see the module docstring)."""

    def __init__(self, url: str, *, window: int, namespace: str = "eigenscope") -> None:
        self.url = url
        #: Sessions waiting for a worker (one list per deployment: its queue name).
        self.pending = f"{namespace}:streams:pending"
        #: Hard cap of a session's input stream: the relay keeps at most ``window`` frames in it, plus
        #: control messages; entries beyond are only ever ones already read (and deleted).
        self.maxlen = 2 * window + 64
        self._sync: Any = None
        self._async: Any = None

    @staticmethod
    def _in(stream_id: str) -> str:
        return f"eigenscope:stream:{stream_id}:in"

    @staticmethod
    def _out(stream_id: str) -> str:
        return f"eigenscope:stream:{stream_id}:out"

    @property
    def sync(self) -> Any:
        if self._sync is None:
            import redis

            self._sync = redis.Redis.from_url(self.url, socket_connect_timeout=5, socket_timeout=30)
        return self._sync

    @property
    def aio(self) -> Any:
        if self._async is None:
            import redis.asyncio

            self._async = redis.asyncio.Redis.from_url(self.url, socket_connect_timeout=5, socket_timeout=30)
        return self._async

    # worker side
    def claim(self, timeout_s: float) -> str | None:
        got = self.sync.brpop([self.pending], timeout=max(1, round(timeout_s)))
        return None if got is None else got[1].decode()

    def read(self, stream_id: str, timeout_s: float) -> list[Item]:
        key = self._in(stream_id)
        got = self.sync.xread({key: "0"}, count=64, block=max(1, int(timeout_s * 1000)))
        items: list[Item] = []
        ids = []
        for _key, entries in got or []:
            for entry_id, fields in entries:
                ids.append(entry_id)
                kind = fields.get(b"k", b"f")
                data = fields.get(b"d", b"")
                if kind == b"c":
                    items.append(Item("control", data, json.loads(data)))
                else:
                    items.append(Item("frame", data))
        if ids:
            self.sync.xdel(key, *ids)
        return items

    def send(self, stream_id: str, message: dict[str, Any]) -> None:
        key = self._out(stream_id)
        pipe = self.sync.pipeline(transaction=False)
        pipe.xadd(key, {b"m": _control(message)}, maxlen=OUT_KEEP, approximate=True)
        pipe.expire(key, KEY_TTL_S)
        pipe.execute()

    def cleanup(self, stream_id: str) -> None:
        pipe = self.sync.pipeline(transaction=False)
        pipe.delete(self._in(stream_id), self._out(stream_id))
        pipe.lrem(self.pending, 0, stream_id)  # a stream that ended before a worker took it up
        pipe.execute()

    # API side
    async def dispatch(self, stream_id: str) -> None:
        await self.aio.lpush(self.pending, stream_id)

    async def push(
        self, stream_id: str, *, frame: bytes | None = None, control: dict[str, Any] | None = None
    ) -> None:
        key = self._in(stream_id)
        fields = (
            {b"k": b"f", b"d": frame} if frame is not None else {b"k": b"c", b"d": _control(control or {})}
        )
        pipe = self.aio.pipeline(transaction=False)
        pipe.xadd(key, fields, maxlen=self.maxlen, approximate=False)
        pipe.expire(key, KEY_TTL_S)
        await pipe.execute()

    async def receive(
        self, stream_id: str, cursor: str, timeout_s: float
    ) -> tuple[list[dict[str, Any]], str]:
        got = await self.aio.xread(
            {self._out(stream_id): cursor}, count=256, block=max(1, int(timeout_s * 1000))
        )
        messages = []
        for _key, entries in got or []:
            for entry_id, fields in entries:
                cursor = entry_id.decode() if isinstance(entry_id, bytes) else str(entry_id)
                messages.append(json.loads(fields[b"m"]))
        return messages, cursor

    async def acleanup(self, stream_id: str) -> None:
        pipe = self.aio.pipeline(transaction=False)
        pipe.delete(self._in(stream_id), self._out(stream_id))
        pipe.lrem(self.pending, 0, stream_id)
        await pipe.execute()

    async def last_cursor(self, stream_id: str) -> str:
        """The id of the newest worker message (``"0"`` when none): a new relay reads from there on."""
        got = await self.aio.xrevrange(self._out(stream_id), count=1)
        if not got:
            return "0"
        entry_id = got[0][0]
        return entry_id.decode() if isinstance(entry_id, bytes) else str(entry_id)

    def close(self) -> None:
        if self._sync is not None:
            with contextlib.suppress(Exception):
                self._sync.close()
            self._sync = None
        self._async = None


# Local ---------------------------------------------------------------------------------------------


class LocalTransport:
    """Sessions, frames and messages as files under ``root`` (one machine; see the module docstring).

    ``pending/<id>`` hands a session out (claimed by an atomic rename); ``<id>/in/`` holds input entries
    named so that they sort in arrival order; ``<id>/out/<seq>.json`` the worker's messages.
    """

    POLL_S = 0.002

    def __init__(self, root: Path) -> None:
        self.root = Path(root)
        self._out_seq: dict[str, int] = {}
        self._counter = 0

    def _dir(self, stream_id: str, sub: str) -> Path:
        if not stream_id.isalnum():
            raise ValueError(f"bad stream id {stream_id!r}")
        return self.root / stream_id / sub

    def _write(self, folder: Path, name: str, data: bytes) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{name}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, folder / name)

    # worker side
    def claim(self, timeout_s: float) -> str | None:
        pending, claimed = self.root / "pending", self.root / "claimed"
        claimed.mkdir(parents=True, exist_ok=True)
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                names = sorted(os.listdir(pending))
            except FileNotFoundError:
                names = []
            for name in names:
                if name.startswith("."):
                    continue
                try:
                    os.replace(pending / name, claimed / name)
                except FileNotFoundError:
                    continue  # another worker was first
                return name
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.02)

    def read(self, stream_id: str, timeout_s: float) -> list[Item]:
        folder = self._dir(stream_id, "in")
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                names = sorted(n for n in os.listdir(folder) if not n.startswith("."))
            except FileNotFoundError:
                names = []
            if names:
                items = []
                for name in names[:64]:
                    path = folder / name
                    data = path.read_bytes()
                    path.unlink()
                    if name.endswith(".c"):
                        items.append(Item("control", data, json.loads(data)))
                    else:
                        items.append(Item("frame", data))
                return items
            if time.monotonic() >= deadline:
                return []
            time.sleep(self.POLL_S)

    def send(self, stream_id: str, message: dict[str, Any]) -> None:
        seq = self._out_seq.get(stream_id, 0) + 1
        self._out_seq[stream_id] = seq
        folder = self._dir(stream_id, "out")
        self._write(folder, f"{seq:010d}.json", _control(message))
        if seq > OUT_KEEP and seq % 64 == 0:
            for old in range(seq - OUT_KEEP - 64, seq - OUT_KEEP):
                (folder / f"{old:010d}.json").unlink(missing_ok=True)

    def cleanup(self, stream_id: str) -> None:
        self._out_seq.pop(stream_id, None)
        shutil.rmtree(self.root / stream_id, ignore_errors=True)
        (self.root / "claimed" / stream_id).unlink(missing_ok=True)
        (self.root / "pending" / stream_id).unlink(missing_ok=True)  # it ended before a worker took it up

    def stream_ids(self) -> list[str]:
        """The streams that have files here (for the sweeper: those of ended streams go)."""
        try:
            return [n for n in os.listdir(self.root) if n.isalnum() and n not in ("pending", "claimed")]
        except FileNotFoundError:
            return []

    # API side
    async def dispatch(self, stream_id: str) -> None:
        self._dir(stream_id, "in").mkdir(parents=True, exist_ok=True)
        self._write(self.root / "pending", stream_id, b"")

    async def push(
        self, stream_id: str, *, frame: bytes | None = None, control: dict[str, Any] | None = None
    ) -> None:
        self._counter += 1
        # Sortable by arrival across processes: wall time first, then this process and its counter.
        name = f"{time.time_ns():020d}-{os.getpid():08d}-{self._counter:010d}"
        if frame is not None:
            self._write(self._dir(stream_id, "in"), name + ".f", frame)
        else:
            self._write(self._dir(stream_id, "in"), name + ".c", _control(control or {}))

    async def receive(
        self, stream_id: str, cursor: str, timeout_s: float
    ) -> tuple[list[dict[str, Any]], str]:
        folder = self._dir(stream_id, "out")
        seq = int(cursor)
        deadline = time.monotonic() + timeout_s
        messages: list[dict[str, Any]] = []
        while True:
            while True:
                path = folder / f"{seq + 1:010d}.json"
                try:
                    data = path.read_bytes()
                except FileNotFoundError:
                    break
                messages.append(json.loads(data))
                seq += 1
            if messages or time.monotonic() >= deadline:
                return messages, str(seq)
            await asyncio.sleep(self.POLL_S)

    async def acleanup(self, stream_id: str) -> None:
        self.cleanup(stream_id)

    async def last_cursor(self, stream_id: str) -> str:
        folder = self._dir(stream_id, "out")
        try:
            seqs = [int(n[:10]) for n in os.listdir(folder) if n.endswith(".json") and not n.startswith(".")]
        except FileNotFoundError:
            seqs = []
        return str(max(seqs, default=0))

    def close(self) -> None:
        """Nothing to release."""


def new_token() -> str:
    """A resume token: 192 random bits."""
    return secrets.token_urlsafe(24)
