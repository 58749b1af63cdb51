"""The native clip bundle: an ``.npz`` archive.

Keys
----
rgb : uint8, (T, H, W, 3)
depth : uint16 (T, H, W) in depth units, or float32 metres -- optional
fps : scalar
intrinsics : [fx, fy, cx, cy] -- optional
depth_scale : metres per unit, default 0.001 -- optional
timestamps : float seconds, (T,) -- optional

Frames are streamed straight out of the archive member (stored or deflated), so memory stays at a frame
or two whatever the clip length.
"""

from __future__ import annotations

import math
import tokenize
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.lib import format as npy_format
from numpy.typing import NDArray

from workers.pipeline.clipio._archive import ZIP_ERRORS
from workers.pipeline.clipio._common import (
    check_decoded,
    check_frames,
    check_inflation,
    check_size,
    resolve_timing,
)
from workers.pipeline.clipio.types import (
    ClipInfo,
    ClipOverrides,
    ClosingReader,
    Frame,
    Intrinsics,
    ReadLimits,
    depth_to_metres,
    sample_nearest,
)
from workers.pipeline.errors import ClipError

DEFAULT_DEPTH_SCALE = 0.001
_SMALL_KEYS = ("fps", "intrinsics", "depth_scale", "timestamps")
_KNOWN_KEYS = {"rgb", "depth", *_SMALL_KEYS}


class _Member:
    """An array inside the archive, read lazily as a stream of leading-axis slices."""

    def __init__(self, archive: zipfile.ZipFile, name: str, key: str) -> None:
        self.archive = archive
        self.name = name
        self.key = key
        self.info = archive.getinfo(name)
        if self.info.flag_bits & 0x1:
            raise ClipError(f"npz: '{key}' is encrypted; save the bundle without a password")
        try:
            with archive.open(name) as fh:
                self.shape, self.fortran, self.dtype = _read_header(fh, key)
                self.header_bytes = fh.tell()
        except ZIP_ERRORS as exc:
            raise ClipError(f"npz: '{key}' cannot be read ({exc}); re-export the clip") from exc
        if any(s < 0 for s in self.shape):
            raise ClipError(f"npz: '{key}' declares the shape {self.shape}; re-export the clip")

    @property
    def nbytes(self) -> int:
        """Bytes of the array's data, from its header (Python ints: no overflow)."""
        return math.prod(self.shape) * self.dtype.itemsize

    def check_bounds(self, limits: ReadLimits) -> None:
        """Refuse, from the headers alone, a member whose data the archive cannot hold or that inflates
        like a decompression bomb."""
        if self.nbytes > self.info.file_size - self.header_bytes:
            raise ClipError(
                f"npz: '{self.key}' declares {self.shape} {self.dtype} ({self.nbytes} bytes) but its archive "
                f"member holds {max(self.info.file_size - self.header_bytes, 0)}; the file is truncated or "
                "forged -- re-export the clip"
            )
        if self.info.compress_type != zipfile.ZIP_STORED:
            check_inflation("npz", f"'{self.key}'", self.info.file_size, self.info.compress_size, limits)

    def small(self, limit_bytes: int = 1 << 20) -> NDArray[Any]:
        nbytes = self.nbytes
        if nbytes > limit_bytes:
            raise ClipError(f"npz: '{self.key}' holds {nbytes} bytes; expected a small metadata array")
        if self.dtype.hasobject:
            raise ClipError(f"npz: '{self.key}' holds Python objects; store plain numbers")
        with self._open() as fh:
            _read_header(fh, self.key)
            data = _read(fh, nbytes, self.key)
        if len(data) != nbytes:
            raise ClipError(
                f"npz: '{self.key}' is truncated ({len(data)} of {nbytes} bytes); re-export the clip"
            )
        order = "F" if self.fortran else "C"
        flat: NDArray[Any] = np.frombuffer(data, dtype=self.dtype)
        return flat.reshape(self.shape, order="F" if order == "F" else "C")

    def slices(self, start: int, stop: int) -> Iterator[NDArray[Any]]:
        """Yield ``array[i]`` for ``start <= i < stop`` without loading the whole array."""
        if self.fortran:
            raise ClipError(
                f"npz: '{self.key}' is stored in Fortran order, which cannot be streamed; "
                "save it with np.ascontiguousarray"
            )
        per = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize
        stored = self._stored_range(per)
        if stored is not None:
            data_start, complete = stored
            with open(str(self.archive.filename), "rb", buffering=0) as raw:
                raw.seek(data_start + per * start)
                for index in range(start, stop):
                    frame = np.empty(self.shape[1:], self.dtype)
                    if index >= complete or raw.readinto(frame.data.cast("B")) != per:
                        raise ClipError(
                            f"npz: '{self.key}' is truncated at frame {index} of {self.shape[0]}; "
                            "re-export the clip"
                        )
                    yield frame
            return
        with self._open() as fh:
            _read_header(fh, self.key)
            _skip(fh, per * start, self.key)
            for index in range(start, stop):
                buf = _read(fh, per, self.key)
                if len(buf) != per:
                    raise ClipError(
                        f"npz: '{self.key}' is truncated at frame {index} of {self.shape[0]}; "
                        "re-export the clip"
                    )
                yield np.frombuffer(buf, dtype=self.dtype).reshape(self.shape[1:])

    def _open(self) -> IO[bytes]:
        try:
            return self.archive.open(self.name)
        except ZIP_ERRORS as exc:
            raise ClipError(f"npz: '{self.key}' is corrupt ({exc}); re-export the clip") from exc

    def _stored_range(self, per: int) -> tuple[int, int] | None:
        """Where a stored (uncompressed) member's frames start in the file, and how many are complete.

        Reading a stored member through :mod:`zipfile` copies every byte twice and checks its CRC, which
        costs as much as the flow of a frame; a stored member is a plain byte range of the file, read
        here straight into each frame's array.

        Returns
        -------
        (offset, frames) or None
            Byte offset of frame 0 and the count of frames wholly present; None for deflated or
            encrypted members and archives not opened from a path.
        """
        info = self.archive.getinfo(self.name)
        path = self.archive.filename
        if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1 or not path or per <= 0:
            return None
        with open(path, "rb") as fh:
            fh.seek(info.header_offset)
            local = fh.read(30)
            if len(local) != 30 or local[:4] != b"PK\x03\x04":
                return None
            name_len = int.from_bytes(local[26:28], "little")
            extra_len = int.from_bytes(local[28:30], "little")
            fh.seek(info.header_offset + 30 + name_len + extra_len)
            member_start = fh.tell()
            _read_header(fh, self.key)
            data_start = fh.tell()
            size = fh.seek(0, 2)
        available = min(info.file_size - (data_start - member_start), size - data_start)
        return data_start, min(self.shape[0], max(available, 0) // per)


def _read(fh: IO[bytes], nbytes: int, key: str) -> bytes:
    """Up to ``nbytes`` of a member; a damaged member is a :class:`ClipError`."""
    try:
        return fh.read(nbytes)
    except ZIP_ERRORS as exc:
        raise ClipError(f"npz: '{key}' is corrupt ({exc}); re-export the clip") from exc


def _skip(fh: IO[bytes], nbytes: int, key: str) -> None:
    chunk = 1 << 22
    while nbytes > 0:
        got = _read(fh, min(chunk, nbytes), key)
        if not got:
            raise ClipError("npz: archive member ends early; the file is truncated")
        nbytes -= len(got)


def _read_header(fh: IO[bytes], key: str) -> tuple[tuple[int, ...], bool, np.dtype[Any]]:
    try:
        version = npy_format.read_magic(fh)
        if version == (1, 0):
            shape, fortran, dtype = npy_format.read_array_header_1_0(fh)
        else:
            shape, fortran, dtype = npy_format.read_array_header_2_0(fh)
    except (*ZIP_ERRORS, tokenize.TokenError, SyntaxError, TypeError) as exc:  # numpy parses it
        raise ClipError(f"npz: '{key}' is not a readable .npy array ({exc}); re-export the clip") from exc
    return tuple(int(s) for s in shape), bool(fortran), np.dtype(dtype)


def _scalar(member: _Member, what: str) -> float:
    arr = member.small()
    if arr.size != 1 or not np.issubdtype(arr.dtype, np.number):
        raise ClipError(f"npz: '{member.key}' must be a single number ({what}), got shape {arr.shape}")
    return float(arr.reshape(()))


def _rgb_shape(rgb: _Member) -> tuple[int, int, int]:
    """``(frames, height, width)`` of the ``rgb`` array, which must be (T, H, W, 3) uint8."""
    if len(rgb.shape) != 4 or rgb.shape[3] != 3:
        raise ClipError(f"npz: 'rgb' must have shape (T, H, W, 3), got {rgb.shape}")
    if rgb.dtype != np.uint8:
        raise ClipError(f"npz: 'rgb' must be uint8, got {rgb.dtype}; scale to 0..255 and cast to uint8")
    frames, height, width = rgb.shape[:3]
    return frames, height, width


def _check_depth(depth: _Member, shape: tuple[int, int, int]) -> None:
    """The ``depth`` array must be one map per colour frame, ``shape`` (T, H, W), uint16 or float."""
    if depth.shape != shape:
        raise ClipError(
            f"npz: 'depth' has shape {depth.shape} but 'rgb' implies {shape}; "
            "depth must be aligned to the colour frames, one map per frame"
        )
    if not (depth.dtype == np.uint16 or np.issubdtype(depth.dtype, np.floating)):
        raise ClipError(f"npz: 'depth' must be uint16 (depth units) or float32 (metres), got {depth.dtype}")


def _depth_scale(members: dict[str, _Member]) -> float:
    """Metres per depth unit from ``depth_scale`` (a positive number), default 0.001."""
    if "depth_scale" not in members:
        return DEFAULT_DEPTH_SCALE
    depth_scale = _scalar(members["depth_scale"], "metres per depth unit")
    if not (math.isfinite(depth_scale) and depth_scale > 0):
        raise ClipError(f"npz: depth_scale={depth_scale} must be a positive number of metres per unit")
    return depth_scale


def _timestamps(members: dict[str, _Member], frames: int) -> NDArray[np.float64] | None:
    """The ``timestamps`` array (one finite value per frame) as seconds from the first; None without it."""
    if "timestamps" not in members:
        return None
    ts = members["timestamps"].small(limit_bytes=64 * frames + 1024).astype(np.float64).ravel()
    if ts.shape != (frames,):
        raise ClipError(f"npz: 'timestamps' has {ts.size} values for {frames} frames")
    if not np.all(np.isfinite(ts)):
        raise ClipError("npz: 'timestamps' contains NaN or infinite values")
    timestamps: NDArray[np.float64] = ts - ts[0]
    return timestamps


def _intrinsics(members: dict[str, _Member]) -> Intrinsics | None:
    """The ``intrinsics`` array ``[fx, fy, cx, cy]``; None without it."""
    if "intrinsics" not in members:
        return None
    k = members["intrinsics"].small().astype(np.float64).ravel()
    if k.shape != (4,):
        raise ClipError(f"npz: 'intrinsics' must be [fx, fy, cx, cy], got {k.size} values")
    return Intrinsics(fx=float(k[0]), fy=float(k[1]), cx=float(k[2]), cy=float(k[3]))


class NpzClip(ClosingReader):
    """Reader of the native ``.npz`` bundle. See the module docstring for the layout."""

    def __init__(
        self,
        path: str | Path,
        *,
        overrides: ClipOverrides | None = None,
        limits: ReadLimits | None = None,
    ) -> None:
        self.path = Path(path)
        overrides = overrides or ClipOverrides()
        limits = limits or ReadLimits()
        try:
            self._zip = zipfile.ZipFile(self.path)
        except ZIP_ERRORS as exc:
            raise ClipError(f"npz: {self.path.name} is not a readable .npz archive ({exc})") from exc
        try:
            self._info, self._rgb, self._depth = self._validate(overrides, limits)
        except Exception:
            self._zip.close()
            raise

    def _validate(
        self, overrides: ClipOverrides, limits: ReadLimits
    ) -> tuple[ClipInfo, _Member, _Member | None]:
        members = self._members()
        rgb = members["rgb"]
        frames, height, width = _rgb_shape(rgb)
        check_frames("npz", frames, limits)
        check_size("npz", width, height, limits)
        check_decoded("npz", frames, width, height, "depth" in members, limits)
        for member in members.values():
            member.check_bounds(limits)
        for streamed in (rgb, members.get("depth")):
            if streamed is not None and streamed.fortran:
                raise ClipError(
                    f"npz: '{streamed.key}' is stored in Fortran order, which cannot be streamed; "
                    "save it with np.ascontiguousarray"
                )
        depth = members.get("depth")
        if depth is not None:
            _check_depth(depth, (frames, height, width))
        depth_scale = _depth_scale(members)
        if overrides.depth_scale is not None:
            depth_scale = overrides.depth_scale
        timestamps = _timestamps(members, frames)
        declared: float | None = None
        if "fps" in members:
            declared = _scalar(members["fps"], "frames per second")
        timing = resolve_timing(
            "npz",
            user_fps=overrides.fps,
            declared_fps=declared,
            declared_source="bundle",
            timestamps_s=timestamps,
        )
        intrinsics = overrides.intrinsics_over(_intrinsics(members), width, height)
        info = ClipInfo(
            format="npz",
            frames=frames,
            width=width,
            height=height,
            fps=timing.fps,
            fps_source=timing.fps_source,
            has_depth=depth is not None,
            depth_scale=depth_scale if depth is not None else None,
            intrinsics=intrinsics,
            timestamps_s=timing.timestamps_s if timestamps is not None else None,
            dropped_frames=timing.dropped_frames,
            streams=tuple(sorted(members)),
            measured_fps=timing.measured_fps,
            container_fps=declared,
            size_bytes=self.path.stat().st_size,
            depth_source="depth" if depth is not None else None,
            notes=timing.notes,
        )
        return info, rgb, depth

    def _members(self) -> dict[str, _Member]:
        """The bundle's known arrays by key (their headers read); ``rgb`` must be among them."""
        members: dict[str, _Member] = {}
        names = self._zip.namelist()
        if len(names) > 64:
            raise ClipError(f"npz: {len(names)} entries; a clip bundle has at most {len(_KNOWN_KEYS)}")
        for name in names:
            key = name[:-4] if name.endswith(".npy") else name
            if key in _KNOWN_KEYS:
                if key in members:
                    raise ClipError(f"npz: '{key}' appears twice in the bundle; re-export the clip")
                members[key] = _Member(self._zip, name, key)
        if "rgb" not in members:
            found = ", ".join(sorted(n.removesuffix(".npy") for n in names)) or "nothing"
            raise ClipError(
                f"npz: missing key 'rgb' (found: {found}); save the colour frames as rgb=(T, H, W, 3) uint8"
            )
        return members

    @property
    def info(self) -> ClipInfo:
        return self._info

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``; see :class:`~workers.pipeline.clipio.types.Frame`."""
        return self._frames(start, stop, None)

    def frames_with_depth_on(
        self, shape: tuple[int, int], start: int = 0, stop: int | None = None
    ) -> Iterator[Frame]:
        """Frames as :meth:`frames`, with ``depth_m`` already resampled to ``shape`` (rows, columns).

        The stored depth is sampled (nearest neighbour, see
        :func:`~workers.pipeline.clipio.types.sample_nearest`) before it is converted to metres: the same
        values as converting the whole map and resizing it with INTER_NEAREST, with a quarter of the
        conversion's work for a half-resolution grid.
        """
        return self._frames(start, stop, shape)

    def _frames(self, start: int, stop: int | None, depth_shape: tuple[int, int] | None) -> Iterator[Frame]:
        total = self._info.frames
        stop = total if stop is None else min(stop, total)
        if not 0 <= start <= stop:
            raise ClipError(f"npz: frame range [{start}, {stop}) is outside the clip's {total} frames")
        fps = self._info.fps or 1.0
        ts = self._info.timestamps_s
        rgb_iter = self._rgb.slices(start, stop)
        depth_iter = self._depth.slices(start, stop) if self._depth is not None else None
        scale = self._info.depth_scale or DEFAULT_DEPTH_SCALE
        for index, rgb in enumerate(rgb_iter, start=start):
            depth = None
            if depth_iter is not None:
                raw = next(depth_iter)
                sampled = raw if depth_shape is None else sample_nearest(raw, depth_shape)
                depth = depth_to_metres(sampled, scale)
            t = float(ts[index]) if ts is not None else index / fps
            yield Frame(index=index, rgb=rgb, depth_m=depth, timestamp_s=t)

    def close(self) -> None:
        self._zip.close()


class NpzDepth:
    """The ``depth`` array of an ``.npz`` used as a depth companion of a video, streamed in metres."""

    def __init__(
        self, path: str | Path, *, overrides: ClipOverrides | None = None, limits: ReadLimits | None = None
    ) -> None:
        self.path = Path(path)
        overrides = overrides or ClipOverrides()
        limits = limits or ReadLimits()
        try:
            self._zip = zipfile.ZipFile(self.path)
        except ZIP_ERRORS as exc:
            raise ClipError(f"npz: {self.path.name} is not a readable .npz archive ({exc})") from exc
        try:
            members = {
                n.removesuffix(".npy"): _Member(self._zip, n, n.removesuffix(".npy"))
                for n in self._zip.namelist()
                if n.removesuffix(".npy") in ("depth", "depth_scale")
            }
            if "depth" not in members:
                raise ClipError(f"npz: {self.path.name} has no 'depth' array (T, H, W)")
            self._depth = members["depth"]
            if len(self._depth.shape) != 3:
                raise ClipError(f"npz: 'depth' must have shape (T, H, W), got {self._depth.shape}")
            for member in members.values():
                member.check_bounds(limits)
            if not (self._depth.dtype == np.uint16 or np.issubdtype(self._depth.dtype, np.floating)):
                raise ClipError(
                    f"npz: 'depth' must be uint16 (depth units) or float32 (metres), got {self._depth.dtype}"
                )
            scale = DEFAULT_DEPTH_SCALE
            if "depth_scale" in members:
                scale = _scalar(members["depth_scale"], "metres per depth unit")
                if not (math.isfinite(scale) and scale > 0):
                    raise ClipError(f"npz: depth_scale={scale} must be a positive number of metres per unit")
            self.depth_scale = overrides.depth_scale if overrides.depth_scale is not None else scale
            self.frames, self.height, self.width = self._depth.shape
        except Exception:
            self._zip.close()
            raise

    def slices(self, start: int, stop: int) -> Iterator[NDArray[np.float32]]:
        """Yield depth maps ``start <= i < stop`` as float32 metres, shape (H, W), NaN where invalid."""
        for raw in self._depth.slices(start, stop):
            yield depth_to_metres(raw, self.depth_scale)

    def close(self) -> None:
        self._zip.close()


def write_npz(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    fps: float,
    depth: NDArray[np.generic] | None = None,
    intrinsics: tuple[float, float, float, float] | None = None,
    depth_scale: float | None = None,
    timestamps: NDArray[np.float64] | None = None,
    compress: bool = False,
) -> Path:
    """Write a native clip bundle.

    Parameters
    ----------
    path : path-like
        Destination, conventionally ending in ``.npz``.
    rgb : ndarray of uint8, shape (T, H, W, 3)
    fps : float
    depth : ndarray of uint16 (T, H, W) in units of ``depth_scale``, or float32 metres, optional
    intrinsics : (fx, fy, cx, cy), optional
    depth_scale : float, optional
        Metres per depth unit (default 0.001 when depth is integer).
    timestamps : ndarray of float64, shape (T,), optional
    compress : bool
        Deflate the members (smaller file, slower to read).
    """
    arrays: dict[str, Any] = {"rgb": np.ascontiguousarray(rgb), "fps": np.float64(fps)}
    if depth is not None:
        arrays["depth"] = np.ascontiguousarray(depth)
    if intrinsics is not None:
        arrays["intrinsics"] = np.asarray(intrinsics, dtype=np.float64)
    if depth_scale is not None:
        arrays["depth_scale"] = np.float64(depth_scale)
    if timestamps is not None:
        arrays["timestamps"] = np.asarray(timestamps, dtype=np.float64)
    path = Path(path)
    with path.open("wb") as fh:
        (np.savez_compressed if compress else np.savez)(fh, **arrays)
    return path
