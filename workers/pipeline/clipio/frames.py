"""Clips stored as image files in a zip archive (or a folder): the frame-folder and TUM RGB-D layouts.

Frame-folder layout (format ``zip-frames``)
    ``rgb/*.png|jpg|jpeg`` colour frames and optionally ``depth/*.png`` (16-bit, depth units), each in
    natural name order (``f2`` before ``f10``); the two folders must hold the same number of frames of
    the same size. Optional ``camera.json`` ``{"fps", "fx", "fy", "cx", "cy", "depth_scale"}``; any
    field may be missing and given by flags instead (flags win). Depth scale defaults to 0.001 m/unit.

TUM RGB-D layout (format ``tum``)
    ``rgb.txt`` and ``depth.txt`` (``timestamp filename`` per line, ``#`` comments) with ``rgb/`` and
    ``depth/`` folders, as in the TUM benchmark; depth scale 1/5000 m/unit. Each colour frame is paired
    with the depth frame nearest in time; colour frames with no depth frame within 0.75 of a frame
    period are dropped (counted in ``ClipInfo.notes``). The timestamps give the frame rate and the
    dropped-frame count. Intrinsics from ``camera.json`` if present, else flags.

Either layout may sit inside one top-level folder of the archive. Frames are read one at a time.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio._archive import Archive, common_root, visible
from workers.pipeline.clipio._common import (
    ImageHeader,
    associate_nearest,
    check_decoded,
    check_frames,
    check_image,
    check_size,
    decode_color,
    decode_depth_png,
    image_header,
    natural_key,
    pairing_tolerance,
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
)
from workers.pipeline.errors import ClipError

COLOR_EXTS = (".png", ".jpg", ".jpeg")
TUM_DEPTH_SCALE = 1.0 / 5000.0
DEFAULT_DEPTH_SCALE = 0.001
_HEADER_BYTES = 64 * 1024
_SMALL_HEADER_BYTES = 1024
_CAMERA_FIELDS = ("fps", "fx", "fy", "cx", "cy", "depth_scale")


def read_json_object(archive: Archive, name: str, fmt: str, *, fields: str = "") -> dict[str, Any]:
    """Parse a small JSON file of the clip that must hold one object (``fields`` names them in errors)."""
    raw = archive.read(name, max_bytes=1 << 20)
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ClipError(
            f"{fmt}: {name} is not valid JSON ({exc}); fix it or give the values as flags"
        ) from exc
    if not isinstance(data, dict):
        raise ClipError(f"{fmt}: {name} must be a JSON object" + (f" with fields {fields}" if fields else ""))
    return data


def read_camera_json(archive: Archive, name: str, fmt: str) -> dict[str, float]:
    """Parse ``camera.json``: a JSON object of the numeric fields ``fps fx fy cx cy depth_scale``."""
    data = read_json_object(archive, name, fmt, fields=", ".join(_CAMERA_FIELDS))
    out: dict[str, float] = {}
    for key in _CAMERA_FIELDS:
        if key not in data or data[key] is None:
            continue
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ClipError(f"{fmt}: {name} field {key!r} must be a number, got {value!r}")
        out[key] = float(value)
    return out


def camera_intrinsics(
    camera: dict[str, float], overrides: ClipOverrides, width: int, height: int, fmt: str
) -> Intrinsics | None:
    """Intrinsics from ``camera.json`` values under the user's overrides; None without a focal length."""
    merged: dict[str, float | None] = {}
    for key in ("fx", "fy", "cx", "cy"):
        given = getattr(overrides, key)
        if given is not None:
            merged[key] = given
            continue
        value = camera.get(key)
        if value is not None and not math.isfinite(value):
            raise ClipError(f"{fmt}: camera.json {key}={value} is not finite; fix it or pass --{key}")
        if value is not None and key in ("fx", "fy") and value <= 0:
            raise ClipError(f"{fmt}: camera.json {key}={value} must be a positive focal length in pixels")
        merged[key] = value
    return ClipOverrides(fx=merged["fx"], fy=merged["fy"], cx=merged["cx"], cy=merged["cy"]).intrinsics_over(
        None, width, height
    )


def camera_depth_scale(camera: dict[str, float], overrides: ClipOverrides, default: float, fmt: str) -> float:
    if overrides.depth_scale is not None:
        return overrides.depth_scale
    scale = camera.get("depth_scale", default)
    if not (math.isfinite(scale) and scale > 0):
        raise ClipError(
            f"{fmt}: camera.json depth_scale={scale} must be a positive number of metres per unit; "
            "fix it or pass --depth-scale"
        )
    return scale


def _parse_tum_list(archive: Archive, name: str, root: str) -> tuple[NDArray[np.float64], list[str]]:
    raw = archive.read(name, max_bytes=64 << 20)
    stamps: list[float] = []
    files: list[str] = []
    for lineno, line in enumerate(raw.decode("utf-8", errors="replace").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) < 2:
            raise ClipError(f"tum: {name} line {lineno} must be 'timestamp filename', got {line[:60]!r}")
        try:
            t = float(parts[0])
        except ValueError:
            raise ClipError(f"tum: {name} line {lineno} has a non-numeric timestamp {parts[0]!r}") from None
        if not math.isfinite(t):
            raise ClipError(f"tum: {name} line {lineno} has a non-finite timestamp {parts[0]!r}")
        stamps.append(t)
        files.append(root + parts[1].replace("\\", "/").lstrip("./"))
    return np.asarray(stamps, dtype=np.float64), files


def _tum_frames(
    archive: Archive, rel: dict[str, str], root: str, notes: list[str]
) -> tuple[list[str], list[str] | None, NDArray[np.float64]]:
    """The frame files of a TUM sequence from ``rgb.txt`` (and ``depth.txt``), in time order.

    Parameters
    ----------
    archive : Archive
    rel : dict
        Archive names keyed by their name relative to the sequence's ``root`` folder.
    root : str
    notes : list of str
        Appended to: the colour frames dropped for want of a depth frame, and how depth was paired.

    Returns
    -------
    (rgb_files, depth_files, rgb_times)
        Colour frame names, the depth frame nearest in time to each (None without ``depth.txt``), and
        the colour frames' timestamps, seconds.
    """
    rgb_t, rgb_files = _parse_tum_list(archive, rel["rgb.txt"], root)
    if len(rgb_files) == 0:
        raise ClipError("tum: rgb.txt lists no frames")
    order = np.argsort(rgb_t, kind="stable")
    rgb_t = rgb_t[order]
    rgb_files = [rgb_files[i] for i in order]
    if "depth.txt" not in rel:
        return rgb_files, None, rgb_t
    d_t, d_files = _parse_tum_list(archive, rel["depth.txt"], root)
    if len(d_files) == 0:
        raise ClipError("tum: depth.txt lists no frames; remove it or add the depth frames")
    d_order = np.argsort(d_t, kind="stable")
    d_t = d_t[d_order]
    d_files = [d_files[i] for i in d_order]
    tol = pairing_tolerance(rgb_t, d_t)
    idx, ok = associate_nearest(rgb_t, d_t, tol)
    if int(ok.sum()) < len(ok):
        notes.append(
            f"{len(ok) - int(ok.sum())} colour frames had no depth frame within "
            f"{tol * 1000:.0f} ms and were dropped"
        )
    rgb_t = rgb_t[ok]
    rgb_files = [f for f, keep in zip(rgb_files, ok, strict=True) if keep]
    depth_files = [d_files[i] for i in idx[ok]]
    notes.append("depth paired to colour by nearest timestamp")
    return rgb_files, depth_files, rgb_t


def _folder_frames(rel: dict[str, str]) -> tuple[list[str], list[str] | None]:
    """The ``rgb/`` and ``depth/`` frame files of the frame-folder layout, each in natural name order
    (depth None without ``depth/``); ``rel`` keys archive names by their name relative to the root."""
    rgb_files = sorted(
        (n for r, n in rel.items() if r.startswith("rgb/") and r.lower().endswith(COLOR_EXTS)),
        key=natural_key,
    )
    if not rgb_files:
        listing = ", ".join(sorted({r.split("/", 1)[0] for r in rel})[:8]) or "nothing"
        raise ClipError(
            f"zip-frames: no colour frames under rgb/ (found: {listing}); put rgb/*.png or "
            "rgb/*.jpg in the zip"
        )
    depth_list = sorted(
        (n for r, n in rel.items() if r.startswith("depth/") and r.lower().endswith(".png")),
        key=natural_key,
    )
    depth_files = depth_list or None
    if depth_files is not None and len(depth_files) != len(rgb_files):
        raise ClipError(
            f"zip-frames: {len(rgb_files)} colour frames but {len(depth_files)} depth frames; "
            "rgb/ and depth/ must hold one frame each per time step (or remove depth/)"
        )
    return rgb_files, depth_files


def _stream_names(is_tum: bool, has_depth: bool, has_camera: bool) -> tuple[str, ...]:
    """What ``ClipInfo.streams`` lists for a frame-folder or TUM clip."""
    if is_tum:
        streams = ["rgb.txt", *(["depth.txt"] if has_depth else [])]
    else:
        streams = ["rgb/"] + (["depth/"] if has_depth else [])
    if has_camera:
        streams.append("camera.json")
    return tuple(streams)


class FramesClip(ClosingReader):
    """Reader of the frame-folder (``zip-frames``) and TUM (``tum``) layouts; see the module docstring."""

    def __init__(
        self,
        path: str | Path,
        *,
        overrides: ClipOverrides | None = None,
        limits: ReadLimits | None = None,
        archive: Archive | None = None,
    ) -> None:
        self.path = Path(path)
        overrides = overrides or ClipOverrides()
        limits = limits or ReadLimits()
        self._archive = archive or Archive(self.path, "zip-frames", limits)
        # Every frame's declared size is checked against these before it is decoded (subclasses too).
        self._limits = limits
        self._max_frame_bytes = limits.max_pixels_per_frame * 8 + (1 << 20)
        try:
            self._setup(overrides, limits)
        except Exception:
            self._archive.close()
            raise

    def _setup(self, overrides: ClipOverrides, limits: ReadLimits) -> None:
        names = visible(self._archive.names)
        root = common_root(names)
        rel = {n[len(root) :]: n for n in names if n.startswith(root)}
        is_tum = "rgb.txt" in rel
        fmt = "tum" if is_tum else "zip-frames"
        self._fmt = self._archive.fmt = fmt
        camera: dict[str, float] = {}
        if "camera.json" in rel:
            camera = read_camera_json(self._archive, rel["camera.json"], fmt)

        notes: list[str] = []
        stamps: NDArray[np.float64] | None = None
        if is_tum:
            rgb_files, depth_files, stamps = _tum_frames(self._archive, rel, root, notes)
            default_scale = TUM_DEPTH_SCALE
        else:
            rgb_files, depth_files = _folder_frames(rel)
            default_scale = DEFAULT_DEPTH_SCALE
        # The frame count before any per-frame work; each lookup in constant time (a zip may list
        # hundreds of thousands of entries).
        check_frames(fmt, len(rgb_files), limits)
        for f in rgb_files + (depth_files or []):
            if f not in self._archive:
                raise ClipError(f"{fmt}: frame file {f!r} is listed but missing from the archive")
        width, height = self._check_frame_headers(rgb_files, depth_files, limits)

        timing = resolve_timing(
            fmt,
            user_fps=overrides.fps,
            declared_fps=camera.get("fps") if "fps" in camera else None,
            declared_source="bundle",
            timestamps_s=stamps,
        )
        depth_scale = camera_depth_scale(camera, overrides, default_scale, fmt)
        self._rgb_files = rgb_files
        self._depth_files = depth_files
        self._depth_scale = depth_scale
        self._info = ClipInfo(
            format=fmt,
            frames=len(rgb_files),
            width=width,
            height=height,
            fps=timing.fps,
            fps_source=timing.fps_source,
            has_depth=depth_files is not None,
            depth_scale=depth_scale if depth_files is not None else None,
            intrinsics=camera_intrinsics(camera, overrides, width, height, fmt),
            timestamps_s=timing.timestamps_s,
            dropped_frames=timing.dropped_frames,
            streams=_stream_names(is_tum, bool(depth_files), "camera.json" in rel),
            measured_fps=timing.measured_fps,
            container_fps=camera.get("fps"),
            size_bytes=_size_of(self.path),
            depth_source=(root + "depth/") if depth_files is not None else None,
            notes=tuple(notes) + timing.notes,
        )

    def _check_frame_headers(
        self, rgb_files: list[str], depth_files: list[str] | None, limits: ReadLimits
    ) -> tuple[int, int]:
        """The clip's frame size (width, height), from the first colour frame, once every frame's header
        declares it (and the depth frames are 16-bit single-channel PNGs).

        Every header is read before any frame is decoded: a frame deep in the clip that declares a larger
        size (a decompression bomb) is refused here, at the upload's validation.
        """
        fmt = self._fmt
        head = self._header(rgb_files[0])
        width, height = head.width, head.height
        check_size(fmt, width, height, limits)
        check_decoded(fmt, len(rgb_files), width, height, depth_files is not None, limits)
        self._max_frame_bytes = width * height * 8 + (1 << 20)
        if depth_files is not None:
            dh = self._header(depth_files[0])
            if dh.kind != "png" or dh.bit_depth != 16 or dh.channels != 1:
                raise ClipError(
                    f"{fmt}: depth frame {depth_files[0]!r} must be a 16-bit single-channel PNG "
                    f"(got {dh.kind}, {dh.bit_depth}-bit, {dh.channels} channel(s))"
                )
            if (dh.width, dh.height) != (width, height):
                raise ClipError(
                    f"{fmt}: depth frames are {dh.width}x{dh.height} but colour frames are {width}x{height}; "
                    "depth must be aligned to colour, same size"
                )
        for names, is_depth in ((rgb_files, False), (depth_files or [], True)):
            for name in names:
                check_image(
                    self._header(name), f"{fmt}: {name}", limits, size=(width, height), depth=is_depth
                )
        return width, height

    def _header(self, name: str) -> ImageHeader:
        """The header of frame file ``name``, reading as little of it as its format needs."""
        what = f"{self._fmt}: {name}"
        size = self._archive.size(name)
        for want in (_SMALL_HEADER_BYTES, _HEADER_BYTES):
            data = self._archive.read(name, head=want)
            try:
                return image_header(data, what)
            except ClipError:
                if len(data) == size:
                    raise
        # A JPEG with long metadata before its frame header.
        return image_header(self._archive.read(name, self._max_frame_bytes), what)

    def _checked(self, name: str, data: bytes, *, depth: bool) -> bytes:
        """``data`` of frame ``name`` once its header declares the clip's size (before it is decoded)."""
        info = self._info
        what = f"{self._fmt}: {name}"
        check_image(image_header(data, what), what, self._limits, size=(info.width, info.height), depth=depth)
        return data

    @property
    def info(self) -> ClipInfo:
        return self._info

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``; see :class:`~workers.pipeline.clipio.types.Frame`."""
        info = self._info
        stop = info.frames if stop is None else min(stop, info.frames)
        if not 0 <= start <= stop:
            raise ClipError(
                f"{self._fmt}: frame range [{start}, {stop}) is outside the clip's {info.frames} frames"
            )
        fps = info.fps or 1.0
        for index in range(start, stop):
            name = self._rgb_files[index]
            data = self._checked(name, self._archive.read(name, self._max_frame_bytes), depth=False)
            rgb = decode_color(data, f"{self._fmt}: {name}")
            if rgb.shape[:2] != (info.height, info.width):
                raise ClipError(
                    f"{self._fmt}: frame {name!r} is {rgb.shape[1]}x{rgb.shape[0]}, but the clip is "
                    f"{info.width}x{info.height}; all frames must have one size"
                )
            depth: NDArray[np.float32] | None = None
            if self._depth_files is not None:
                dname = self._depth_files[index]
                ddata = self._checked(dname, self._archive.read(dname, self._max_frame_bytes), depth=True)
                raw = decode_depth_png(ddata, f"{self._fmt}: {dname}")
                if raw.shape != (info.height, info.width):
                    raise ClipError(
                        f"{self._fmt}: depth frame {dname!r} is {raw.shape[1]}x{raw.shape[0]}, but colour "
                        f"is {info.width}x{info.height}"
                    )
                depth = depth_to_metres(raw, self._depth_scale)
            t = float(info.timestamps_s[index]) if info.timestamps_s is not None else index / fps
            yield Frame(index=index, rgb=rgb, depth_m=depth, timestamp_s=t)

    def close(self) -> None:
        self._archive.close()


def _size_of(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())
    return path.stat().st_size
