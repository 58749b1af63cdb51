"""Azure Kinect and Orbbec Femto recordings (format ``k4a-mkv``): a Matroska file with a colour track and a
16-bit depth track, as written by ``k4arecorder`` and the Orbbec K4A wrapper.

Tracks are found by their K4A tags (``K4A_COLOR_TRACK``, ``K4A_DEPTH_TRACK``) or titles (``COLOR``,
``DEPTH``); a 16-bit grey video track (FourCC ``b16g``) not titled ``IR`` also counts as depth. The IR and
IMU tracks are ignored.

- **Colour**: any codec FFmpeg decodes (MJPEG, NV12, YUY2, BGRA in K4A recordings).
- **Depth**: ``b16g`` raw 16-bit grey in millimetres (depth scale 0.001 m/unit unless ``--depth-scale``).
- **Calibration**: the ``calibration.json`` attachment (``K4A_CALIBRATION_FILE``). From it come the colour
  camera's intrinsics for the recorded colour mode and the depth camera's for the depth mode
  (``K4A_DEPTH_MODE``, else guessed from the depth image size), converted as the Azure Kinect SDK does, and
  the depth-to-colour extrinsics. Depth maps are then reprojected into the colour image (pinhole model; the
  lens distortion in the file is not applied). Flags (``--fx`` ...) win over the file's colour intrinsics.
  Without the attachment, depth of the colour frames' size is taken as already aligned; depth of another
  size cannot be aligned and is left out, with a note saying so.

Each colour frame is paired with the depth frame nearest in time; colour frames with no depth frame within
0.75 of a frame period are dropped (counted in the notes), as in the TUM reader. The colour track's
presentation times are the frame timestamps.
"""

from __future__ import annotations

import json
import math
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio._common import (
    align_depth_to_color,
    associate_nearest,
    check_frames,
    check_size,
    frame_window,
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
from workers.pipeline.clipio.video import OpenedVideo, open_video
from workers.pipeline.errors import ClipError

FORMAT = "k4a-mkv"
#: Millimetres, the K4A depth unit.
DEPTH_SCALE = 0.001
#: Largest calibration attachment read.
_MAX_CALIBRATION_BYTES = 1 << 20
_DEPTH_PURPOSE = "CALIBRATION_CameraPurposeDepth"
_COLOR_PURPOSE = "CALIBRATION_CameraPurposePhotoVideo"
#: Depth modes: (binned calibration image size, crop offset, output size), as in the Azure Kinect SDK.
DEPTH_MODES: dict[str, tuple[tuple[int, int], tuple[int, int], tuple[int, int]]] = {
    "NFOV_2X2BINNED": ((512, 512), (96, 90), (320, 288)),
    "NFOV_UNBINNED": ((1024, 1024), (192, 180), (640, 576)),
    "WFOV_2X2BINNED": ((512, 512), (0, 0), (512, 512)),
    "WFOV_UNBINNED": ((1024, 1024), (0, 0), (1024, 1024)),
    "PASSIVE_IR": ((1024, 1024), (0, 0), (1024, 1024)),
}
_GREY16 = frozenset({"gray16be", "gray16le"})


def _av_errors() -> tuple[type[BaseException], ...]:
    import av

    return (av.error.FFmpegError, OSError, ValueError, EOFError)


def _msg(exc: BaseException) -> str:
    return ((str(exc).strip() or type(exc).__name__).splitlines() or [""])[0][:200]


def _tag(stream: Any) -> str:
    try:
        return str(stream.codec_context.codec_tag or "")
    except (AttributeError, ValueError):
        return ""


def _title(stream: Any) -> str:
    meta = stream.metadata or {}
    return str(meta.get("title") or meta.get("TITLE") or "").strip().upper()


def find_tracks(container: Any) -> tuple[Any | None, Any | None]:
    """The colour and depth video streams of an open PyAV container (None where missing).

    Parameters
    ----------
    container : av.container.InputContainer

    Returns
    -------
    (colour, depth) : PyAV video streams or None
    """
    videos = list(container.streams.video)
    color = depth = None
    for stream in videos:
        meta = {str(k).upper() for k in (stream.metadata or {})}
        title = _title(stream)
        if depth is None and ("K4A_DEPTH_TRACK" in meta or title == "DEPTH"):
            depth = stream
        elif color is None and ("K4A_COLOR_TRACK" in meta or title == "COLOR"):
            color = stream
    if depth is None:
        for stream in videos:
            if stream is not color and _tag(stream) == "b16g" and _title(stream) != "IR":
                depth = stream
                break
    if color is None and depth is not None:
        others = [
            s for s in videos if s is not depth and _tag(s) != "b16g" and _title(s) not in ("IR", "DEPTH")
        ]
        color = others[0] if others else None
    return color, depth


def is_k4a_recording(path: str | Path) -> bool:
    """True when the Matroska file at ``path`` holds a K4A depth track (see :func:`find_tracks`)."""
    from workers.pipeline.clipio.video import open_video

    try:
        opened = open_video(path, Path(path).name, demuxers=("matroska",), decoders=None)
    except ClipError:
        return False
    except _av_errors():
        return False
    try:
        return find_tracks(opened.container)[1] is not None
    finally:
        opened.close()


# ------------------------------------------------------------------------------------------ calibration


@dataclass(frozen=True, slots=True)
class K4aCalibration:
    """What ``calibration.json`` gives for one recording's modes.

    Attributes
    ----------
    color : Intrinsics
        Colour camera, pixels of the recorded colour frames.
    depth : Intrinsics
        Depth camera, pixels of the recorded depth frames.
    rotation : ndarray of float64, shape (3, 3)
        Depth-camera to colour-camera rotation.
    translation_m : ndarray of float64, shape (3,)
        Depth-camera to colour-camera translation, metres.
    depth_mode : str
        The depth mode the depth intrinsics were converted for.
    """

    color: Intrinsics
    depth: Intrinsics
    rotation: NDArray[np.float64]
    translation_m: NDArray[np.float64]
    depth_mode: str


def _camera(cameras: list[Any], purpose: str) -> dict[str, Any]:
    for cam in cameras:
        if isinstance(cam, dict) and cam.get("Purpose") == purpose:
            return cam
    raise ClipError(f"{FORMAT}: calibration.json has no camera with Purpose {purpose}")


def _numbers(value: Any, count: int, what: str) -> list[float]:
    if (
        not isinstance(value, list)
        or len(value) < count
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value[:count])
    ):
        raise ClipError(f"{FORMAT}: calibration.json {what} must hold at least {count} numbers")
    out = [float(v) for v in value[:count]]
    if not all(math.isfinite(v) for v in out):
        raise ClipError(f"{FORMAT}: calibration.json {what} holds a non-finite number")
    return out


def _sensor(cam: dict[str, Any], what: str) -> tuple[list[float], float, float]:
    intr = cam.get("Intrinsics")
    if not isinstance(intr, dict):
        raise ClipError(f"{FORMAT}: calibration.json {what} camera has no Intrinsics")
    params = _numbers(intr.get("ModelParameters"), 4, f"{what} ModelParameters")
    width, height = cam.get("SensorWidth"), cam.get("SensorHeight")
    if not (isinstance(width, int | float) and isinstance(height, int | float) and width > 0 and height > 0):
        raise ClipError(f"{FORMAT}: calibration.json {what} camera needs positive SensorWidth/SensorHeight")
    return params, float(width), float(height)


def _color_intrinsics(cam: dict[str, Any], width: int, height: int) -> Intrinsics:
    """Normalised colour intrinsics (4:3 or 16:9 sensor) for a colour mode of ``width`` x ``height``."""
    (cx, cy, fx, fy), sw, sh = _sensor(cam, "colour")
    cx, cy, fx, fy = cx * sw, cy * sh, fx * sw, fy * sh
    if abs(sw * 3 / 4 - sh) > 0.5:  # a 16:9 calibration: pad to the 4:3 image the modes are cut from
        cy += (sw * 3 / 4 - sh) / 2
        sh = sw * 3 / 4
    scale = width / sw
    crop_y = (sh * scale - height) / 2
    return Intrinsics(fx=fx * scale, fy=fy * scale, cx=cx * scale - 0.5, cy=cy * scale - crop_y - 0.5)


def _depth_intrinsics(cam: dict[str, Any], mode: str) -> Intrinsics:
    (cx, cy, fx, fy), _sw, _sh = _sensor(cam, "depth")
    (bw, bh), (ox, oy), _size = DEPTH_MODES[mode]
    return Intrinsics(fx=fx * bw, fy=fy * bh, cx=cx * bw - ox - 0.5, cy=cy * bh - oy - 0.5)


def _pose(cam: dict[str, Any], what: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    rt = cam.get("Rt")
    if not isinstance(rt, dict):
        return np.eye(3), np.zeros(3)
    rot = np.asarray(_numbers(rt.get("Rotation"), 9, f"{what} Rt.Rotation"), np.float64).reshape(3, 3)
    trans = np.asarray(_numbers(rt.get("Translation"), 3, f"{what} Rt.Translation"), np.float64)
    return rot, trans


def depth_mode_for(size: tuple[int, int], tagged: str | None) -> str:
    """The depth mode of a recording: its ``K4A_DEPTH_MODE`` tag, else the one whose image is ``size``."""
    if tagged:
        mode = tagged.strip().upper()
        if mode in DEPTH_MODES:
            if DEPTH_MODES[mode][2] != size:
                raise ClipError(
                    f"{FORMAT}: depth frames are {size[0]}x{size[1]} but K4A_DEPTH_MODE={mode} gives "
                    f"{DEPTH_MODES[mode][2][0]}x{DEPTH_MODES[mode][2][1]}; the recording is inconsistent"
                )
            return mode
    for mode, (_binned, _crop, out) in DEPTH_MODES.items():
        if out == size:
            return mode
    known = ", ".join(f"{m} {o[0]}x{o[1]}" for m, (_b, _c, o) in DEPTH_MODES.items())
    raise ClipError(f"{FORMAT}: depth frames of {size[0]}x{size[1]} match no K4A depth mode ({known})")


def parse_calibration(
    data: bytes, *, color_size: tuple[int, int], depth_size: tuple[int, int], depth_mode: str | None
) -> K4aCalibration:
    """Read a K4A ``calibration.json`` for a recording's colour and depth modes.

    Parameters
    ----------
    data : bytes
        The attachment.
    color_size, depth_size : (width, height)
        Sizes of the recorded colour and depth frames, pixels.
    depth_mode : str or None
        The recording's ``K4A_DEPTH_MODE`` tag, if any.

    Returns
    -------
    K4aCalibration
    """
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise ClipError(f"{FORMAT}: calibration.json is not valid JSON ({exc})") from exc
    info = doc.get("CalibrationInformation") if isinstance(doc, dict) else None
    cameras = info.get("Cameras") if isinstance(info, dict) else None
    if not isinstance(cameras, list):
        raise ClipError(f"{FORMAT}: calibration.json has no CalibrationInformation.Cameras list")
    depth_cam, color_cam = _camera(cameras, _DEPTH_PURPOSE), _camera(cameras, _COLOR_PURPOSE)
    mode = depth_mode_for(depth_size, depth_mode)
    rd, td = _pose(depth_cam, "depth")
    rc, tc = _pose(color_cam, "colour")
    rotation = rc @ rd.T  # each Rt maps the reference (the depth camera) into that camera
    return K4aCalibration(
        color=_color_intrinsics(color_cam, *color_size),
        depth=_depth_intrinsics(depth_cam, mode),
        rotation=rotation,
        translation_m=tc - rotation @ td,
        depth_mode=mode,
    )


def calibration_json(
    *,
    color: tuple[float, float, float, float],
    color_size: tuple[int, int],
    depth: tuple[float, float, float, float],
    depth_mode: str,
    rotation: NDArray[np.float64] | None = None,
    translation_m: NDArray[np.float64] | None = None,
) -> dict[str, Any]:
    """A K4A ``calibration.json`` document that :func:`parse_calibration` reads back as these values.

    Parameters
    ----------
    color, depth : (fx, fy, cx, cy)
        Intrinsics in pixels of the colour frames (of ``color_size`` (width, height), at most 4:3 tall) and
        of the ``depth_mode`` frames.
    rotation, translation_m : optional
        Depth-to-colour extrinsics (identity when None).
    """
    width, height = color_size
    sw, sh = 4096.0, 3072.0
    scale = width / sw
    crop_y = (sh * scale - height) / 2
    fx, fy, cx, cy = color
    color_params = [
        (cx + 0.5) / scale / sw,
        (cy + 0.5 + crop_y) / scale / sh,
        fx / scale / sw,
        fy / scale / sh,
    ]
    (bw, bh), (ox, oy), _size = DEPTH_MODES[depth_mode]
    dfx, dfy, dcx, dcy = depth
    depth_params = [(dcx + 0.5 + ox) / bw, (dcy + 0.5 + oy) / bh, dfx / bw, dfy / bh]
    rot = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    trans = np.zeros(3) if translation_m is None else np.asarray(translation_m, np.float64)

    def camera(params: list[float], purpose: str, location: str, size: tuple[float, float], rt: Any) -> Any:
        return {
            "Intrinsics": {
                "ModelParameterCount": 14,
                "ModelParameters": [*params, *([0.0] * 10)],
                "ModelType": "CALIBRATION_LensDistortionModelBrownConrady",
            },
            "Location": location,
            "Purpose": purpose,
            "MetricRadius": 0,
            "Rt": rt,
            "SensorWidth": size[0],
            "SensorHeight": size[1],
            "Shutter": "CALIBRATION_ShutterTypeUndefined",
        }

    identity = {"Rotation": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "Translation": [0.0, 0.0, 0.0]}
    color_rt = {"Rotation": [float(v) for v in rot.ravel()], "Translation": [float(v) for v in trans]}
    return {
        "CalibrationInformation": {
            "Cameras": [
                camera(depth_params, _DEPTH_PURPOSE, "CALIBRATION_CameraLocationD0", (1024, 1024), identity),
                camera(color_params, _COLOR_PURPOSE, "CALIBRATION_CameraLocationPV0", (sw, sh), color_rt),
            ],
            "InertialSensors": [],
            "Metadata": {"SerialId": "eigenscope-synthetic", "Version": {"Major": 1, "Minor": 2}},
        }
    }


# ----------------------------------------------------------------------------------------------- reader


def _calibration_attachment(container: Any) -> bytes | None:
    for stream in container.streams:
        if getattr(stream, "type", None) != "attachment":
            continue
        meta = {str(k).upper(): str(v) for k, v in (stream.metadata or {}).items()}
        name = str(getattr(stream, "name", "") or meta.get("FILENAME", ""))
        if "K4A_CALIBRATION_FILE" in meta or name.lower() == "calibration.json":
            data = bytes(stream.data or b"")
            if len(data) > _MAX_CALIBRATION_BYTES:
                raise ClipError(f"{FORMAT}: calibration attachment of {len(data)} bytes is too large")
            return data
    return None


def _stamps(pts: list[int], time_base: Any, what: str) -> NDArray[np.float64]:
    if time_base is None or len(pts) == 0:
        raise ClipError(f"{FORMAT}: the {what} track carries no presentation times")
    if len(set(pts)) != len(pts):
        raise ClipError(f"{FORMAT}: the {what} track repeats presentation times; the file is corrupt")
    return np.sort(np.asarray(pts, np.int64)).astype(np.float64) * float(time_base)


def _pair_depth(
    color_t: NDArray[np.float64], depth_pts: list[int], time_base: Any, notes: list[str]
) -> tuple[NDArray[np.intp], list[int]]:
    """Pair each colour frame with the depth frame nearest in time.

    Parameters
    ----------
    color_t : ndarray of float64
        The colour frames' times, sorted, seconds.
    depth_pts : list of int
        The depth track's presentation times, in file order.
    time_base : Fraction
        The depth track's.
    notes : list of str
        Appended to: the colour frames dropped for want of a depth frame close enough.

    Returns
    -------
    (keep, pts)
        Indices of the colour frames kept, and the presentation time of each one's depth frame.
    """
    depth_t = _stamps(depth_pts, time_base, "depth")
    tol = pairing_tolerance(color_t, depth_t)
    idx, ok = associate_nearest(color_t, depth_t, tol)
    if int(ok.sum()) < len(ok):
        notes.append(
            f"{len(ok) - int(ok.sum())} colour frames had no depth frame within {tol * 1000:.0f} ms "
            "and were dropped"
        )
    sorted_depth_pts = sorted(depth_pts)
    return np.nonzero(ok)[0], [sorted_depth_pts[i] for i in idx[ok]]


class K4aClip(ClosingReader):
    """Reader of Azure Kinect / Orbbec ``.mkv`` recordings; see the module docstring."""

    def __init__(
        self, path: str | Path, *, overrides: ClipOverrides | None = None, limits: ReadLimits | None = None
    ) -> None:
        self.path = Path(path)
        self._overrides = overrides or ClipOverrides()
        self._limits = limits or ReadLimits()
        self._calibration: K4aCalibration | None = None
        opened = self._open()
        try:
            self._setup(opened.container)
        finally:
            opened.close()

    def _open(self) -> OpenedVideo:
        """The recording, opened so that it cannot reach outside itself (Matroska only)."""
        try:
            return open_video(self.path, self.path.name, demuxers=("matroska",), decoders=None)
        except _av_errors() as exc:
            raise ClipError(
                f"{FORMAT}: {self.path.name} is not a readable Matroska file ({_msg(exc)})"
            ) from exc

    def _setup(self, container: Any) -> None:
        limits, overrides = self._limits, self._overrides
        color, depth = self._tracks(container)
        width, height = int(color.codec_context.width), int(color.codec_context.height)
        check_size(FORMAT, width, height, limits)
        self._color_index = color.index
        self._color_codec = str(color.codec_context.name)
        notes: list[str] = []
        if depth is not None:
            self._depth_index = depth.index
            self._depth_size = (int(depth.codec_context.width), int(depth.codec_context.height))
        pts = self._demux_pts(container, [color] + ([depth] if depth is not None else []))
        color_t = _stamps(pts[color.index], color.time_base, "colour")
        rate = color.average_rate or color.guessed_rate or color.base_rate
        declared = float(rate) if rate and math.isfinite(float(rate)) else None

        calibration_data = _calibration_attachment(container)
        use_depth = depth is not None
        if depth is not None:
            use_depth = self._calibrate(container, depth, calibration_data, (width, height), notes)
        depth_pts: list[int] = []
        if use_depth and depth is not None:
            keep, depth_pts = _pair_depth(color_t, pts[depth.index], depth.time_base, notes)
        else:
            keep = np.arange(len(color_t))
        sorted_color_pts = sorted(pts[color.index])
        self._color_pts = [sorted_color_pts[i] for i in keep]
        self._depth_pts = depth_pts if use_depth else None
        self._use_depth = use_depth
        count = len(self._color_pts)
        check_frames(FORMAT, count, limits)
        timing = resolve_timing(
            FORMAT,
            user_fps=overrides.fps,
            declared_fps=declared,
            declared_source="container",
            timestamps_s=color_t[keep],
        )
        self._depth_scale = overrides.depth_scale if overrides.depth_scale is not None else DEPTH_SCALE
        base = self._calibration.color if self._calibration is not None else None
        streams, depth_source = self._stream_labels((width, height), depth, calibration_data is not None)
        self._info = ClipInfo(
            format=FORMAT,
            frames=count,
            width=width,
            height=height,
            fps=timing.fps,
            fps_source=timing.fps_source,
            has_depth=use_depth,
            depth_scale=self._depth_scale if use_depth else None,
            intrinsics=overrides.intrinsics_over(base, width, height),
            timestamps_s=timing.timestamps_s,
            dropped_frames=timing.dropped_frames,
            streams=tuple(streams),
            measured_fps=timing.measured_fps,
            container_fps=declared,
            size_bytes=self.path.stat().st_size,
            depth_source=depth_source if use_depth else None,
            notes=tuple(notes) + timing.notes,
        )

    def _tracks(self, container: Any) -> tuple[Any, Any | None]:
        """The colour and depth tracks (see :func:`find_tracks`); a recording without colour, or with a
        track FFmpeg cannot decode, is a :class:`ClipError`."""
        color, depth = find_tracks(container)
        if color is None:
            raise ClipError(
                f"{FORMAT}: {self.path.name} has a depth track but no colour track; record with the colour "
                "camera on (k4arecorder --color-mode)"
            )
        for stream, what in ((color, "colour"), (depth, "depth")):
            if stream is not None and stream.codec_context is None:  # FFmpeg has no decoder for it
                raise ClipError(
                    f"{FORMAT}: {self.path.name}'s {what} track is in a codec FFmpeg cannot decode "
                    f"({_tag(stream) or 'unknown'}); record with k4arecorder's standard formats"
                )
        return color, depth

    def _demux_pts(self, container: Any, streams: list[Any]) -> dict[int, list[int]]:
        """The presentation times of each of ``streams``' packets in file order, by stream index."""
        limits = self._limits
        pts: dict[int, list[int]] = {stream.index: [] for stream in streams}
        try:
            for packet in container.demux(*streams):
                if packet.pts is None:
                    continue
                bucket = pts[packet.stream.index]
                bucket.append(int(packet.pts))
                if len(bucket) > limits.max_frames:
                    check_frames(FORMAT, len(bucket), limits)
        except _av_errors() as exc:
            raise ClipError(f"{FORMAT}: {self.path.name} is corrupt or truncated ({_msg(exc)})") from exc
        return pts

    def _calibrate(
        self,
        container: Any,
        depth: Any,
        calibration_data: bytes | None,
        color_size: tuple[int, int],
        notes: list[str],
    ) -> bool:
        """Read the calibration that aligns depth to colour; returns whether the depth track is used.

        Parameters
        ----------
        container : av.container.InputContainer
        depth : PyAV video stream
            The depth track (its size is ``self._depth_size``).
        calibration_data : bytes or None
            The ``calibration.json`` attachment.
        color_size : (width, height)
            Size of the colour frames.
        notes : list of str
            Appended to: how depth is aligned, or why it is ignored.

        Returns
        -------
        bool
            False when depth of another size than colour cannot be aligned (no calibration).
        """
        dsize = self._depth_size
        depth_mode_tag = (depth.metadata or {}).get("K4A_DEPTH_MODE")
        if depth_mode_tag is None:
            depth_mode_tag = (container.metadata or {}).get("K4A_DEPTH_MODE")
        if calibration_data is not None:
            self._calibration = parse_calibration(
                calibration_data, color_size=color_size, depth_size=dsize, depth_mode=depth_mode_tag
            )
            notes.append(
                f"depth ({self._calibration.depth_mode}, {dsize[0]}x{dsize[1]}) reprojected into the colour "
                "image with calibration.json (pinhole; lens distortion not applied)"
            )
        elif dsize != color_size:
            notes.append(
                f"depth track ignored: its {dsize[0]}x{dsize[1]} frames differ from the "
                f"{color_size[0]}x{color_size[1]} colour frames and the recording has no calibration.json "
                "to align them"
            )
            return False
        return True

    def _stream_labels(
        self, color_size: tuple[int, int], depth: Any | None, has_calibration: bool
    ) -> tuple[list[str], str | None]:
        """What ``ClipInfo.streams`` lists, and the depth track's description (None without one)."""
        streams = [f"COLOR:{self._color_codec} {color_size[0]}x{color_size[1]}"]
        depth_source = None
        if depth is not None:
            dsize = self._depth_size
            depth_source = f"DEPTH track {depth.index} (b16g {dsize[0]}x{dsize[1]}, mm)"
            streams.append(f"DEPTH:{_tag(depth) or depth.codec_context.name} {dsize[0]}x{dsize[1]}")
        if has_calibration:
            streams.append("calibration.json")
        return streams, depth_source

    @property
    def info(self) -> ClipInfo:
        return self._info

    @property
    def calibration(self) -> K4aCalibration | None:
        """The recording's calibration (None without a ``calibration.json`` attachment)."""
        return self._calibration

    def _packets(self, index: int) -> Iterator[Any]:
        """Packets of stream ``index`` with presentation times, in file order (a container of its own)."""
        opened = self._open()
        container = opened.container
        errors = _av_errors()
        try:
            stream = container.streams[index]
            demuxed = container.demux(stream)
            while True:
                try:
                    packet = next(demuxed)
                except StopIteration:
                    return
                except errors as exc:
                    raise ClipError(f"{FORMAT}: reading {self.path.name} failed ({_msg(exc)})") from exc
                if packet.pts is not None:
                    yield packet
        finally:
            opened.close()

    def _depth_maps(self) -> Generator[tuple[int, NDArray[np.uint16]]]:
        """``(pts, depth in millimetres (h, w) uint16)`` of the depth track, in file order."""
        w, h = self._depth_size
        errors = _av_errors()
        for packet in self._packets(self._depth_index):
            try:
                frames = packet.decode()
            except errors as exc:
                raise ClipError(f"{FORMAT}: a depth frame does not decode ({_msg(exc)})") from exc
            for frame in frames:
                if frame.format.name not in _GREY16:
                    raise ClipError(
                        f"{FORMAT}: the depth track decodes as {frame.format.name}; expected 16-bit grey "
                        "(b16g) depth in millimetres"
                    )
                raw = frame.to_ndarray()
                if raw.shape != (h, w):
                    raise ClipError(f"{FORMAT}: a depth frame is {raw.shape[1]}x{raw.shape[0]}, not {w}x{h}")
                yield int(packet.pts), np.ascontiguousarray(raw, dtype=np.uint16)

    def _depth_metres(self, raw: NDArray[np.uint16]) -> NDArray[np.float32]:
        metres = depth_to_metres(raw, self._depth_scale)
        cal = self._calibration
        if cal is None:
            return metres
        d, c = cal.depth, cal.color
        return align_depth_to_color(
            metres,
            (d.fx, d.fy, d.cx, d.cy),
            (c.fx, c.fy, c.cx, c.cy),
            (self._info.height, self._info.width),
            cal.rotation,
            cal.translation_m,
        )

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``; see :class:`~workers.pipeline.clipio.types.Frame`."""
        stop = frame_window(FORMAT, start, stop, self._info.frames)
        if start == stop:
            return
        wanted = {p: i for i, p in enumerate(self._color_pts) if start <= i < stop}
        depth_iter = self._depth_maps() if self._use_depth else None
        try:
            yield from self._stream(start, stop, wanted, depth_iter)
        finally:
            if depth_iter is not None:
                depth_iter.close()

    def _stream(
        self,
        start: int,
        stop: int,
        wanted: dict[int, int],
        depth_iter: Iterator[tuple[int, NDArray[np.uint16]]] | None,
    ) -> Iterator[Frame]:
        info = self._info
        depth_pts = self._depth_pts or []
        # Two colour frames may pair with one depth frame: the last one converted is kept.
        last_depth: tuple[int, NDArray[np.float32]] | None = None
        intra = self._color_codec in ("mjpeg", "rawvideo")
        errors = _av_errors()
        fps = info.fps or 1.0
        done = 0
        for packet in self._packets(self._color_index):
            pts = int(packet.pts)
            index = wanted.get(pts)
            if intra and index is None:
                continue  # an intra-only codec: frames outside the window need no decoding
            try:
                decoded = packet.decode()
            except errors as exc:
                raise ClipError(f"{FORMAT}: colour frame at pts {pts} does not decode ({_msg(exc)})") from exc
            for frame in decoded:
                index = wanted.get(int(frame.pts) if frame.pts is not None else pts)
                if index is None:
                    continue
                rgb = frame.to_ndarray(format="rgb24")
                if rgb.shape[:2] != (info.height, info.width):
                    raise ClipError(
                        f"{FORMAT}: colour frame {index} is {rgb.shape[1]}x{rgb.shape[0]}, not "
                        f"{info.width}x{info.height}"
                    )
                depth = None
                if depth_iter is not None:
                    target = depth_pts[index]
                    while last_depth is None or last_depth[0] != target:
                        found = next(depth_iter, None)
                        if found is None:
                            raise ClipError(
                                f"{FORMAT}: the depth frame at pts {target} is missing; the file is corrupt"
                            )
                        if found[0] == target:
                            last_depth = (target, self._depth_metres(found[1]))
                    depth = last_depth[1]
                ts = info.timestamps_s
                yield Frame(
                    index=index,
                    rgb=np.ascontiguousarray(rgb, dtype=np.uint8),
                    depth_m=depth,
                    timestamp_s=float(ts[index]) if ts is not None else index / fps,
                )
                done += 1
                if done == stop - start:
                    return
        raise ClipError(
            f"{FORMAT}: the colour track ends after {start + done} decodable frames but {info.frames} were "
            "listed; the file is truncated or corrupt"
        )

    def close(self) -> None:
        """Nothing stays open between calls (each stream of frames opens the file itself)."""
