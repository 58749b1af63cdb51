"""ROS 1 and ROS 2 bags, read without ROS through ``rosbags``.

Supported
    * ROS 1 ``.bag`` (v2.0), as written by ``rosbag record`` (for example realsense-ros:
      ``/camera/color/image_raw``, ``/camera/aligned_depth_to_color/image_raw``, ``.../camera_info``) and by
      the Intel RealSense Viewer / SDK (``/device_0/sensor_*/Color_0/image/data``,
      ``.../Depth_0/image/data``, ``.../info/camera_info``, depth units in
      ``/device_0/sensor_*/option/Depth_Units/value``, stream extrinsics in ``.../tf/0``).
    * ROS 2 bags: a single ``.mcap`` or ``.db3`` file, a bag folder (``metadata.yaml`` + storage files),
      or a zip of a bag folder (unpacked to a scratch folder, size-capped, removed on close).
    * ``sensor_msgs/Image`` (rgb8, bgr8, rgba8, bgra8, mono8, yuv422/uyvy, yuyv, bayer_*, 16UC1, mono16,
      32FC1) and ``sensor_msgs/CompressedImage`` (jpeg/png; ``compressedDepth`` png).

Topics
    Chosen automatically: the colour topic (name says color/rgb; raw before compressed; most messages),
    the depth topic (``aligned_depth_to_color`` first, then any depth topic) and the ``CameraInfo`` topic
    that shares the longest namespace with each. ``ClipOverrides.color_topic`` / ``depth_topic`` pick them
    by name (``depth_topic="none"`` ignores depth).

Time and alignment
    Frames are ordered by their header stamps (the bag's receive time when a stamp is zero). Each colour
    frame is paired with the depth frame nearest in time; colour frames with no depth frame within 0.75 of
    a frame period are dropped (counted in ``ClipInfo.notes``). Depth that is not already aligned to colour
    (a different size or camera matrix) is reprojected into the colour camera with both cameras' intrinsics
    and, for RealSense SDK bags, the recorded extrinsics; without extrinsics the baseline is ignored (noted).
"""

from __future__ import annotations

import contextlib
import os
import struct
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio._archive import Archive, common_root, rmtree_quiet, visible
from workers.pipeline.clipio._common import (
    align_depth_to_color,
    associate_nearest,
    check_decoded,
    check_frames,
    check_image,
    check_size,
    decode_color,
    decode_depth_png,
    image_header,
    pairing_tolerance,
    resolve_timing,
)
from workers.pipeline.clipio.ros_images import (
    COLOR_ENCODINGS,
    DEPTH_ENCODINGS,
    check_raw_size,
    image_to_depth,
    image_to_rgb,
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
from workers.pipeline.errors import ClipError, ClipTooLargeError

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
DEFAULT_DEPTH_SCALE = 0.001
#: Most colour frames held while waiting for their depth partner.
_MAX_PENDING = 512


@dataclass
class _Topic:
    name: str
    msgtype: str
    count: int
    conns: list[Any]
    role: str = "other"  # color, depth, infrared, other
    encoding: str = ""
    width: int = 0
    height: int = 0


@dataclass
class _Timeline:
    """The clip's colour frames in time order, and the depth frame paired with each.

    Attributes
    ----------
    c_order : ndarray of int
        Bag-order index (among the colour messages) of each frame.
    c_t : ndarray of float64
        Each frame's time, seconds from the first.
    d_order : ndarray of int, optional
        Bag-order index (among the depth messages) of each depth message in time order; None without depth.
    d_pos : ndarray of int, optional
        Time-order position of each frame's depth message; None without depth.
    """

    c_order: NDArray[np.int64]
    c_t: NDArray[np.float64]
    d_order: NDArray[np.int64] | None = None
    d_pos: NDArray[np.int64] | None = None


class _Source:
    """Uniform access to a ROS 1 or ROS 2 bag: connections, raw messages, deserialisation, stamps."""

    def __init__(self, path: Path, fmt: str, limits: ReadLimits, scratch_dir: str | Path | None) -> None:
        self.fmt = fmt
        self.path = path
        self._scratch: Path | None = None
        self._reader: Any = None
        try:
            if fmt == "ros1-bag":
                self._open_ros1(path)
            else:
                self._open_ros2(path, limits, scratch_dir)
        except Exception:
            self.close()
            raise

    def _open_ros1(self, path: Path) -> None:
        from rosbags.rosbag1 import Reader, ReaderError
        from rosbags.typesys import Stores, get_typestore

        self.cdr = False
        self.typestore = get_typestore(Stores.ROS1_NOETIC)
        reader = Reader(path)
        try:
            reader.open()
        except (ReaderError, Exception) as exc:  # rosbags raises many types (asserts too) on a corrupt bag
            raise ClipError(
                f"ros1-bag: {path.name} cannot be read ({_short(exc)}); it is truncated, corrupt or not "
                "indexed -- run `rosbag reindex` on it or re-record"
            ) from exc
        self._reader = reader
        self.connections = list(reader.connections)

    def _open_ros2(self, path: Path, limits: ReadLimits, scratch_dir: str | Path | None) -> None:
        from rosbags.rosbag2 import Reader
        from rosbags.typesys import Stores, get_typestore

        self.cdr = True
        self.typestore = get_typestore(Stores.ROS2_HUMBLE)
        target = path
        head = b""
        if path.is_file():
            with path.open("rb") as fh:
                head = fh.read(16)
        if path.is_file() and head.startswith(b"PK"):
            target = self._unzip(path, limits, scratch_dir)
        elif path.is_file():
            suffix = ".mcap" if head.startswith(b"\x89MCAP") else ".db3"
            if path.suffix != suffix:  # rosbags picks the storage plugin by suffix
                self._scratch = Path(tempfile.mkdtemp(prefix="eigenscope-bag-", dir=scratch_dir))
                target = self._scratch / f"bag{suffix}"
                os.symlink(path.resolve(), target)
        try:
            reader = Reader(target)
            reader.open()
        except Exception as exc:  # rosbags raises many types on corrupt storage (sqlite, struct, yaml)
            raise ClipError(
                f"ros2-bag: {path.name} cannot be read ({_short(exc)}); it is truncated or corrupt -- "
                "re-record or re-export the bag"
            ) from exc
        self._reader = reader
        self.connections = list(reader.connections)

    def _unzip(self, path: Path, limits: ReadLimits, scratch_dir: str | Path | None) -> Path:
        archive = Archive(path, "ros2-bag", limits)
        try:
            names = visible(archive.names)
            root = common_root(names)
            storage = [n for n in names if n.endswith((".mcap", ".db3", ".mcap.zstd", ".db3.zstd"))]
            if not storage:
                raise ClipError("ros2-bag: the zip holds no .mcap or .db3 storage file")
            self._scratch = Path(tempfile.mkdtemp(prefix="eigenscope-bag-", dir=scratch_dir))
            meta = root + "metadata.yaml"
            if meta in names:
                folder = [n for n in names if n.startswith(root) and "/" not in n[len(root) :]]
                archive.extract(folder, self._scratch)
                return self._scratch / root if root else self._scratch
            if len(storage) != 1:
                raise ClipError(
                    f"ros2-bag: the zip holds {len(storage)} storage files but no metadata.yaml; zip the "
                    "whole bag folder"
                )
            archive.extract(storage, self._scratch)
            return self._scratch / storage[0]
        finally:
            archive.close()

    def messages(self, conns: list[Any]) -> Iterator[tuple[Any, int, bytes]]:
        try:
            yield from self._reader.messages(connections=conns)
        except ClipError:
            raise
        except Exception as exc:
            raise ClipError(
                f"{self.fmt}: reading messages failed ({_short(exc)}); the bag is truncated or corrupt"
            ) from exc

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        try:
            if self.cdr:
                return self.typestore.deserialize_cdr(raw, msgtype)
            return self.typestore.deserialize_ros1(raw, msgtype)
        except Exception as exc:
            raise ClipError(f"{self.fmt}: a {msgtype} message is corrupt ({_short(exc)})") from exc

    def stamp_ns(self, raw: bytes) -> int:
        """Header stamp of an Image/CompressedImage from its raw bytes (0 if unreadable)."""
        try:
            if self.cdr:
                endian = "<" if raw[1] == 1 else ">"
                sec, nsec = struct.unpack_from(endian + "iI", raw, 4)
            else:
                _, sec, nsec = struct.unpack_from("<III", raw, 0)
        except (struct.error, IndexError):
            return 0
        return int(sec) * 1_000_000_000 + int(nsec)

    def close(self) -> None:
        if self._reader is not None:
            with contextlib.suppress(Exception):  # a half-open reader must not mask the real error
                self._reader.close()
            self._reader = None
        if self._scratch is not None:
            rmtree_quiet(self._scratch)
            self._scratch = None


def _short(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0][:200]


def _common_prefix_len(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a.strip("/").split("/"), b.strip("/").split("/"), strict=False):
        if x != y:
            break
        n += 1
    return n


class BagClip(ClosingReader):
    """Reader of ROS 1 (``ros1-bag``) and ROS 2 (``ros2-bag``) bags; see the module docstring."""

    def __init__(
        self,
        path: str | Path,
        *,
        fmt: str,
        overrides: ClipOverrides | None = None,
        limits: ReadLimits | None = None,
        scratch_dir: str | Path | None = None,
    ) -> None:
        self.path = Path(path)
        self._fmt = fmt
        self._overrides = overrides or ClipOverrides()
        self._limits = limits or ReadLimits()
        self._info_names: list[str] = []
        self._src = _Source(self.path, fmt, self._limits, scratch_dir)
        try:
            self._setup()
        except Exception:
            self._src.close()
            raise

    # ------------------------------------------------------------------------------------------- probe

    def _topics(self) -> dict[str, _Topic]:
        topics: dict[str, _Topic] = {}
        for c in self._src.connections:
            if not isinstance(c.topic, str) or not isinstance(c.msgtype, str):
                raise ClipError(
                    f"{self._fmt}: a connection has no topic name or message type; the bag is corrupt"
                )
            t = topics.setdefault(c.topic, _Topic(c.topic, c.msgtype, 0, []))
            t.conns.append(c)
            t.count += int(getattr(c, "msgcount", 0) or 0)
        return topics

    def _peek(self, topic: _Topic) -> Any:
        for _, _, raw in self._src.messages(topic.conns):
            return self._src.deserialize(raw, topic.msgtype)
        return None

    def _classify(self, topic: _Topic) -> None:
        msg = self._peek(topic)
        if msg is None:
            return
        lname = topic.name.lower()
        infra = any(k in lname for k in ("infra", "/ir", "ir_", "infrared"))
        if topic.msgtype == IMAGE:
            enc = str(msg.encoding).lower()
            topic.encoding, topic.width, topic.height = enc, int(msg.width), int(msg.height)
            if enc in DEPTH_ENCODINGS and not (infra and enc == "mono16"):
                topic.role = "depth"
            elif enc in COLOR_ENCODINGS or enc.startswith("bayer"):
                topic.role = "infrared" if infra else "color"
        else:
            fmt = str(msg.format).lower()
            topic.encoding = fmt
            data = bytes(msg.data[:65536])
            if "compresseddepth" in fmt:
                data = data[12:]
                topic.role = "depth"
            try:
                head = image_header(data, f"{self._fmt}: {topic.name}")
            except ClipError:
                return
            topic.width, topic.height = head.width, head.height
            if topic.role != "depth":
                if head.kind == "png" and head.bit_depth == 16 and head.channels == 1:
                    topic.role = "depth"
                else:
                    topic.role = "infrared" if infra else "color"
        if topic.role == "color" and "depth" in lname:
            topic.role = "other"

    def _setup(self) -> None:
        fmt, ov = self._fmt, self._overrides
        topics = self._topics()
        images = self._image_topics(topics)
        color, depth = self._choose_topics(images, topics)
        infos = [t for t in topics.values() if t.msgtype == CAMERA_INFO]
        notes: list[str] = []
        layout = "realsense-sdk" if color.name.startswith("/device_") else "ros"
        notes.append(f"layout: {layout}")
        c_stamps, d_stamps = self._read_stamps(color, depth)
        timeline = self._timeline(color, depth, c_stamps, d_stamps, notes)
        c_order = timeline.c_order
        check_frames(fmt, len(c_order), self._limits)
        check_size(fmt, color.width, color.height, self._limits)
        check_decoded(fmt, len(c_order), color.width, color.height, depth is not None, self._limits)
        if depth is not None:
            check_size(fmt, depth.width, depth.height, self._limits)

        color_k = self._camera_info(infos, color)
        depth_k = self._camera_info(infos, depth) if depth is not None else None
        self._align: tuple[Any, ...] | None = None
        depth_scale: float | None = None
        if depth is not None:
            self._align = self._alignment(topics, (color, color_k), (depth, depth_k), notes)
            depth_scale = self._depth_scale_of(topics, depth)
        intr = ov.intrinsics_over(
            Intrinsics(*color_k) if color_k is not None else None, color.width, color.height
        )
        timing = resolve_timing(
            fmt, user_fps=ov.fps, declared_fps=None, declared_source="container", timestamps_s=timeline.c_t
        )
        self._color, self._depth = color, depth
        self._c_frame_of: dict[int, int] = {int(k): i for i, k in enumerate(c_order)}
        self._d_sorted_of: dict[int, int] = {}
        if depth is not None and timeline.d_order is not None and timeline.d_pos is not None:
            self._d_sorted_of = {int(k): i for i, k in enumerate(timeline.d_order)}
            self._d_pos = timeline.d_pos
        self._depth_scale = depth_scale or DEFAULT_DEPTH_SCALE
        #: Each frame's raw stamp (ns, the bag's clock): topics read beside the frames use it (force_topics).
        self._frame_stamps_ns = int(min(c_stamps)) + np.rint(timeline.c_t * 1e9).astype(np.int64)
        streams = [color.name, *([depth.name] if depth else [])]
        streams += self._info_names
        self._info = ClipInfo(
            format=fmt,
            frames=len(c_order),
            width=color.width,
            height=color.height,
            fps=timing.fps,
            fps_source=timing.fps_source,
            has_depth=depth is not None,
            depth_scale=depth_scale,
            intrinsics=intr,
            timestamps_s=timing.timestamps_s,
            dropped_frames=timing.dropped_frames,
            streams=tuple(streams),
            measured_fps=timing.measured_fps,
            container_fps=None,
            size_bytes=_size_of(self.path),
            depth_source=depth.name if depth else None,
            notes=tuple(notes) + timing.notes,
        )

    def _image_topics(self, topics: dict[str, _Topic]) -> list[_Topic]:
        """The bag's image topics, each classified (colour, depth, infrared or other) from its first
        message; a bag with no messages or no image topic is a :class:`ClipError`."""
        fmt = self._fmt
        if sum(t.count for t in topics.values()) == 0:
            raise ClipError(f"{fmt}: {self.path.name} holds no messages; record the camera topics into it")
        images = [t for t in topics.values() if t.msgtype in (IMAGE, COMPRESSED)]
        if not images:
            listing = ", ".join(f"{t.name} [{t.msgtype.rsplit('/', 1)[-1]}]" for t in topics.values())
            raise ClipError(
                f"{fmt}: no sensor_msgs/Image or CompressedImage topic in the bag (topics: {listing[:300]}); "
                "record the camera's image topics"
            )
        for t in images:
            self._classify(t)
        return images

    def _choose_topics(self, images: list[_Topic], topics: dict[str, _Topic]) -> tuple[_Topic, _Topic | None]:
        """The colour topic and the depth topic (None without one, or with ``depth_topic="none"``)."""
        ov = self._overrides
        color = self._pick(images, ov.color_topic, "color", topics)
        depth: _Topic | None
        if ov.depth_topic is not None and ov.depth_topic.lower() == "none":
            depth = None
        else:
            depth = self._pick(images, ov.depth_topic, "depth", topics, required=False)
        assert color is not None
        return color, depth

    def _read_stamps(self, color: _Topic, depth: _Topic | None) -> tuple[list[int], list[int]]:
        """Header stamps (the receive time where a stamp is zero) of the colour and depth messages, in
        bag order, read in one pass over the two topics."""
        conns = color.conns + (depth.conns if depth else [])
        depth_ids = {id(c) for c in depth.conns} if depth else set()
        c_stamps: list[int] = []
        d_stamps: list[int] = []
        for conn, logtime, raw in self._src.messages(conns):
            stamp = self._src.stamp_ns(raw) or logtime
            (d_stamps if id(conn) in depth_ids else c_stamps).append(stamp)
            if len(c_stamps) > self._limits.max_frames:
                check_frames(self._fmt, len(c_stamps), self._limits)
        return c_stamps, d_stamps

    def _timeline(
        self,
        color: _Topic,
        depth: _Topic | None,
        c_stamps: list[int],
        d_stamps: list[int],
        notes: list[str],
    ) -> _Timeline:
        """Order the colour frames by stamp (dropping repeated stamps) and pair each with the nearest
        depth frame (dropping colour frames with none close enough); what is dropped is noted.

        Parameters
        ----------
        color, depth : _Topic
            The chosen topics (``depth`` None without depth).
        c_stamps, d_stamps : list of int
            Their messages' stamps in bag order, nanoseconds.
        notes : list of str
            Appended to.

        Returns
        -------
        _Timeline
        """
        fmt = self._fmt
        cs = np.asarray(c_stamps, dtype=np.int64)
        c_order = np.argsort(cs, kind="stable")
        cs_sorted = cs[c_order]
        keep = np.ones(len(cs_sorted), bool)
        keep[1:] = np.diff(cs_sorted) > 0
        if not keep.all():
            notes.append(f"{int((~keep).sum())} colour messages repeat an earlier stamp and were skipped")
        c_order, cs_sorted = c_order[keep], cs_sorted[keep]
        t0 = int(cs_sorted[0]) if len(cs_sorted) else 0
        c_t = (cs_sorted - t0).astype(np.float64) * 1e-9
        if depth is None:
            return _Timeline(c_order, c_t)
        if not d_stamps:
            raise ClipError(f"{fmt}: depth topic {depth.name} holds no messages; pick another or none")
        ds = np.asarray(d_stamps, dtype=np.int64)
        d_order = np.argsort(ds, kind="stable")
        d_t = (ds[d_order] - t0).astype(np.float64) * 1e-9
        tol = pairing_tolerance(c_t, d_t)
        idx, ok = associate_nearest(c_t, d_t, tol)
        if not ok.all():
            notes.append(
                f"{int((~ok).sum())} colour frames had no depth frame within {tol * 1000:.0f} ms and "
                "were dropped"
            )
        c_order, c_t, d_pos = c_order[ok], c_t[ok], idx[ok]
        if len(c_t) == 0:
            raise ClipError(
                f"{fmt}: colour ({color.name}) and depth ({depth.name}) frames never overlap in time; "
                "pick matching topics or depth_topic=none"
            )
        return _Timeline(c_order, c_t, d_order, d_pos)

    def _alignment(
        self,
        topics: dict[str, _Topic],
        color: tuple[_Topic, tuple[float, float, float, float] | None],
        depth: tuple[_Topic, tuple[float, float, float, float] | None],
        notes: list[str],
    ) -> tuple[Any, ...] | None:
        """How depth maps are reprojected onto colour: None when the depth topic is already aligned,
        else ``(depth_k, color_k, rotation, translation)`` (what is done is noted).

        Parameters
        ----------
        topics : dict
            Every topic of the bag (for the RealSense SDK extrinsics).
        color, depth : (topic, intrinsics or None)
            The chosen topics with their ``CameraInfo`` intrinsics (fx, fy, cx, cy).
        notes : list of str
            Appended to.
        """
        (color_t, color_k), (depth_t, depth_k) = color, depth
        same_size = (depth_t.width, depth_t.height) == (color_t.width, color_t.height)
        same_k = depth_k is None or color_k is None or np.allclose(depth_k, color_k, rtol=0.01)
        if "aligned" in depth_t.name.lower() or (same_size and same_k):
            notes.append(f"depth topic {depth_t.name} is aligned to colour")
            return None
        if depth_k is None or color_k is None:
            raise ClipError(
                f"{self._fmt}: depth ({depth_t.width}x{depth_t.height}) is not aligned to colour "
                f"({color_t.width}x{color_t.height}) and a CameraInfo is missing to reproject it; record "
                "aligned depth (align_depth:=true) or the camera_info topics"
            )
        rot, trans = self._extrinsics(topics, color_t, depth_t)
        if rot is None:
            notes.append("depth reprojected onto colour with intrinsics only (no extrinsics in the bag)")
        else:
            notes.append("depth reprojected onto colour with the recorded extrinsics")
        return (depth_k, color_k, rot, trans)

    def _depth_scale_of(self, topics: dict[str, _Topic], depth: _Topic) -> float:
        """Metres per depth unit: 1 for float depth, else the user's, else the bag's (or the default)."""
        if depth.encoding == "32fc1":
            return 1.0
        if self._overrides.depth_scale is not None:
            return self._overrides.depth_scale
        return self._depth_units(topics, depth)

    def _pick(
        self,
        images: list[_Topic],
        wanted: str | None,
        role: str,
        topics: dict[str, _Topic],
        *,
        required: bool = True,
    ) -> _Topic | None:
        fmt = self._fmt
        if wanted:
            if wanted not in topics:
                listing = ", ".join(t.name for t in images)
                raise ClipError(f"{fmt}: {role} topic {wanted!r} is not in the bag (image topics: {listing})")
            t = topics[wanted]
            if t.msgtype not in (IMAGE, COMPRESSED):
                raise ClipError(f"{fmt}: {role} topic {wanted!r} carries {t.msgtype}, not images")
            if t.width == 0:
                raise ClipError(f"{fmt}: {role} topic {wanted!r} holds no readable image")
            return t
        cands = [t for t in images if t.role == role]
        if not cands:
            if not required:
                return None
            if role == "color":
                infra = [t for t in images if t.role == "infrared"]
                if infra:
                    return infra[0]
            listing = ", ".join(f"{t.name} ({t.encoding or 'empty'})" for t in images)
            raise ClipError(
                f"{fmt}: no {role} image topic found among {listing}; give the topic with --{role}-topic"
            )

        def score(t: _Topic) -> tuple[int, int, int, int]:
            n = t.name.lower()
            named = int(any(k in n for k in ("color", "colour", "rgb"))) if role == "color" else 0
            aligned = int("aligned" in n) if role == "depth" else 0
            return (aligned, named, int(t.msgtype == IMAGE), t.count)

        return max(cands, key=score)

    def _camera_info(self, infos: list[_Topic], image: _Topic) -> tuple[float, float, float, float] | None:
        best: _Topic | None = None
        best_len = 0
        for t in infos:
            n = _common_prefix_len(t.name, image.name)
            if n > best_len:
                best, best_len = t, n
        if best is None:
            return None
        msg = self._peek(best)
        if msg is None:
            return None
        k = getattr(msg, "k", None)
        if k is None:
            k = getattr(msg, "K", None)
        if k is None:
            return None
        k = np.asarray(k, dtype=np.float64).ravel()
        if k.size != 9 or not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
            return None
        w, h = int(msg.width), int(msg.height)
        sx = image.width / w if w else 1.0
        sy = image.height / h if h else 1.0
        if best.name not in self._info_names:
            self._info_names.append(best.name)
        return (float(k[0] * sx), float(k[4] * sy), float(k[2] * sx), float(k[5] * sy))

    def _depth_units(self, topics: dict[str, _Topic], depth: _Topic) -> float:
        """RealSense SDK bags store metres per unit as ``/device_N/sensor_M/option/Depth_Units/value``."""
        cands = [t for t in topics.values() if t.name.endswith("/option/Depth_Units/value")]
        if not cands:
            return DEFAULT_DEPTH_SCALE
        best = max(cands, key=lambda t: _common_prefix_len(t.name, depth.name))
        msg = self._peek(best)
        value = float(getattr(msg, "data", 0.0) or 0.0)
        if not (np.isfinite(value) and value > 0):
            raise ClipError(
                f"{self._fmt}: {best.name} stores depth units {value}, which is not a positive scale; "
                "pass --depth-scale"
            )
        return value

    def _extrinsics(
        self, topics: dict[str, _Topic], color: _Topic, depth: _Topic
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.float64] | None]:
        """Depth-to-colour rotation and translation from RealSense SDK ``<stream>/tf/0`` topics."""

        def pose(image: _Topic) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
            stream = image.name.rsplit("/image/", 1)[0]
            t = topics.get(stream + "/tf/0")
            if t is None:
                return None
            msg = self._peek(t)
            if msg is None:
                return None
            q = msg.rotation
            x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
            rot = np.array(
                [
                    [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
                ]
            )
            tr = msg.translation
            return rot, np.array([float(tr.x), float(tr.y), float(tr.z)])

        pd, pc = pose(depth), pose(color)
        if pd is None or pc is None:
            return None, None
        (rd, td), (rc, tc) = pd, pc
        # Each stream's tf is its pose in the reference stream: p_ref = R p + t.
        return rc.T @ rd, rc.T @ (td - tc)

    # ------------------------------------------------------------------------------------------ decode

    @property
    def info(self) -> ClipInfo:
        return self._info

    def _decode_color(self, raw: bytes) -> NDArray[np.uint8]:
        t = self._color
        msg = self._src.deserialize(raw, t.msgtype)
        what = f"{self._fmt}: {t.name}"
        compressed = t.msgtype == COMPRESSED
        size = (self._info.width, self._info.height)
        if compressed:
            data = bytes(msg.data)
            check_image(image_header(data, what), what, self._limits, size=size)
            rgb = decode_color(data, what)
        else:
            check_raw_size(msg, what, size)
            rgb = image_to_rgb(msg, what)
        if rgb.shape[:2] != (self._info.height, self._info.width):
            raise ClipError(
                f"{what}: a frame is {rgb.shape[1]}x{rgb.shape[0]}, the topic started at "
                f"{self._info.width}x{self._info.height}; the resolution must not change"
            )
        return rgb

    def _decode_depth(self, raw: bytes) -> NDArray[np.float32]:
        t = self._depth
        assert t is not None
        msg = self._src.deserialize(raw, t.msgtype)
        what = f"{self._fmt}: {t.name}"
        arr: NDArray[Any]
        if t.msgtype == COMPRESSED:
            data = bytes(msg.data)
            if "compresseddepth" in str(msg.format).lower():
                data = data[12:]
            check_image(image_header(data, what), what, self._limits, size=(t.width, t.height), depth=True)
            arr = decode_depth_png(data, what)
        else:
            check_raw_size(msg, what, (t.width, t.height))
            arr = image_to_depth(msg, what)
        if arr.shape != (t.height, t.width):
            raise ClipError(
                f"{what}: a depth frame is {arr.shape[1]}x{arr.shape[0]}, expected {t.width}x{t.height}"
            )
        depth = depth_to_metres(arr, self._depth_scale)
        if self._align is not None:
            dk, ck, rot, trans = self._align
            depth = align_depth_to_color(depth, dk, ck, (self._info.height, self._info.width), rot, trans)
        return depth

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``; see :class:`~workers.pipeline.clipio.types.Frame`."""
        info = self._info
        stop = info.frames if stop is None else min(stop, info.frames)
        if not 0 <= start <= stop:
            raise ClipError(
                f"{self._fmt}: frame range [{start}, {stop}) is outside the clip's {info.frames} frames"
            )
        if start == stop:
            return
        ts = info.timestamps_s
        assert ts is not None
        depth = self._depth
        depth_ids = {id(c) for c in depth.conns} if depth else set()
        conns = self._color.conns + (depth.conns if depth else [])
        pending_c: dict[int, bytes] = {}
        pending_d: dict[int, bytes] = {}
        need_d = set(int(x) for x in self._d_pos[start:stop]) if depth else set()
        nxt = start
        c_ord = d_ord = 0
        for conn, _, raw in self._src.messages(conns):
            if id(conn) in depth_ids:
                pos = self._d_sorted_of[d_ord]
                d_ord += 1
                if pos in need_d:
                    pending_d[pos] = raw
            else:
                frame = self._c_frame_of.get(c_ord, -1)
                c_ord += 1
                if start <= frame < stop:
                    pending_c[frame] = raw
                    if len(pending_c) > _MAX_PENDING:
                        raise ClipTooLargeError(
                            f"{self._fmt}: colour and depth messages are too far apart in the bag to pair "
                            "while streaming; re-record or pick depth_topic=none"
                        )
            while nxt < stop and nxt in pending_c:
                dpos = int(self._d_pos[nxt]) if depth else -1
                if depth and dpos not in pending_d:
                    break
                rgb = self._decode_color(pending_c.pop(nxt))
                dm = self._decode_depth(pending_d[dpos]) if depth else None
                yield Frame(index=nxt, rgb=rgb, depth_m=dm, timestamp_s=float(ts[nxt]))
                nxt += 1
                if depth and nxt < stop:
                    floor = int(self._d_pos[nxt])
                    for k in [k for k in pending_d if k < floor]:
                        del pending_d[k]
            if nxt >= stop:
                return
        raise ClipError(
            f"{self._fmt}: the bag ended after frame {nxt} of {stop}; it is truncated or its index is wrong"
        )

    def close(self) -> None:
        self._src.close()


def _size_of(path: Path) -> int:
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())
    return path.stat().st_size
