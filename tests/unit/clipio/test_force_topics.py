"""Force/torque topics read from bags the tests write (ROS 1, ROS 2 mcap and sqlite3) beside the camera.

Each bag holds the conftest scene's 24 colour frames at 30 fps (with aligned depth) and a wrist F/T topic at
500 Hz carrying a push-hold-release: 0 N until 0.1 s, a ramp to 8 N by 0.2 s, held, released at 0.5 s
(times from the first frame). Messages arrive 1-5 ms after their stamp, so the bag's order is not the
stamps' order and the receive time is not the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from workers.pipeline.clipio import ClipOverrides, open_clip
from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.clipio.force_topics import force_topics, quaternion_to_matrix, read_force
from workers.pipeline.clipio.rosbag import BagClip
from workers.pipeline.errors import ForceError
from workers.pipeline.force import ForceSeries

Truth = Any  # the session fixture from conftest.py
RATE = 500.0
HELD_N = 8.0
RELEASE_S = 0.5
SENSOR = "ft_sensor_link"
CAMERA = "camera_color_optical_frame"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
WRENCH = "geometry_msgs/msg/Wrench"
TF = "tf2_msgs/msg/TFMessage"
#: A generic push direction in the sensor's frame.
DIRECTION = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


def profile(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Push-hold-release magnitude (N) at times ``t`` (s from the first frame)."""
    ramp = np.clip((t - 0.1) / 0.1, 0.0, 1.0) * HELD_N
    return np.where(t < RELEASE_S, ramp, 0.0)


def rot_x(deg: float) -> NDArray[np.float64]:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(deg: float) -> NDArray[np.float64]:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(deg: float) -> NDArray[np.float64]:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


#: The sensor's orientation in the camera's optical frame: 90 degrees about z, then 30 about x.
CAM_FROM_SENSOR = rot_z(90) @ rot_x(30)
#: realsense-ros's camera_color_frame -> camera_color_optical_frame rotation, q = (-0.5, 0.5, -0.5, 0.5).
OPTICAL = Rotation.from_quat([-0.5, 0.5, -0.5, 0.5]).as_matrix()


@dataclass
class ForceTopic:
    """One F/T topic to write: samples at ``RATE`` from ``start_s`` to ``stop_s`` (s from frame 0)."""

    name: str = "/ft_sensor/wrench"
    msgtype: str = WRENCH_STAMPED
    frame_id: str = SENSOR
    start_s: float = -0.1
    stop_s: float = 0.9
    direction: NDArray[np.float64] = field(default_factory=lambda: DIRECTION.copy())
    #: Offset (ns) of the header stamps from the ROS clock (a sensor stamping on its own clock).
    stamp_offset_ns: int = 0
    zero_stamps: bool = False
    duplicates: int = 0
    nan_at: int | None = None

    def samples(self, t0_ns: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """True stamps (ns, ROS clock) and force vectors (N, 3) in the sensor frame."""
        n = round((self.stop_s - self.start_s) * RATE) + 1
        t = self.start_s + np.arange(n) / RATE
        stamps = t0_ns + np.rint(t * 1e9).astype(np.int64)
        force = profile(t)[:, None] * self.direction[None, :]
        return stamps, force


@dataclass
class Transform:
    parent: str
    child: str
    rotation: NDArray[np.float64]
    static: bool = True
    stamp_s: float = 0.0  # /tf only: s from the first frame


def write_bag(
    path: Path,
    truth: Truth,
    *,
    version: int = 1,
    storage: str = "mcap",
    layout: str = "ros",
    forces: tuple[ForceTopic, ...] = (ForceTopic(),),
    transforms: tuple[Transform, ...] = (),
    first_depth: int = 0,
) -> Path:
    """The conftest scene (colour + aligned depth from frame ``first_depth``) with force and tf topics."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros1 = version == 1
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", TF))
    T = ts.types
    opts = bw.RosBagOptions(layout=layout, storage=storage)  # type: ignore[arg-type]
    writer = bw._open_bag_writer(path, ros1, storage)
    stamps = [int(s) for s in truth.stamps_ns]
    t0 = stamps[0]
    events: list[tuple[int, int, str, tuple[Any, ...]]] = []  # (time, order, _BagOut method, args)

    def vec(v: NDArray[np.float64]) -> Any:
        return T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def header(ns: int, frame: str) -> Any:
        return bw._header(ts, ns, frame, ros1, 0)

    for i, s in enumerate(stamps):
        events.append((s, 0, "color", (s, i, truth.rgb[i])))
        if i >= first_depth:
            events.append((s, 1, "depth", (s, i, truth.depth[i])))
    rng = np.random.default_rng(7)
    for ft in forces:
        f_stamps, f_force = ft.samples(t0)
        if ft.nan_at is not None:
            f_force[ft.nan_at, 0] = np.nan
        latency = rng.integers(1_000_000, 5_000_000, len(f_stamps))
        rows = list(range(len(f_stamps))) + list(range(0, ft.duplicates * 7, 7))
        for k in rows:
            wrench = T[WRENCH](force=vec(f_force[k]), torque=vec(np.zeros(3)))
            recv = int(f_stamps[k] + latency[k])
            if ft.msgtype == WRENCH:
                recv = int(f_stamps[k])  # unstamped: the receive time is the truth
                msg = wrench
            else:
                st = 0 if ft.zero_stamps else int(f_stamps[k]) + ft.stamp_offset_ns
                msg = T[WRENCH_STAMPED](header=header(st, ft.frame_id), wrench=wrench)
            events.append((recv, 2, "write", (ft.name, ft.msgtype, recv, msg)))
    for tr in transforms:
        q = Rotation.from_matrix(tr.rotation).as_quat()  # x, y, z, w
        st = t0 + round(tr.stamp_s * 1e9)
        stamped = T["geometry_msgs/msg/TransformStamped"](
            header=header(st, tr.parent),
            child_frame_id=tr.child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=vec(np.array([0.01, 0.02, 0.03])),
                rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )
        topic = "/tf_static" if tr.static else "/tf"
        recv = t0 - 1_000_000 if tr.static else st
        msg = T[TF](transforms=[stamped])
        events.append((recv, 3, "write", (topic, TF, recv, msg)))
    events.sort(key=lambda e: (e[0], e[1]))
    with writer:
        out = bw._BagOut(writer, ts, ros1, bw._bag_topics(layout, False), truth.intrinsics, (96, 80), opts)
        for _, _, method, args in events:
            getattr(out, method)(*args)
    return path


def bag_path(folder: Path, version: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    return folder / ("c.bag" if version == 1 else "bag")


def open_bag(path: Path, **kwargs: Any) -> BagClip:
    clip = open_clip(path, **kwargs)
    assert isinstance(clip, BagClip)
    return clip


def release_time(series: ForceSeries) -> float:
    """First sample after the hold whose magnitude falls below half the held force."""
    mag = np.linalg.norm(series.force_n, axis=1)
    held = np.flatnonzero(mag > 0.9 * HELD_N)
    after = np.flatnonzero((mag < HELD_N / 2) & (np.arange(mag.size) > held[0]))
    return float(series.times_s[after[0]])


BAGS = [(1, "mcap"), (2, "mcap"), (2, "sqlite3")]


# ------------------------------------------------------------------------------------- push-hold-release


@pytest.mark.parametrize(("version", "storage"), BAGS)
def test_push_hold_release_on_the_frames_clock(
    truth: Truth, tmp_path: Path, version: int, storage: str
) -> None:
    ft = ForceTopic(duplicates=10)
    path = write_bag(bag_path(tmp_path, version), truth, version=version, storage=storage, forces=(ft,))
    assert force_topics(path) == [("/ft_sensor/wrench", WRENCH_STAMPED)]
    true_stamps, true_force = ft.samples(int(truth.stamps_ns[0]))
    with open_bag(path) as clip:
        assert force_topics(clip) == [("/ft_sensor/wrench", WRENCH_STAMPED)]
        series = read_force(clip)
        ts = clip.info.timestamps_s
    assert ts is not None
    assert ts[0] == 0.0
    assert series.source == "topic /ft_sensor/wrench"
    assert series.frame_id == SENSOR
    assert not series.in_camera_frame
    assert series.times_s.dtype == np.float64
    assert series.force_n.shape == (len(true_stamps), 3)  # the 10 duplicates are dropped
    assert np.all(np.diff(series.times_s) > 0)
    truth_s = (true_stamps - truth.stamps_ns[0]) * 1e-9
    assert np.max(np.abs(series.times_s - truth_s)) < 1e-3  # in fact exact to the nanosecond
    np.testing.assert_allclose(series.times_s, truth_s, atol=1e-9)
    np.testing.assert_allclose(series.force_n, true_force, atol=1e-12)
    # The same instant on both clocks: frame 3 (0.1 s) and the force sample stamped with it.
    k = int(np.argmin(np.abs(true_stamps - truth.stamps_ns[3])))
    assert true_stamps[k] == truth.stamps_ns[3]
    assert series.times_s[k] == pytest.approx(ts[3], abs=1e-9)
    assert abs(release_time(series) - RELEASE_S) <= 1 / RATE


def test_clock_origin_is_the_first_kept_frame_and_follows_a_given_fps(truth: Truth, tmp_path: Path) -> None:
    """Depth starts at frame 2, so frames 0 and 1 are dropped: time 0 is frame 2's stamp. With --fps 60
    the frames' clock runs twice as fast and the force's with it."""
    ft = ForceTopic()
    path = write_bag(tmp_path / "c.bag", truth, forces=(ft,), first_depth=2)
    true_stamps, _ = ft.samples(int(truth.stamps_ns[0]))
    truth_s = (true_stamps - truth.stamps_ns[2]) * 1e-9
    with open_bag(path) as clip:
        assert clip.info.frames == 22
        series = read_force(clip)
    np.testing.assert_allclose(series.times_s, truth_s, atol=1e-9)
    assert abs(release_time(series) - (RELEASE_S - 2 / 30)) <= 1 / RATE
    with open_bag(path, overrides=ClipOverrides(fps=60.0)) as clip:
        ts = clip.info.timestamps_s
        series = read_force(clip)
    assert ts is not None
    np.testing.assert_allclose(ts, np.arange(22) / 60.0, atol=1e-6)
    np.testing.assert_allclose(series.times_s, truth_s / 2, atol=1e-6)


def test_realsense_sdk_layout(truth: Truth, tmp_path: Path) -> None:
    path = write_bag(tmp_path / "rs.bag", truth, layout="realsense-sdk")
    with open_bag(path) as clip:
        assert "layout: realsense-sdk" in clip.info.notes
        series = read_force(clip)
    assert series.source == "topic /ft_sensor/wrench"
    assert len(series.times_s) == 501
    assert abs(release_time(series) - RELEASE_S) <= 1 / RATE


# ----------------------------------------------------------------------------------------- topic choice


@pytest.mark.parametrize("version", [1, 2])
def test_two_force_topics_refused_with_the_fix_and_chosen(truth: Truth, tmp_path: Path, version: int) -> None:
    left = ForceTopic(name="/left/ft/wrench", frame_id="left_ft")
    right = ForceTopic(name="/right/ft/wrench", frame_id="right_ft", direction=np.array([0.0, 0.0, 1.0]))
    path = write_bag(bag_path(tmp_path, version), truth, version=version, forces=(left, right))
    with open_bag(path) as clip:
        assert force_topics(clip) == [
            ("/left/ft/wrench", WRENCH_STAMPED),
            ("/right/ft/wrench", WRENCH_STAMPED),
        ]
        with pytest.raises(ForceError, match="2 force topics") as err:
            read_force(clip)
        assert "/left/ft/wrench" in str(err.value)
        assert "/right/ft/wrench" in str(err.value)
        assert "--force-topic TOPIC" in str(err.value)
        series = read_force(clip, topic="/right/ft/wrench")
        assert series.source == "topic /right/ft/wrench"
        assert series.frame_id == "right_ft"
        np.testing.assert_allclose(series.force_n[:, :2], 0.0, atol=1e-12)
        assert series.force_n[:, 2].max() == pytest.approx(HELD_N)
        with pytest.raises(ForceError, match="not in the bag") as err:
            read_force(clip, topic="/nope")
        assert "/left/ft/wrench" in str(err.value)
        with pytest.raises(ForceError, match="carries sensor_msgs/msg/Image"):
            read_force(clip, topic="/camera/color/image_raw")
    assert ForceError.code == "invalid-force"


def test_no_force_topic(truth: Truth, tmp_path: Path) -> None:
    path = write_bag(tmp_path / "c.bag", truth, forces=())
    assert force_topics(path) == []
    with open_bag(path) as clip:
        with pytest.raises(ForceError, match="no geometry_msgs/WrenchStamped or Wrench topic"):
            read_force(clip)
        with pytest.raises(ForceError, match="bag holds no force topic"):
            read_force(clip, topic="/ft_sensor/wrench")


@pytest.mark.parametrize("version", [1, 2])
def test_unstamped_wrench_and_zero_stamps_take_the_receive_time(
    truth: Truth, tmp_path: Path, version: int
) -> None:
    plain = ForceTopic(name="/ft/raw", msgtype=WRENCH)
    zero = ForceTopic(name="/ft/zero_stamps", zero_stamps=True)
    path = write_bag(bag_path(tmp_path, version), truth, version=version, forces=(plain, zero))
    true_stamps, true_force = plain.samples(int(truth.stamps_ns[0]))
    truth_s = (true_stamps - truth.stamps_ns[0]) * 1e-9
    with open_bag(path) as clip:
        assert force_topics(clip) == [("/ft/raw", WRENCH), ("/ft/zero_stamps", WRENCH_STAMPED)]
        series = read_force(clip, topic="/ft/raw")
        late = read_force(clip, topic="/ft/zero_stamps")
    assert series.frame_id is None
    assert not series.in_camera_frame
    np.testing.assert_allclose(series.times_s, truth_s, atol=1e-9)
    np.testing.assert_allclose(series.force_n, true_force, atol=1e-12)
    # Zero stamps: the receive time, 1-5 ms late (the k-th receive time lies 1-5 ms after the k-th stamp).
    assert late.frame_id == SENSOR
    assert len(late.times_s) == len(truth_s)
    lag = late.times_s - truth_s
    assert lag.min() >= 0.001 - 1e-9
    assert lag.max() < 0.005


# ------------------------------------------------------------------------------------------- transforms


def realsense_tf(sensor_rot: NDArray[np.float64], *, mount: NDArray[np.float64]) -> tuple[Transform, ...]:
    """realsense-ros's static camera tree, the camera on the wrist (tool0 -> camera_link) and the sensor
    on tool0 with ``sensor_rot`` (its orientation in tool0)."""
    return (
        Transform("camera_link", "camera_color_frame", np.eye(3)),
        Transform("camera_color_frame", CAMERA, OPTICAL),
        Transform("tool0", "camera_link", mount),
        Transform("tool0", SENSOR, sensor_rot),
    )


@pytest.mark.parametrize(("version", "storage"), BAGS)
def test_rotated_sensor_with_tf_static_comes_back_in_the_camera_frame(
    truth: Truth, tmp_path: Path, version: int, storage: str
) -> None:
    mount = rot_y(20)
    # v_cam = OPTICAL^T mount^T sensor_rot v_sensor must equal CAM_FROM_SENSOR v_sensor.
    sensor_rot = mount @ OPTICAL @ CAM_FROM_SENSOR
    ft = ForceTopic()
    path = write_bag(
        bag_path(tmp_path, version),
        truth,
        version=version,
        storage=storage,
        forces=(ft,),
        transforms=realsense_tf(sensor_rot, mount=mount),
    )
    _, sensor_force = ft.samples(int(truth.stamps_ns[0]))
    with open_bag(path) as clip:
        series = read_force(clip)
    assert series.in_camera_frame
    assert series.frame_id == CAMERA
    np.testing.assert_allclose(series.force_n, sensor_force @ CAM_FROM_SENSOR.T, atol=1e-6)
    # Sensor x is camera y (90 degrees about z); the held push points along CAM_FROM_SENSOR @ DIRECTION.
    np.testing.assert_allclose(CAM_FROM_SENSOR @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    held = series.force_n[np.argmax(np.linalg.norm(series.force_n, axis=1))]
    np.testing.assert_allclose(held, HELD_N * (CAM_FROM_SENSOR @ DIRECTION), atol=1e-6)


def test_rotated_sensor_without_tf_stays_in_the_sensor_frame(truth: Truth, tmp_path: Path) -> None:
    ft = ForceTopic()
    mount = rot_y(20)
    # Only the camera's own tree: no chain from the sensor to the camera.
    tree = realsense_tf(mount @ OPTICAL @ CAM_FROM_SENSOR, mount=mount)[:2]
    for name, transforms in (("none.bag", ()), ("camera_only.bag", tree)):
        path = write_bag(tmp_path / name, truth, forces=(ft,), transforms=transforms)
        _, sensor_force = ft.samples(int(truth.stamps_ns[0]))
        with open_bag(path) as clip:
            series = read_force(clip)
        assert not series.in_camera_frame
        assert series.frame_id == SENSOR
        np.testing.assert_allclose(series.force_n, sensor_force, atol=1e-12)


def test_dynamic_tf_takes_the_transform_nearest_in_time(truth: Truth, tmp_path: Path) -> None:
    """The camera is off the arm; /tf publishes the arm's pose at 50 Hz, and the wrist turns by 90 degrees
    about z at 0.4 s. Each sample is rotated with the pose nearest its stamp."""
    world_from_cam = rot_x(-110)
    before, after = np.eye(3), rot_z(90)
    tfs = [Transform("world", CAMERA, world_from_cam)]
    tfs += [
        Transform("world", "tool0", before if t < 0.4 else after, static=False, stamp_s=t)
        for t in np.arange(-0.2, 1.0, 0.02)
    ]
    tfs.append(Transform("tool0", SENSOR, rot_y(35)))
    ft = ForceTopic()
    path = write_bag(tmp_path / "c.bag", truth, forces=(ft,), transforms=tuple(tfs))
    _, sensor_force = ft.samples(int(truth.stamps_ns[0]))
    with open_bag(path) as clip:
        series = read_force(clip)
    assert series.in_camera_frame
    t = series.times_s
    for pose, sel in ((before, t < 0.4 - 0.011), (after, t > 0.4 + 0.011)):
        rot = world_from_cam.T @ pose @ rot_y(35)
        np.testing.assert_allclose(series.force_n[sel], sensor_force[sel] @ rot.T, atol=1e-6)


def test_quaternion_to_matrix_matches_scipy() -> None:
    rng = np.random.default_rng(0)
    for q in rng.normal(size=(20, 4)):
        got = quaternion_to_matrix(type("Q", (), dict(zip("xyzw", q, strict=True)))())
        assert got is not None
        np.testing.assert_allclose(got, Rotation.from_quat(q).as_matrix(), atol=1e-12)
    assert quaternion_to_matrix(type("Q", (), {"x": 0.0, "y": 0.0, "z": 0.0, "w": 0.0})()) is None


# ------------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("version", [1, 2])
def test_clocks_that_do_not_overlap_are_refused(truth: Truth, tmp_path: Path, version: int) -> None:
    # The sensor stamps on its own clock (boot time): received with the frames, stamped 1.7e9 s earlier.
    own_clock = ForceTopic(stamp_offset_ns=-int(truth.stamps_ns[0]) + 1_000 * 10**9)
    path = write_bag(bag_path(tmp_path, version), truth, version=version, forces=(own_clock,))
    with open_bag(path) as clip, pytest.raises(ForceError, match="different clocks") as err:
        read_force(clip)
    assert "does not overlap the frames'" in str(err.value)
    assert "received while the frames were" in str(err.value)
    # Recorded after the camera stopped: neither clock overlaps.
    later = ForceTopic(start_s=5.0, stop_s=6.0)
    path = write_bag(bag_path(tmp_path / "later", version), truth, version=version, forces=(later,))
    with open_bag(path) as clip, pytest.raises(ForceError, match="different clocks") as err:
        read_force(clip)
    assert "received while" not in str(err.value)


def test_non_finite_force_is_refused(truth: Truth, tmp_path: Path) -> None:
    path = write_bag(tmp_path / "c.bag", truth, forces=(ForceTopic(nan_at=40),))
    with open_bag(path) as clip, pytest.raises(ForceError, match=r"1 of 501 messages .* NaN"):
        read_force(clip)
