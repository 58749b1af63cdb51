"""Write a small Intel RealSense recording (.bag, the SDK's ROS 1 layout, file version 3) with ``rosbags``,
as the RealSense Viewer would, so that ``pyrealsense2``'s playback device can play it without a camera."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

STREAM_INFO = "uint32 fps\nstring encoding\nbool is_recommended\n"


def write_realsense_bag(
    path: Path,
    rgb: NDArray[np.uint8],
    depth: NDArray[np.uint16],
    *,
    fps: float,
    intrinsics: tuple[float, float, float, float],
    depth_scale: float = 0.001,
) -> Path:
    """Colour (T, H, W, 3) and aligned depth (T, H, W) frames as a RealSense SDK recording."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(STREAM_INFO, "realsense_msgs/msg/StreamInfo"))
    T = store.types
    h, w = rgb.shape[1:3]
    fx, fy, cx, cy = intrinsics

    def ser(msg: Any, kind: str) -> bytes:
        return bytes(store.serialize_ros1(msg, kind))

    def stamp(ns: int) -> Any:
        return T["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

    def header(ns: int, seq: int) -> Any:
        return T["std_msgs/msg/Header"](seq=seq, stamp=stamp(ns), frame_id="0")

    def camera_info(ns: int) -> Any:
        roi = T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return T["sensor_msgs/msg/CameraInfo"](
            header=header(ns, 0),
            height=h,
            width=w,
            distortion_model="Brown Conrady",
            D=np.zeros(5),
            K=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0]),
            R=np.eye(3).ravel(),
            P=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1.0, 0]),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )

    kv = "diagnostic_msgs/msg/KeyValue"
    static = 1  # ns: the SDK's static information sits at the first valid ROS time
    streams = {
        "/device_0/sensor_0/Depth_0": ("mono16", depth, 2),
        "/device_0/sensor_1/Color_0": ("rgb8", rgb, 3),
    }
    path.unlink(missing_ok=True)
    with Writer(path) as bag:
        conns: dict[str, Any] = {}

        def write(topic: str, kind: str, msg: Any, ns: int) -> None:
            if topic not in conns:
                conns[topic] = bag.add_connection(topic, kind, typestore=store)
            bag.write(conns[topic], ns, ser(msg, kind))

        write("/file_version", "std_msgs/msg/UInt32", T["std_msgs/msg/UInt32"](data=3), static)
        for key, value in (
            ("Name", "Intel RealSense D435"),
            ("Serial Number", "000000000001"),
            ("Firmware Version", "05.12.00.00"),
            ("Product Id", "0B07"),
        ):
            write("/device_0/info", kv, T[kv](key=key, value=value), static)
        for sensor, name in (("sensor_0", "Stereo Module"), ("sensor_1", "RGB Camera")):
            write(f"/device_0/{sensor}/info", kv, T[kv](key="Name", value=name), static)
        write(
            "/device_0/sensor_0/option/Depth_Units/value",
            "std_msgs/msg/Float32",
            T["std_msgs/msg/Float32"](data=depth_scale),
            static,
        )
        write(
            "/device_0/sensor_0/option/Depth_Units/description",
            "std_msgs/msg/String",
            T["std_msgs/msg/String"](data="Number of meters represented by a single depth unit"),
            static,
        )
        for prefix, (encoding, _, _) in streams.items():
            info = T["realsense_msgs/msg/StreamInfo"](fps=round(fps), encoding=encoding, is_recommended=True)
            write(prefix + "/info", "realsense_msgs/msg/StreamInfo", info, static)
            write(prefix + "/info/camera_info", "sensor_msgs/msg/CameraInfo", camera_info(0), static)
            identity = T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            write(prefix + "/tf/0", "geometry_msgs/msg/Transform", identity, static)
        for i in range(rgb.shape[0]):
            ns = 1_000_000_000 + round(i * 1e9 / fps)
            for prefix, (encoding, frames, bpp) in streams.items():
                data = np.ascontiguousarray(frames[i]).view(np.uint8).reshape(-1)
                image = T["sensor_msgs/msg/Image"](
                    header=header(ns, i),
                    height=h,
                    width=w,
                    encoding=encoding,
                    is_bigendian=0,
                    step=w * bpp,
                    data=data,
                )
                write(prefix + "/image/data", "sensor_msgs/msg/Image", image, ns)
                for key, value in (
                    ("frame_timestamp", str(ns / 1e6)),
                    ("timestamp_domain", "System Time"),
                    ("system_time", str(ns // 1_000_000)),
                ):
                    write(prefix + "/image/metadata", kv, T[kv](key=key, value=value), ns)
    return path
