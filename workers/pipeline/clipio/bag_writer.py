"""Write a clip held in memory as a ROS 1 or ROS 2 bag with the ``rosbags`` writers: colour and depth
topics in the realsense-ros or the RealSense SDK layout, camera info, and beside them a wrist force/torque
sensor's ``WrenchStamped`` topics and the ``/tf`` and ``/tf_static`` transforms that place it. Arrays follow
the clip conventions (:mod:`workers.pipeline.clipio.writers`).
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.writers import Intr, bgr_of, jpg_bytes, png_bytes, zip_folder


def _header(typestore: Any, stamp_ns: int, frame_id: str, ros1: bool, seq: int) -> Any:
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    if ros1:
        return Header(seq=seq, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def _image_msg(typestore: Any, header: Any, img: NDArray[Any], encoding: str) -> Any:
    Image = typestore.types["sensor_msgs/msg/Image"]
    h, w = img.shape[:2]
    data = np.ascontiguousarray(img).view(np.uint8).reshape(-1)
    return Image(
        header=header,
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=int(data.size // h),
        data=data,
    )


def _compressed_msg(typestore: Any, header: Any, data: bytes, fmt: str) -> Any:
    CompressedImage = typestore.types["sensor_msgs/msg/CompressedImage"]
    return CompressedImage(header=header, format=fmt, data=np.frombuffer(data, dtype=np.uint8))


def _camera_info_msg(typestore: Any, header: Any, w: int, h: int, k: Intr, ros1: bool) -> Any:
    CameraInfo = typestore.types["sensor_msgs/msg/CameraInfo"]
    RegionOfInterest = typestore.types["sensor_msgs/msg/RegionOfInterest"]
    fx, fy, cx, cy = k
    kmat = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
    rmat = np.eye(3).ravel()
    pmat = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64)
    fields = {
        "header": header,
        "height": h,
        "width": w,
        "distortion_model": "plumb_bob",
        "binning_x": 0,
        "binning_y": 0,
        "roi": RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    }
    if ros1:
        fields.update(D=np.zeros(5), K=kmat, R=rmat, P=pmat)
    else:
        fields.update(d=np.zeros(5), k=kmat, r=rmat, p=pmat)
    return CameraInfo(**fields)


@dataclass(frozen=True)
class RosBagOptions:
    """How :func:`write_ros_bag` lays the bag out (the defaults are a plain realsense-ros recording).

    Attributes
    ----------
    layout : ``"ros"`` or ``"realsense-sdk"``
        ``ros``: realsense-ros topic names (``/camera/color/image_raw``,
        ``/camera/aligned_depth_to_color/image_raw``). ``realsense-sdk``: the RealSense Viewer layout
        (``/device_0/sensor_1/Color_0/image/data`` ...), with depth units in the bag (ROS 1 only).
    storage : ``"mcap"`` or ``"sqlite3"``
        ROS 2 storage plugin.
    compressed : bool
        Colour as ``CompressedImage`` (jpeg) and depth as ``compressedDepth`` png (ROS 2 style topics).
    depth_scale : float
        Metres per depth unit; stored in the bag for the SDK layout.
    extra_topics : bool
        Also write unrelated topics (IMU-like floats, tf) as real recordings have.
    wrenches : tuple of WrenchTopic
        Force/torque topics written beside the frames.
    transforms : tuple of StaticTransform or MovingTransform
        Static ones are written on ``/tf_static`` before the first frame, moving ones on ``/tf`` at their
        stamps (the colour frames' frame is ``camera_color_optical_frame``).
    """

    layout: Literal["ros", "realsense-sdk"] = "ros"
    storage: Literal["mcap", "sqlite3"] = "mcap"
    compressed: bool = False
    depth_scale: float = 0.001
    extra_topics: bool = True
    wrenches: tuple[WrenchTopic, ...] = ()
    transforms: tuple[StaticTransform | MovingTransform, ...] = ()


@dataclass(frozen=True)
class _BagTopics:
    """Topic names of one bag layout, and the image message type and depth encoding they carry."""

    color: str
    color_info: str
    depth: str
    depth_info: str
    depth_encoding: str
    image_type: str


def _bag_topics(layout: str, compressed: bool) -> _BagTopics:
    """The colour, depth and camera-info topics of ``layout`` (``/compressed`` image topics if asked)."""
    if layout == "realsense-sdk":
        c_img, c_info = "/device_0/sensor_1/Color_0/image/data", "/device_0/sensor_1/Color_0/info/camera_info"
        d_img, d_info = "/device_0/sensor_0/Depth_0/image/data", "/device_0/sensor_0/Depth_0/info/camera_info"
        d_enc = "mono16"
    else:
        c_img, c_info = "/camera/color/image_raw", "/camera/color/camera_info"
        d_img = "/camera/aligned_depth_to_color/image_raw"
        d_info = "/camera/aligned_depth_to_color/camera_info"
        d_enc = "16UC1"
    if compressed:
        c_img += "/compressed"
        d_img += "/compressedDepth"
    img_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    return _BagTopics(c_img, c_info, d_img, d_info, d_enc, img_type)


def _open_bag_writer(path: Path, ros1: bool, storage: str) -> Any:
    """A ``rosbags`` writer (not yet opened) of a ROS 1 bag file or a ROS 2 bag folder at ``path``."""
    if ros1:
        from rosbags.rosbag1 import Writer as Ros1Writer

        return Ros1Writer(path)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Ros2Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Ros2Writer(path, version=9, storage_plugin=plugin)


@dataclass
class _BagOut:
    """An open bag and what all its camera messages share: one connection per topic (made on the
    topic's first message), messages serialised for the bag's ROS version."""

    writer: Any
    typestore: Any
    ros1: bool
    topics: _BagTopics
    intrinsics: Intr
    size: tuple[int, int]  # (width, height)
    options: RosBagOptions
    conns: dict[str, Any] = field(default_factory=dict)

    def write(self, topic: str, msgtype: str, stamp: int, msg: Any) -> None:
        """Write ``msg`` of ``msgtype`` on ``topic`` with receive time ``stamp`` (ns)."""
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
        if self.ros1:
            raw = bytes(self.typestore.serialize_ros1(msg, msgtype))
        else:
            raw = bytes(self.typestore.serialize_cdr(msg, msgtype))
        self.writer.write(self.conns[topic], stamp, raw)

    def sdk_options(self, t0: int) -> None:
        """The RealSense SDK's depth units and per-stream (identity) extrinsics, stamped ``t0``."""
        f32 = self.typestore.types["std_msgs/msg/Float32"]
        self.write(
            "/device_0/sensor_0/option/Depth_Units/value",
            "std_msgs/msg/Float32",
            t0,
            f32(data=self.options.depth_scale),
        )
        tf = self.typestore.types["geometry_msgs/msg/Transform"]
        vec = self.typestore.types["geometry_msgs/msg/Vector3"]
        quat = self.typestore.types["geometry_msgs/msg/Quaternion"]
        for stream in ("/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"):
            msg = tf(translation=vec(x=0.0, y=0.0, z=0.0), rotation=quat(x=0.0, y=0.0, z=0.0, w=1.0))
            self.write(stream + "/tf/0", "geometry_msgs/msg/Transform", t0, msg)

    def color(self, stamp: int, index: int, frame: NDArray[np.uint8]) -> None:
        """Colour frame ``index`` with its camera info (and, every 4th frame, an unrelated topic)."""
        ts, topics = self.typestore, self.topics
        header = _header(ts, stamp, "camera_color_optical_frame", self.ros1, index)
        if self.options.compressed:
            msg = _compressed_msg(ts, header, jpg_bytes(bgr_of(frame)), "rgb8; jpeg compressed bgr8")
        else:
            msg = _image_msg(ts, header, frame, "rgb8")
        self.write(topics.color, topics.image_type, stamp, msg)
        info = _camera_info_msg(ts, header, *self.size, self.intrinsics, self.ros1)
        self.write(topics.color_info, "sensor_msgs/msg/CameraInfo", stamp, info)
        if self.options.extra_topics and index % 4 == 0:
            f32 = ts.types["std_msgs/msg/Float32"]
            self.write("/imu/temperature", "std_msgs/msg/Float32", stamp, f32(data=21.5))

    def depth(self, stamp: int, index: int, frame: NDArray[np.uint16]) -> None:
        """Depth frame ``index`` with its camera info."""
        ts, topics = self.typestore, self.topics
        header = _header(ts, stamp, "camera_color_optical_frame", self.ros1, index)
        if self.options.compressed:
            data = bytes(12) + png_bytes(frame)
            msg = _compressed_msg(ts, header, data, "16UC1; compressedDepth png")
        else:
            msg = _image_msg(ts, header, frame, topics.depth_encoding)
        self.write(topics.depth, topics.image_type, stamp, msg)
        info = _camera_info_msg(ts, header, *self.size, self.intrinsics, self.ros1)
        self.write(topics.depth_info, "sensor_msgs/msg/CameraInfo", stamp, info)


@dataclass(frozen=True)
class WrenchTopic:
    """A wrist force/torque sensor's ``geometry_msgs/WrenchStamped`` topic to write beside the frames.

    Attributes
    ----------
    stamps_ns : ndarray of int64, shape (N,)
        Header stamps (and receive times), nanoseconds, on the frames' clock.
    force_n : ndarray of float64, shape (N, 3)
        Force in the sensor's frame, newtons (the torque is written as zero).
    name, frame_id : str
    """

    stamps_ns: NDArray[np.int64]
    force_n: NDArray[np.float64]
    name: str = "/ft_sensor/wrench"
    frame_id: str = "ft_sensor_link"


@dataclass(frozen=True)
class StaticTransform:
    """A ``/tf_static`` transform: ``child``'s pose in ``parent``'s frame (rotation as x, y, z, w)."""

    parent: str
    child: str
    rotation_xyzw: tuple[float, float, float, float]
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class MovingTransform:
    """A ``/tf`` transform that changes with time (a robot's wrist turning): ``child``'s orientation in
    ``parent``'s frame at each stamp.

    Attributes
    ----------
    parent, child : str
    stamps_ns : ndarray of int64, shape (N,)
        Header stamps (and receive times), nanoseconds, on the frames' clock.
    rotations_xyzw : ndarray of float64, shape (N, 4)
        Unit quaternions (x, y, z, w); the translation is written as zero.
    """

    parent: str
    child: str
    stamps_ns: NDArray[np.int64]
    rotations_xyzw: NDArray[np.float64]


def write_ros_bag(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    stamps_ns: Sequence[int] | NDArray[np.int64],
    intrinsics: Intr,
    depth: NDArray[np.uint16] | None = None,
    depth_stamps_ns: Sequence[int] | NDArray[np.int64] | None = None,
    version: Literal[1, 2] = 1,
    options: RosBagOptions | None = None,
) -> Path:
    """Write colour (+ depth) frames as a ROS 1 or ROS 2 bag with the ``rosbags`` writers.

    Parameters
    ----------
    path : path-like
        ROS 1: the ``.bag`` file. ROS 2: the bag folder to create (holds ``metadata.yaml``).
    rgb : ndarray of uint8, shape (T, H, W, 3)
    stamps_ns : sequence of int, length T
        Header stamps (and receive times) of the colour frames, nanoseconds.
    intrinsics : (fx, fy, cx, cy)
    depth : ndarray of uint16, shape (Td, H, W), optional
        Aligned depth in units of ``options.depth_scale``.
    depth_stamps_ns : sequence of int, length Td, optional
        Defaults to ``stamps_ns``.
    version : 1 or 2
    options : RosBagOptions, optional
        Topic layout, ROS 2 storage plugin, compression, depth scale, extra topics, force/torque topics and
        transforms; see :class:`RosBagOptions` for the defaults.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    opts = options or RosBagOptions()
    wrenches, transforms = opts.wrenches, opts.transforms
    path = Path(path)
    ros1 = version == 1
    typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1 and transforms:  # ROS 1's store has no tf2 message built in
        typestore.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", _TF))
    writer = _open_bag_writer(path, ros1, opts.storage)
    d_stamps = list(stamps_ns if depth_stamps_ns is None else depth_stamps_ns)
    h, w = rgb.shape[1:3]
    topics = _bag_topics(opts.layout, opts.compressed)
    with writer:
        out = _BagOut(writer, typestore, ros1, topics, intrinsics, (w, h), opts)
        t0 = int(min(stamps_ns[0], d_stamps[0] if depth is not None else stamps_ns[0]))
        if opts.layout == "realsense-sdk":
            out.sdk_options(t0)
        moving = [t for t in transforms if isinstance(t, MovingTransform)]
        for transform in transforms:
            if isinstance(transform, StaticTransform):
                _write_static(out, transform, t0 - 1)
        events: list[tuple[int, int, str, int]] = [(int(s), 0, "c", i) for i, s in enumerate(stamps_ns)]
        if depth is not None:
            events += [(int(s), 1, "d", i) for i, s in enumerate(d_stamps)]
        for w, topic in enumerate(wrenches):
            events += [(int(s), 2 + w, "w", i) for i, s in enumerate(topic.stamps_ns)]
        first_tf = 2 + len(wrenches)
        for m, transform in enumerate(moving):
            events += [(int(s), first_tf + m, "t", i) for i, s in enumerate(transform.stamps_ns)]
        events.sort()
        for stamp, order, kind, i in events:
            if kind == "c":
                out.color(stamp, i, rgb[i])
            elif kind == "w":
                _write_wrench(out, wrenches[order - 2], stamp, i)
            elif kind == "t":
                _write_moving(out, moving[order - first_tf], stamp, i)
            else:
                assert depth is not None
                out.depth(stamp, i, depth[i])
    return path


_WRENCH = "geometry_msgs/msg/WrenchStamped"
_TF = "tf2_msgs/msg/TFMessage"


def _vector(out: _BagOut, v: Sequence[float]) -> Any:
    return out.typestore.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _write_wrench(out: _BagOut, topic: WrenchTopic, stamp: int, i: int) -> None:
    types = out.typestore.types
    wrench = types["geometry_msgs/msg/Wrench"](
        force=_vector(out, topic.force_n[i]), torque=_vector(out, (0, 0, 0))
    )
    header = _header(out.typestore, stamp, topic.frame_id, out.ros1, i)
    out.write(topic.name, _WRENCH, stamp, types[_WRENCH](header=header, wrench=wrench))


def _write_static(out: _BagOut, transform: StaticTransform, stamp: int) -> None:
    stamped = _stamped(
        out, transform.parent, transform.child, transform.rotation_xyzw, stamp, 0, transform.translation_m
    )
    out.write("/tf_static", _TF, stamp, out.typestore.types[_TF](transforms=[stamped]))


def _write_moving(out: _BagOut, transform: MovingTransform, stamp: int, i: int) -> None:
    stamped = _stamped(out, transform.parent, transform.child, transform.rotations_xyzw[i], stamp, i)
    out.write("/tf", _TF, stamp, out.typestore.types[_TF](transforms=[stamped]))


def _stamped(
    out: _BagOut,
    parent: str,
    child: str,
    xyzw: Sequence[float],
    stamp: int,
    seq: int,
    translation_m: Sequence[float] = (0.0, 0.0, 0.0),
) -> Any:
    """A ``geometry_msgs/TransformStamped``: ``child``'s pose in ``parent``'s frame."""
    types = out.typestore.types
    x, y, z, w = (float(c) for c in xyzw)
    return types["geometry_msgs/msg/TransformStamped"](
        header=_header(out.typestore, stamp, parent, out.ros1, seq),
        child_frame_id=child,
        transform=types["geometry_msgs/msg/Transform"](
            translation=_vector(out, translation_m),
            rotation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        ),
    )


def write_ros2_zip(path: str | Path, rgb: NDArray[np.uint8], **kwargs: Any) -> Path:
    """Write a ROS 2 bag folder with :func:`write_ros_bag` and zip it to ``path``."""
    with tempfile.TemporaryDirectory(prefix="eigenscope-write-") as tmp:
        bag = Path(tmp) / Path(path).stem
        write_ros_bag(bag, rgb, version=2, **kwargs)
        zip_folder(bag, path)
        shutil.rmtree(bag, ignore_errors=True)
    return Path(path)
