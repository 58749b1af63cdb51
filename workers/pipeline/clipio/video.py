"""Video clips (mp4, avi, mkv, mov, ... anything FFmpeg demuxes) decoded with PyAV, RGB only.

Depth, when there is any, comes from a companion:

* ``open_clip(video, depth=path)`` with ``path`` an ``.npz`` holding ``depth`` (T, H, W) (uint16 depth
  units, ``depth_scale`` optional, default 0.001 m; or float32 metres), or a zip / folder of 16-bit depth
  PNGs (``depth/*.png`` or ``*.png`` at its top level), in natural name order;
* or a single zip holding the video file, ``depth/*.png`` and optionally ``camera.json`` (format
  ``video``, layout ``zip``).

The companion must hold exactly one depth map per video frame, of the video's size.

Probing demuxes the packets (no decoding) to count frames and read their presentation times; the
container's declared rate is ``container_fps``, the presentation times give ``measured_fps`` and the
dropped-frame count, and ``--fps`` rescales the timeline (for high-speed cameras that write 30 fps).
"""

from __future__ import annotations

import dataclasses
import errno
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio._archive import ZIP_ERRORS, Archive, common_root, visible
from workers.pipeline.clipio._common import (
    Timing,
    check_decoded,
    check_frames,
    check_image,
    check_size,
    decode_depth_png,
    image_header,
    natural_key,
    resolve_timing,
)
from workers.pipeline.clipio.frames import camera_depth_scale, camera_intrinsics, read_camera_json
from workers.pipeline.clipio.npz import NpzDepth
from workers.pipeline.clipio.types import (
    ClipInfo,
    ClipOverrides,
    ClosingReader,
    Frame,
    ReadLimits,
    depth_to_metres,
)
from workers.pipeline.errors import ClipError

VIDEO_EXTS = (".mp4", ".m4v", ".avi", ".mkv", ".mov", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts")
DEFAULT_DEPTH_SCALE = 0.001
#: Pixel formats whose first plane is 8-bit luma (a grey image as it is).
_LUMA_FIRST = frozenset(
    {"gray", "yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "yuv411p", "yuv440p"}
    | {"yuvj440p", "nv12", "nv21", "nv16", "nv24"}
)


#: Containers a video clip may come in (FFmpeg's demuxer names; MP4/MOV, Matroska/WebM, AVI, MPEG-TS,
#: MPEG-PS, ASF/WMV, FLV). Each holds its own packets: playlists (``hls``), concatenation (``concat``),
#: manifests (``dash``, ``imf``), image sequences (``image2``) and every other demuxer that opens further
#: files or URLs are not among them.
VIDEO_DEMUXERS = ("mov", "matroska", "avi", "mpegts", "mpeg", "asf", "flv")
#: Video codecs a clip may hold (FFmpeg's canonical codec names).
VIDEO_CODECS = frozenset(
    {"h264", "hevc", "mpeg4", "mjpeg", "ffv1", "vp8", "vp9", "av1", "mpeg1video", "mpeg2video", "h263"}
    | {"msmpeg4v2", "msmpeg4v3", "wmv1", "wmv2", "wmv3", "vc1", "flv1", "theora", "prores", "dnxhd"}
    | {"rawvideo", "png", "huffyuv", "ffvhuff", "utvideo", "qtrle"}
)
#: The decoders of those codecs (FFmpeg's own, and the libraries PyAV's FFmpeg prefers for some).
_VIDEO_DECODERS = (*sorted(VIDEO_CODECS - {"flv1", "msmpeg4v3"}), "flv", "msmpeg4", "libdav1d", "libvpx")
_VIDEO_DECODERS += ("libvpx-vp9",)
#: Text that FFmpeg would read as a list of other files or URLs (a playlist, a manifest, a script).
_REFERRING_HEADS = (
    (b"#EXTM3U", "an HLS playlist (.m3u8)"),
    (b"ffconcat", "an FFmpeg concat list"),
    (b"<?xml", "an XML document (a DASH or IMF manifest, a playlist)"),
    (b"<MPD", "a DASH manifest"),
    (b"[playlist]", "a playlist"),
    (b"v=0", "an SDP session description (it names network streams)"),
)


class _OtherFileError(Exception):
    """The demuxer asked to open a file or URL other than the clip itself."""


def _refuse_other_files(url: str, flags: int, options: dict[str, Any]) -> Any:
    raise _OtherFileError(url)


def referring_kind(head: bytes) -> str | None:
    """What a file that starts with ``head`` is when it is a list of other files or URLs, else None."""
    start = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    for magic, kind in _REFERRING_HEADS:
        if start[: len(magic)].lower() == magic.lower():
            return kind
    return None


def _refused(name: str, kind: str) -> ClipError:
    return ClipError(
        f"video: {name} is {kind}, which names other files or URLs; Eigenscope reads only clips that hold "
        "their own frames: upload the video file itself"
    )


@dataclass
class OpenedVideo:
    """A video opened by :func:`open_video`: the PyAV container and the file it reads."""

    container: Any
    file: IO[bytes]
    owns_file: bool

    def close(self) -> None:
        try:
            self.container.close()
        finally:
            if self.owns_file:
                self.file.close()


def open_video(
    src: str | Path | IO[bytes],
    name: str,
    *,
    demuxers: tuple[str, ...] = VIDEO_DEMUXERS,
    decoders: tuple[str, ...] | None = _VIDEO_DECODERS,
) -> OpenedVideo:
    """Open ``src`` for demuxing so that it cannot reach outside itself.

    FFmpeg reads the one file through a Python file object; the demuxer must be one of ``demuxers``
    (checked before its header is parsed), the decoders FFmpeg opens to probe the streams one of
    ``decoders``, no protocol is enabled, and any attempt to open another file or URL fails. A playlist
    or a container off the list is a :class:`ClipError` that says so (``name`` names the clip in it).
    """
    import av

    owns = isinstance(src, str | Path)
    fh = Path(src).open("rb") if isinstance(src, str | Path) else src  # noqa: SIM115 - closed by OpenedVideo
    try:
        head = fh.read(64)
        fh.seek(0)
        kind = referring_kind(head)
        if kind is not None:
            raise _refused(name, kind)
        options = {"format_whitelist": ",".join(demuxers), "protocol_whitelist": "none"}
        if decoders is not None:
            options["codec_whitelist"] = ",".join(decoders)
        try:
            container = av.open(
                fh, mode="r", metadata_errors="ignore", container_options=options, io_open=_refuse_other_files
            )
        except _OtherFileError as exc:
            raise _refused(name, f"a file that refers to another ({_msg(exc)})") from None
        except av.error.ArgumentError as exc:
            if exc.errno != errno.EINVAL:
                raise
            raise ClipError(
                f"video: {name} is not in a container Eigenscope reads (MP4/MOV, Matroska/WebM, AVI, "
                "MPEG-TS, MPEG-PS, ASF/WMV, FLV); re-encode it into one, or upload the camera's original file"
            ) from exc
    except BaseException:
        if owns:
            fh.close()
        raise
    return OpenedVideo(container, fh, owns)


def check_codec(stream: Any, name: str) -> None:
    """Refuse a video stream whose codec is not one of :data:`VIDEO_CODECS` (before it is decoded)."""
    codec = stream.codec_context.codec.canonical_name if stream.codec_context is not None else None
    if codec not in VIDEO_CODECS:
        raise ClipError(
            f"video: {name} holds a {codec or 'unknown'} video stream, a codec Eigenscope does not decode; "
            "re-encode it (H.264, HEVC, VP9, AV1, MJPEG, FFV1, ...)"
        )


def _av_error_types() -> tuple[type[BaseException], ...]:
    """What decoding a broken video raises: FFmpeg's errors, and those of a zip member it reads."""
    import av

    return (av.error.FFmpegError, _OtherFileError, *ZIP_ERRORS)


@dataclass
class _DepthSource:
    """Depth maps, one per video frame, streamed in metres by ``slices(start, stop)``."""

    label: str
    frames: int
    width: int
    height: int
    scale: float
    slices: Callable[[int, int], Iterator[NDArray[np.float32]]]
    closer: Callable[[], None] | None = None

    def close(self) -> None:
        if self.closer is not None:
            self.closer()
            self.closer = None


def _png_depth_source(
    archive: Archive,
    names: list[str],
    scale: float,
    label: str,
    limits: ReadLimits,
    *,
    owns_archive: bool,
) -> _DepthSource:
    h = image_header(archive.read(names[0], head=4096), f"video depth: {names[0]}")
    if h.kind != "png" or h.bit_depth != 16 or h.channels != 1:
        raise ClipError(
            f"video: depth frame {names[0]!r} must be a 16-bit single-channel PNG "
            f"(got {h.kind}, {h.bit_depth}-bit, {h.channels} channel(s))"
        )
    width, height = h.width, h.height
    check_size("video depth", width, height, limits)
    for name in names[1:]:  # every header before any map is decoded
        what = f"video depth: {name}"
        check_image(
            image_header(archive.read(name, head=4096), what), what, limits, size=(width, height), depth=True
        )
    cap = width * height * 8 + (1 << 20)

    def slices(start: int, stop: int) -> Iterator[NDArray[np.float32]]:
        for name in names[start:stop]:
            what = f"video depth: {name}"
            data = archive.read(name, cap)
            check_image(image_header(data, what), what, limits, size=(width, height), depth=True)
            raw = decode_depth_png(data, what)
            if raw.shape != (height, width):
                raise ClipError(
                    f"video: depth frame {name!r} is {raw.shape[1]}x{raw.shape[0]}; expected {width}x{height}"
                )
            yield depth_to_metres(raw, scale)

    return _DepthSource(
        label, len(names), width, height, scale, slices, archive.close if owns_archive else None
    )


def _open_depth_companion(
    path: Path, overrides: ClipOverrides, limits: ReadLimits
) -> tuple[_DepthSource, dict[str, float]]:
    """Open a ``depth=`` companion: npz with a depth array, or zip/folder of 16-bit PNGs."""
    if not path.exists():
        raise ClipError(f"video: depth companion {path.name} does not exist")
    if path.is_file():
        with path.open("rb") as fh:
            if not fh.read(4).startswith(b"PK"):
                raise ClipError(
                    f"video: depth companion {path.name} is neither an .npz with a 'depth' array nor a "
                    "zip of depth PNGs"
                )
    archive = Archive(path, "video depth", limits)
    try:
        names = visible(archive.names)
        if path.is_file() and any(n.removesuffix(".npy") == "depth" for n in names):
            archive.close()
            npz = NpzDepth(path, overrides=overrides, limits=limits)
            return _DepthSource(
                f"{path.name}:depth",
                npz.frames,
                npz.width,
                npz.height,
                npz.depth_scale,
                npz.slices,
                npz.close,
            ), {}
        root = common_root(names)
        pngs = [n for n in names if n.lower().endswith(".png") and n.startswith(root)]
        sub = [n for n in pngs if n[len(root) :].startswith("depth/")]
        chosen = sorted(sub or [n for n in pngs if "/" not in n[len(root) :]], key=natural_key)
        if not chosen:
            raise ClipError(f"video: depth companion {path.name} holds no depth PNGs (depth/*.png)")
        camera: dict[str, float] = {}
        if root + "camera.json" in names:
            camera = read_camera_json(archive, root + "camera.json", "video depth")
        scale = camera_depth_scale(camera, overrides, DEFAULT_DEPTH_SCALE, "video")
        label = f"{path.name}:{'depth/' if sub else '*.png'}"
        return _png_depth_source(archive, chosen, scale, label, limits, owns_archive=True), camera
    except Exception:
        archive.close()
        raise


@dataclass
class _Probe:
    """What demuxing a video stream's packets (without decoding them) tells.

    Attributes
    ----------
    width, height : int
        Frame size, pixels.
    codec : str
        The stream's codec (FFmpeg's name).
    frames : int
        Packets holding a frame.
    declared_fps : float or None
        The container's rate (average, else guessed, else base).
    capture_fps : float or None
        A slow-motion video's capture rate from its metadata.
    time_base : Fraction or None
    pts : list of int
        The packets' presentation times (those that have one), in ``time_base`` units.
    """

    width: int
    height: int
    codec: str
    frames: int
    declared_fps: float | None
    capture_fps: float | None
    time_base: Fraction | None
    pts: list[int]


def _pts_seconds(pts: list[int], time_base: Fraction | None, count: int) -> NDArray[np.float64] | None:
    """Frame times in seconds from the first, sorted, when each of the ``count`` frames has its own
    presentation time; else None."""
    if time_base is None or len(pts) != count or len(set(pts)) != count:
        return None
    arr = np.sort(np.asarray(pts, dtype=np.int64))
    stamps: NDArray[np.float64] = (arr - arr[0]).astype(np.float64) * float(time_base)
    return stamps


def _video_timing(
    user_fps: float | None,
    capture: float | None,
    declared: float | None,
    stamps: NDArray[np.float64] | None,
) -> tuple[Timing, bool]:
    """The video's timing, and whether the capture rate from its metadata was used.

    A phone's slow motion records its capture rate beside a slower playback rate: the capture rate is
    the physics' clock (the user's ``user_fps`` still wins).
    """
    use_capture = (
        user_fps is None
        and capture is not None
        and declared is not None
        and abs(capture / declared - 1) > 0.05
    )
    timing = resolve_timing(
        "video",
        user_fps=capture if use_capture else user_fps,
        declared_fps=declared,
        declared_source="container",
        timestamps_s=stamps,
    )
    if use_capture:
        timing = dataclasses.replace(timing, fps_source="metadata")
    return timing, use_capture


def _name_rate_notes(hint: float | None, declared: float | None) -> tuple[str, ...]:
    """A note when the file name names a rate that differs from the container's by over 5 %."""
    if hint is not None and declared is not None and abs(hint / declared - 1) > 0.05:
        return (f"the file name says {hint:g} fps: if the clip was filmed at that rate, give --fps {hint:g}",)
    return ()


class VideoClip(ClosingReader):
    """Reader of video files (optionally with companion depth); see the module docstring."""

    def __init__(
        self,
        path: str | Path,
        *,
        overrides: ClipOverrides | None = None,
        limits: ReadLimits | None = None,
        depth: str | Path | None = None,
        archive: Archive | None = None,
    ) -> None:
        self.path = Path(path)
        self._overrides = overrides or ClipOverrides()
        self._limits = limits or ReadLimits()
        self._archive = archive
        self._depth: _DepthSource | None = None
        self._member: str | None = None
        #: Frames that decoded when a read ended early (a damaged file), and why; None until then.
        self.decodable_frames: int | None = None
        self.decode_error: str | None = None
        try:
            self._setup(depth)
        except Exception:
            self.close()
            raise

    def _open_container(self) -> OpenedVideo:
        src: Path | IO[bytes]
        if self._archive is not None:
            assert self._member is not None
            src = self._archive.open(self._member)
        else:
            src = self.path
        name = self._member or self.path.name
        try:
            opened = open_video(src, name)
        except BaseException as exc:
            if not isinstance(src, Path):
                src.close()
            if isinstance(exc, _av_error_types()):
                raise ClipError(
                    f"video: {name} is not a readable video ({_msg(exc)}); upload the camera's original file"
                ) from exc
            raise
        if not isinstance(src, Path):
            opened.owns_file = True  # the zip member's handle closes with the container
        # The decoder refuses a picture over the pixel cap before allocating it (a stream that grows
        # in the middle, past the size its header declared).
        for stream in opened.container.streams.video:
            if stream.codec_context is None:
                continue
            stream.codec_context.options = {
                **stream.codec_context.options,
                "max_pixels": str(self._limits.max_pixels_per_frame),
            }
        return opened

    def _setup(self, depth: str | Path | None) -> None:
        overrides, limits = self._overrides, self._limits
        camera: dict[str, float] = {}
        layout = "file"
        if self._archive is not None:
            camera = self._read_zip_layout(self._archive, depth)
            layout = "zip"
        if depth is not None:
            self._depth, cam2 = _open_depth_companion(Path(depth), overrides, limits)
            camera = {**cam2, **camera}

        probe = self._probe()
        count, width, height = probe.frames, probe.width, probe.height
        check_frames("video", count, limits)
        check_decoded("video", count, width, height, self._depth is not None, limits)
        stamps = _pts_seconds(probe.pts, probe.time_base, count)
        declared = probe.declared_fps
        if declared is not None and not math.isfinite(declared):
            declared = None
        timing, use_capture = _video_timing(overrides.fps, probe.capture_fps, declared, stamps)
        hint = None if use_capture else capture_rate_in_name(self._member or self.path.name)
        self._check_depth_matches(count, width, height)
        self._frames = count
        self._info = ClipInfo(
            format="video",
            frames=count,
            width=width,
            height=height,
            fps=timing.fps,
            fps_source=timing.fps_source,
            has_depth=self._depth is not None,
            depth_scale=self._depth.scale if self._depth is not None else None,
            intrinsics=camera_intrinsics(camera, overrides, width, height, "video"),
            timestamps_s=timing.timestamps_s,
            dropped_frames=timing.dropped_frames,
            streams=(f"video:{probe.codec}", *((self._depth.label,) if self._depth is not None else ())),
            measured_fps=timing.measured_fps,
            container_fps=declared,
            size_bytes=self.path.stat().st_size,
            depth_source=self._depth.label if self._depth is not None else None,
            notes=(f"layout: {layout}", *timing.notes, *_name_rate_notes(hint, declared)),
            capture_fps_hint=hint,
            capture_fps_hint_source="the file name" if hint is not None else None,
        )

    def _read_zip_layout(self, archive: Archive, depth: str | Path | None) -> dict[str, float]:
        """Find the one video file of a zip (it becomes the member read) and its ``depth/*.png`` maps
        (the depth source unless a ``depth`` companion is given); returns ``camera.json``'s values."""
        names = visible(archive.names)
        root = common_root(names)
        videos = [n for n in names if n.lower().endswith(VIDEO_EXTS)]
        if len(videos) != 1:
            raise ClipError(f"video: the zip must hold exactly one video file, found {len(videos)}")
        self._member = videos[0]
        camera: dict[str, float] = {}
        if root + "camera.json" in names:
            camera = read_camera_json(archive, root + "camera.json", "video")
        dpng = sorted(
            (n for n in names if n.startswith(root + "depth/") and n.lower().endswith(".png")),
            key=natural_key,
        )
        if dpng and depth is None:
            scale = camera_depth_scale(camera, self._overrides, DEFAULT_DEPTH_SCALE, "video")
            self._depth = _png_depth_source(
                archive, dpng, scale, root + "depth/", self._limits, owns_archive=False
            )
        return camera

    def _probe(self) -> _Probe:
        """Demux the video stream's packets (no decoding) for its size, codec, rates and frame times."""
        limits = self._limits
        opened = self._open_container()
        container = opened.container
        try:
            if not container.streams.video:
                raise ClipError(f"video: {self._member or self.path.name} has no video stream")
            stream = container.streams.video[0]
            if stream.codec_context is None:
                raise ClipError(f"video: {self._member or self.path.name} has no decodable video stream")
            check_codec(stream, self._member or self.path.name)
            width, height = int(stream.codec_context.width), int(stream.codec_context.height)
            check_size("video", width, height, limits)
            rate = stream.average_rate or stream.guessed_rate or stream.base_rate
            declared = float(rate) if rate else None
            capture = _capture_rate(container.metadata, stream.metadata)
            tb: Fraction | None = stream.time_base
            pts: list[int] = []
            count = 0
            for packet in container.demux(stream):
                if packet.size == 0 and packet.pts is None:
                    continue  # flush packet
                count += 1
                if count > limits.max_frames:
                    check_frames("video", count, limits)
                if packet.pts is not None:
                    pts.append(int(packet.pts))
            codec = stream.codec_context.name
        except _av_error_types() as exc:
            raise ClipError(
                f"video: {self._member or self.path.name} is corrupt or truncated ({_msg(exc)})"
            ) from exc
        finally:
            opened.close()
        return _Probe(width, height, codec, count, declared, capture, tb, pts)

    def _check_depth_matches(self, count: int, width: int, height: int) -> None:
        """The depth source must hold one map of the video's size per video frame."""
        if self._depth is None:
            return
        d = self._depth
        if d.frames != count:
            raise ClipError(
                f"video: {count} video frames but {d.frames} depth maps in {d.label}; the depth "
                "companion must hold one map per video frame"
            )
        if (d.width, d.height) != (width, height):
            raise ClipError(
                f"video: depth maps are {d.width}x{d.height} but the video is {width}x{height}; "
                "depth must be aligned to the video frames"
            )

    @property
    def info(self) -> ClipInfo:
        return self._info

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``; see :class:`~workers.pipeline.clipio.types.Frame`."""
        info = self._info
        stop = info.frames if stop is None else min(stop, info.frames)
        depth_iter = None
        fps = info.fps or 1.0
        for index, frame in self._decode(start, stop):
            if depth_iter is None and self._depth is not None:
                depth_iter = self._depth.slices(start, stop)
            rgb = frame.to_ndarray(format="rgb24")
            if rgb.shape[:2] != (info.height, info.width):
                raise ClipError(
                    f"video: frame {index} is {rgb.shape[1]}x{rgb.shape[0]}, the stream changed size "
                    f"from {info.width}x{info.height}; re-encode at one size"
                )
            depth = next(depth_iter) if depth_iter is not None else None
            ts = info.timestamps_s
            t = float(ts[index]) if ts is not None else index / fps
            yield Frame(
                index=index,
                rgb=np.ascontiguousarray(rgb, dtype=np.uint8),
                depth_m=depth,
                timestamp_s=t,
            )

    def gray_frames(self, start: int = 0, stop: int | None = None) -> Iterator[NDArray[np.uint8]]:
        """Yield the grey (luma) image of frames ``start <= index < stop``, shape (H, W), uint8.

        For a quick look at every frame (see :mod:`workers.pipeline.survey`): the decoder's luma plane is
        copied as it is (no colour conversion), several times faster than :meth:`frames`.
        """
        info = self._info
        stop = info.frames if stop is None else min(stop, info.frames)
        for index, frame in self._decode(start, stop):
            if (frame.width, frame.height) != (info.width, info.height):
                raise ClipError(
                    f"video: frame {index} is {frame.width}x{frame.height}, the stream changed size "
                    f"from {info.width}x{info.height}; re-encode at one size"
                )
            if frame.format.name in _LUMA_FIRST:
                plane = frame.planes[0]
                rows = np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)
                yield np.array(rows[: info.height, : info.width], dtype=np.uint8)
            else:
                yield np.ascontiguousarray(frame.to_ndarray(format="gray"), dtype=np.uint8)

    def _decode(self, start: int, stop: int) -> Iterator[tuple[int, Any]]:
        """Decoded PyAV frames ``start <= index < stop`` with their index (frames before ``start`` are
        decoded and dropped: a video is read from its beginning).

        A damaged file (a truncated tail, a corrupt packet) ends the frames early instead of failing:
        the frames that decode are delivered, and :attr:`decodable_frames` says how many there were.
        """
        info = self._info
        if not 0 <= start <= stop:
            raise ClipError(
                f"video: frame range [{start}, {stop}) is outside the clip's {info.frames} frames"
            )
        if start == stop:
            return
        opened = self._open_container()
        container = opened.container
        errors = _av_error_types()
        index = 0
        try:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            decoded = container.decode(stream)
            while index < stop:
                try:
                    frame = next(decoded)
                except StopIteration:
                    break
                except errors as exc:
                    self.decode_error = f"decoding failed at frame {index} ({_msg(exc)})"
                    break
                if index >= start:
                    yield index, frame
                index += 1
        finally:
            opened.close()
        if index < stop:
            self.decodable_frames = (
                index if self.decodable_frames is None else min(self.decodable_frames, index)
            )
            if index <= start:
                why = self.decode_error or "the stream ends"
                raise ClipError(
                    f"video: no frame from {start} on decodes ({why} after {index} of the {info.frames} "
                    "frames listed); the file is truncated or corrupt"
                )

    def close(self) -> None:
        if self._depth is not None:
            self._depth.close()
            self._depth = None
        if self._archive is not None:
            self._archive.close()


def _capture_rate(*metadata: dict[str, str]) -> float | None:
    """The capture rate a phone writes beside a slow-motion video's playback rate
    (``com.android.capture.fps``), or None."""
    for meta in metadata:
        for key, value in (meta or {}).items():
            if key.lower().endswith("capture.fps"):
                try:
                    rate = float(str(value).strip())
                except ValueError:
                    continue
                if math.isfinite(rate) and 0 < rate <= 100_000:
                    return rate
    return None


_RATE_IN_NAME = re.compile(
    r"(?:^|[^0-9a-z])(?:fps[-_ ]?(\d{2,6})|(\d{2,6})[-_ ]?fps)(?![0-9])", re.IGNORECASE
)


def capture_rate_in_name(name: str) -> float | None:
    """A frame rate named in a file name (``clip_fps1000.mp4``, ``fork-240fps.mov``), or None.

    High-speed cameras write a playback rate into the container; people often write the true one into the
    name. It is only a hint (for a quality note), never used as the rate.
    """
    match = _RATE_IN_NAME.search(Path(name).stem)
    if match is None:
        return None
    rate = float(match.group(1) or match.group(2))
    return rate if 1 <= rate <= 100_000 else None


def _msg(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:200]
