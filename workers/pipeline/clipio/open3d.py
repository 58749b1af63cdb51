"""Open3D RGB-D datasets (format ``open3d``), zipped or as a folder, possibly inside one top folder.

Layout (what Open3D's RealSense and Azure Kinect recorders and its reconstruction system use):

``color/*.jpg|png``
    Colour frames, in natural name order.
``depth/*.png``
    16-bit depth frames aligned to colour, one per colour frame, in natural name order.
``camera_intrinsic.json`` (or ``intrinsic.json``)
    ``{"width", "height", "intrinsic_matrix": [fx, 0, 0, 0, fy, 0, cx, cy, 1]}`` -- the 3x3 matrix
    **column-major**, as ``open3d.camera.PinholeCameraIntrinsic`` writes it.
``config.json`` (optional)
    ``depth_scale`` in Open3D's sense, depth *units per metre* (default 1000, millimetres), and ``fps``.
    A ``depth_scale`` of at most 1 is read as metres per unit instead, with a note.

Flags win over every file (``--fps``, ``--fx`` ..., ``--depth-scale`` in metres per unit). The frames are
streamed one at a time by :class:`~workers.pipeline.clipio.frames.FramesClip`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from workers.pipeline.clipio._archive import Archive, common_root, visible
from workers.pipeline.clipio._common import (
    check_frames,
    check_size,
    image_header,
    natural_key,
    resolve_timing,
)
from workers.pipeline.clipio.frames import COLOR_EXTS, FramesClip, _size_of, read_json_object
from workers.pipeline.clipio.types import ClipInfo, ClipOverrides, Intrinsics, ReadLimits
from workers.pipeline.errors import ClipError

FORMAT = "open3d"
#: Open3D's default: depth in millimetres, 1000 units per metre.
DEFAULT_UNITS_PER_METRE = 1000.0
INTRINSIC_FILES = ("camera_intrinsic.json", "intrinsic.json")
_HEADER_BYTES = 64 * 1024


def is_open3d_layout(relative_names: list[str]) -> bool:
    """True when names (relative to the dataset's root) hold Open3D's ``color/`` frames."""
    return any(n.startswith("color/") and n.lower().endswith(COLOR_EXTS) for n in relative_names)


def _number(data: dict[str, Any], key: str, name: str) -> float | None:
    value = data.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ClipError(f"{FORMAT}: {name} field {key!r} must be a finite number, got {value!r}")
    return float(value)


def read_intrinsic(data: dict[str, Any], name: str, width: int, height: int) -> Intrinsics:
    """Intrinsics from an Open3D ``PinholeCameraIntrinsic`` JSON document (column-major matrix).

    A file written for another image size is scaled to ``width`` x ``height``.
    """
    matrix = data.get("intrinsic_matrix")
    if (
        not isinstance(matrix, list)
        or len(matrix) != 9
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in matrix)
    ):
        raise ClipError(
            f"{FORMAT}: {name} needs 'intrinsic_matrix': the 3x3 camera matrix as 9 numbers, column-major "
            "[fx, 0, 0, 0, fy, 0, cx, cy, 1]"
        )
    fx, fy, cx, cy = float(matrix[0]), float(matrix[4]), float(matrix[6]), float(matrix[7])
    if matrix[1] != 0 or matrix[2] != 0 or matrix[5] != 0 or matrix[8] != 1:
        raise ClipError(
            f"{FORMAT}: {name} intrinsic_matrix {matrix} is not a pinhole matrix in column-major order "
            "[fx, 0, 0, 0, fy, 0, cx, cy, 1] (a row-major matrix has cx, cy in places 2 and 5)"
        )
    file_w, file_h = _number(data, "width", name), _number(data, "height", name)
    if file_w and file_h and (int(file_w), int(file_h)) != (width, height):
        sx, sy = width / file_w, height / file_h
        fx, cx, fy, cy = fx * sx, (cx + 0.5) * sx - 0.5, fy * sy, (cy + 0.5) * sy - 0.5
    if not (fx > 0 and fy > 0):
        raise ClipError(f"{FORMAT}: {name} focal lengths fx={fx}, fy={fy} must be positive")
    return Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy)


def _dataset_frames(rel: dict[str, str]) -> tuple[list[str], list[str]]:
    """The ``color/`` and ``depth/`` frame files (depth empty without ``depth/``), each in natural name
    order; ``rel`` keys archive names by their name relative to the dataset's root."""
    color = sorted(
        (n for r, n in rel.items() if r.startswith("color/") and r.lower().endswith(COLOR_EXTS)),
        key=natural_key,
    )
    depth = sorted(
        (n for r, n in rel.items() if r.startswith("depth/") and r.lower().endswith(".png")),
        key=natural_key,
    )
    if not color:
        raise ClipError(f"{FORMAT}: no colour frames under color/ (color/*.jpg or color/*.png)")
    if depth and len(depth) != len(color):
        raise ClipError(
            f"{FORMAT}: {len(color)} colour frames but {len(depth)} depth frames; color/ and depth/ must "
            "hold one frame each per time step (or remove depth/)"
        )
    return color, depth


def _first_frames_size(
    archive: Archive, color: list[str], depth: list[str], limits: ReadLimits
) -> tuple[int, int]:
    """The frame size (width, height) from the first colour frame's header, once the first depth frame
    (if any) is a 16-bit single-channel PNG of that size."""
    head = image_header(archive.read(color[0], head=_HEADER_BYTES), f"{FORMAT}: {color[0]}")
    width, height = head.width, head.height
    check_size(FORMAT, width, height, limits)
    if depth:
        dh = image_header(archive.read(depth[0], head=_HEADER_BYTES), f"{FORMAT}: {depth[0]}")
        if dh.kind != "png" or dh.bit_depth != 16 or dh.channels != 1:
            raise ClipError(
                f"{FORMAT}: depth frame {depth[0]!r} must be a 16-bit single-channel PNG "
                f"(got {dh.kind}, {dh.bit_depth}-bit, {dh.channels} channel(s))"
            )
        if (dh.width, dh.height) != (width, height):
            raise ClipError(
                f"{FORMAT}: depth frames are {dh.width}x{dh.height} but colour frames are "
                f"{width}x{height}; Open3D datasets hold depth aligned to colour, same size"
            )
    return width, height


def _read_metadata(
    archive: Archive, rel: dict[str, str], width: int, height: int
) -> tuple[Intrinsics | None, dict[str, Any], list[str]]:
    """The dataset's intrinsics file and ``config.json``, where present.

    Parameters
    ----------
    archive : Archive
    rel : dict
        Archive names keyed by their name relative to the dataset's root.
    width, height : int
        Frame size, pixels (an intrinsics file for another size is scaled to it).

    Returns
    -------
    (intrinsics, config, files)
        Intrinsics from the first of :data:`INTRINSIC_FILES` present (else None), the ``config.json``
        object (else empty) and the names of the files read, in that order.
    """
    files: list[str] = []
    intrinsics: Intrinsics | None = None
    for name in INTRINSIC_FILES:
        if name in rel:
            intrinsics = read_intrinsic(read_json_object(archive, rel[name], FORMAT), name, width, height)
            files.append(name)
            break
    config: dict[str, Any] = {}
    if "config.json" in rel:
        config = read_json_object(archive, rel["config.json"], FORMAT)
        files.append("config.json")
    return intrinsics, config, files


def _config_values(
    config: dict[str, Any], overrides: ClipOverrides, notes: list[str]
) -> tuple[float | None, float]:
    """The frame rate ``config.json`` declares (None if it declares none) and the depth scale in metres
    per unit (the user's, else from ``config.json``'s units per metre, else Open3D's millimetres).

    A ``depth_scale`` of at most 1 is read as metres per unit, noted in ``notes``.
    """
    file_fps = _number(config, "fps", "config.json")
    if file_fps is not None and file_fps <= 0:
        raise ClipError(f"{FORMAT}: config.json fps={file_fps} must be positive; fix it or pass --fps")
    units = _number(config, "depth_scale", "config.json")
    if units is not None and units <= 0:
        raise ClipError(f"{FORMAT}: config.json depth_scale={units} must be positive (depth units per metre)")
    if overrides.depth_scale is not None:
        scale = overrides.depth_scale
    elif units is None:
        scale = 1.0 / DEFAULT_UNITS_PER_METRE
    elif units <= 1.0:
        scale = units
        notes.append(
            f"config.json depth_scale={units:g} read as metres per unit (Open3D uses units per metre)"
        )
    else:
        scale = 1.0 / units
    return file_fps, scale


class Open3dClip(FramesClip):
    """Reader of Open3D RGB-D datasets; see the module docstring."""

    def __init__(
        self,
        path: str | Path,
        *,
        overrides: ClipOverrides | None = None,
        limits: ReadLimits | None = None,
    ) -> None:
        super().__init__(
            path, overrides=overrides, limits=limits, archive=Archive(path, FORMAT, limits or ReadLimits())
        )

    def _setup(self, overrides: ClipOverrides, limits: ReadLimits) -> None:
        names = visible(self._archive.names)
        root = common_root(names)
        rel = {n[len(root) :]: n for n in names if n.startswith(root)}
        self._fmt = self._archive.fmt = FORMAT
        color, depth = _dataset_frames(rel)
        check_frames(FORMAT, len(color), limits)
        width, height = _first_frames_size(self._archive, color, depth, limits)
        notes: list[str] = []
        intrinsics, config, metadata_files = _read_metadata(self._archive, rel, width, height)
        streams = ["color/"] + (["depth/"] if depth else []) + metadata_files
        file_fps, scale = _config_values(config, overrides, notes)
        timing = resolve_timing(
            FORMAT, user_fps=overrides.fps, declared_fps=file_fps, declared_source="bundle", timestamps_s=None
        )
        self._rgb_files = color
        self._depth_files = depth or None
        self._max_frame_bytes = width * height * 8 + (1 << 20)
        self._depth_scale = scale
        self._info = ClipInfo(
            format=FORMAT,
            frames=len(color),
            width=width,
            height=height,
            fps=timing.fps,
            fps_source=timing.fps_source,
            has_depth=bool(depth),
            depth_scale=scale if depth else None,
            intrinsics=overrides.intrinsics_over(intrinsics, width, height),
            timestamps_s=None,
            dropped_frames=0,
            streams=tuple(streams),
            measured_fps=None,
            container_fps=file_fps,
            size_bytes=_size_of(self.path),
            depth_source=(root + "depth/") if depth else None,
            notes=tuple(notes) + timing.notes,
        )
