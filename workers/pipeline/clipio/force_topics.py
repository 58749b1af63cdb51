"""Force/torque topics recorded beside the camera in a ROS bag: the excitation, on the frames' clock.

Topics
    ``geometry_msgs/WrenchStamped`` and ``geometry_msgs/Wrench`` (unstamped) topics are found by type. With
    one, it is taken; with several, ``topic`` (``--force-topic``) must choose one.

Time
    A sample's time is its header stamp (the bag's receive time when the stamp is zero; always the receive
    time for ``Wrench``), mapped onto the clip's clock exactly as the frames are: seconds from the raw stamp
    of frame 0 (``ClipInfo.timestamps_s[0] == 0``), rescaled like the frames when the user gave the frame
    rate. Samples are sorted by time; samples repeating an earlier stamp are dropped. A topic whose times do
    not overlap the frames' at all is refused: the two are on different clocks.

Frame
    When ``/tf_static`` (and ``/tf``) hold a chain of transforms from the wrench's ``frame_id`` to the colour
    image's ``frame_id`` (for example ``camera_color_optical_frame``), the force vectors are rotated into
    the camera frame (rotation only: a force is a free vector): static transforms as they are, dynamic ones
    nearest in time to each sample. Otherwise they stay in the sensor's frame (``in_camera_frame`` False).
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.rosbag import BagClip, _Source
from workers.pipeline.clipio.types import ReadLimits
from workers.pipeline.errors import ForceError
from workers.pipeline.force import ForceSeries

WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
WRENCH = "geometry_msgs/msg/Wrench"
FORCE_TYPES = (WRENCH_STAMPED, WRENCH)
#: tf2's message, and ROS 1's older ``tf/tfMessage`` (rosbags names both with ``/msg/``).
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
_TF_DEFINITION = "geometry_msgs/TransformStamped[] transforms\n"
_FIX = "choose one with --force-topic TOPIC"


# ----------------------------------------------------------------------------------------------- topics


def force_topics(bag: BagClip | str | Path) -> list[tuple[str, str]]:
    """The bag's force topics.

    Parameters
    ----------
    bag : BagClip or path
        An open bag clip, or the path of a ROS 1 or ROS 2 bag (opened and closed here).

    Returns
    -------
    list of (topic, msgtype)
        Every ``WrenchStamped`` and ``Wrench`` topic, sorted by name; ``msgtype`` is rosbags' name
        (``geometry_msgs/msg/WrenchStamped``).
    """
    if isinstance(bag, BagClip):
        return _force_topics_of(bag._src.connections)
    path = Path(bag)
    from workers.pipeline.clipio.detect import detect_format

    fmt = detect_format(path)
    if fmt not in ("ros1-bag", "ros2-bag"):
        raise ForceError(f"{path.name} is a {fmt} clip, not a ROS bag; force topics are read from bags")
    src = _Source(path, fmt, ReadLimits(), None)
    try:
        return _force_topics_of(src.connections)
    finally:
        src.close()


def _force_topics_of(connections: Iterable[Any]) -> list[tuple[str, str]]:
    found = {(str(c.topic), str(c.msgtype)) for c in connections if c.msgtype in FORCE_TYPES}
    return sorted(found)


def _listing(topics: list[tuple[str, str]]) -> str:
    return ", ".join(f"{name} [{msgtype.rsplit('/', 1)[-1]}]" for name, msgtype in topics)


def _choose(clip: BagClip, topic: str | None) -> tuple[str, str]:
    """The force topic to read: ``topic`` if given (it must carry wrenches), else the only one."""
    fmt = clip._fmt
    found = force_topics(clip)
    if topic is not None:
        for name, msgtype in found:
            if name == topic:
                return name, msgtype
        types = {str(c.topic): str(c.msgtype) for c in clip._src.connections}
        if topic in types:
            raise ForceError(
                f"{fmt}: topic {topic!r} carries {types[topic]}, not geometry_msgs/WrenchStamped or Wrench"
                + (f"; the force topics are {_listing(found)}" if found else "")
            )
        where = f"the force topics are {_listing(found)}" if found else "the bag holds no force topic"
        raise ForceError(f"{fmt}: force topic {topic!r} is not in the bag ({where})")
    if not found:
        names = ", ".join(sorted({str(c.topic) for c in clip._src.connections}))
        raise ForceError(
            f"{fmt}: the bag holds no geometry_msgs/WrenchStamped or Wrench topic (topics: {names[:300]}); "
            "record the force/torque sensor's topic with the camera, or give the force another way"
        )
    if len(found) > 1:
        raise ForceError(f"{fmt}: the bag holds {len(found)} force topics ({_listing(found)}); {_FIX}")
    return found[0]


# ------------------------------------------------------------------------------------------------- read


def read_force(clip: BagClip, *, topic: str | None = None) -> ForceSeries:
    """The force topic's samples on the clip's clock, in the camera frame when the bag's tf allows.

    Parameters
    ----------
    clip : BagClip
        The open bag clip (its frames fix the clock).
    topic : str, optional
        The force topic; needed when the bag holds several (``--force-topic``).

    Returns
    -------
    ForceSeries
        ``times_s`` strictly increasing, same origin (and scale) as ``clip.info.timestamps_s``.

    Raises
    ------
    ForceError
        No force topic, an unknown or ambiguous one, an empty one, non-finite values, or times that do not
        overlap the frames'.
    """
    fmt = clip._fmt
    name, msgtype = _choose(clip, topic)
    conns = [c for c in clip._src.connections if c.topic == name and c.msgtype == msgtype]
    raw = _read_samples(clip._src, conns, msgtype)
    if raw.stamps_ns.size == 0:
        raise ForceError(f"{fmt}: force topic {name} holds no messages; record the sensor or pick another")
    bad = ~np.all(np.isfinite(raw.force), axis=1)
    if bad.any():
        raise ForceError(
            f"{fmt}: {int(bad.sum())} of {bad.size} messages of force topic {name} hold NaN or infinite "
            "forces; fix the sensor driver or the recording"
        )
    order = np.argsort(raw.stamps_ns, kind="stable")
    stamps, force, logs = raw.stamps_ns[order], raw.force[order], raw.log_ns[order]
    keep = np.ones(stamps.size, bool)
    keep[1:] = np.diff(stamps) > 0
    stamps, force, logs = stamps[keep], force[keep], logs[keep]

    times = _to_clip_seconds(clip, stamps)
    ok = np.ones(times.size, bool)
    ok[1:] = np.diff(times) > 0  # a rescaled clock could merge stamps 1 ns apart
    times, stamps, force, logs = times[ok], stamps[ok], force[ok], logs[ok]
    _check_overlap(clip, name, times, logs, raw.stamped)

    frame_id = raw.frame_id
    in_camera = False
    camera = _camera_frame(clip)
    if frame_id and camera:
        rot = _rotation_between(clip._src, frame_id, camera, stamps)
        if rot is not None:
            force = np.einsum("...ij,...j->...i", rot, force)
            frame_id, in_camera = camera, True
    return ForceSeries(
        times_s=np.ascontiguousarray(times, dtype=np.float64),
        force_n=np.ascontiguousarray(force, dtype=np.float64),
        source=f"topic {name}",
        frame_id=frame_id,
        in_camera_frame=in_camera,
    )


@dataclass
class _Samples:
    """A force topic's messages in bag order: stamps (receive time where zero), receive times, forces."""

    stamps_ns: NDArray[np.int64]
    log_ns: NDArray[np.int64]
    force: NDArray[np.float64]
    frame_id: str | None
    stamped: bool


def _read_samples(src: _Source, conns: list[Any], msgtype: str) -> _Samples:
    stamped = msgtype == WRENCH_STAMPED
    stamps: list[int] = []
    logs: list[int] = []
    forces: list[tuple[float, float, float]] = []
    frames: Counter[str] = Counter()
    for _, logtime, data in src.messages(conns):
        msg = src.deserialize(data, msgtype)
        if stamped:
            stamp = _stamp_ns(msg.header.stamp)
            frames[_frame_name(msg.header.frame_id)] += 1
            f = msg.wrench.force
        else:
            stamp = 0
            f = msg.force
        logs.append(int(logtime))
        stamps.append(stamp or int(logtime))
        forces.append((float(f.x), float(f.y), float(f.z)))
    frame_id = frames.most_common(1)[0][0] if frames else ""
    return _Samples(
        stamps_ns=np.asarray(stamps, dtype=np.int64),
        log_ns=np.asarray(logs, dtype=np.int64),
        force=np.asarray(forces, dtype=np.float64).reshape(-1, 3),
        frame_id=frame_id or None,
        stamped=stamped,
    )


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _frame_name(frame_id: Any) -> str:
    """tf2 frame names carry no leading slash (ROS 1 recordings sometimes do)."""
    return str(frame_id).strip().lstrip("/")


# ------------------------------------------------------------------------------------------------ clock


def _clock(clip: BagClip) -> tuple[int, float]:
    """Raw stamp (ns) of the clip's time 0, and clip seconds per raw second (1 unless the user's frame
    rate rescaled the frames' timestamps)."""
    stamps: NDArray[np.int64] = clip._frame_stamps_ns
    origin = int(stamps[0])
    ts = clip.info.timestamps_s
    span = int(stamps[-1]) - origin
    if ts is None or len(ts) < 2 or span <= 0 or clip.info.fps_source != "user":
        return origin, 1.0
    return origin, float(ts[-1]) / (span * 1e-9)


def _to_clip_seconds(clip: BagClip, stamps_ns: NDArray[np.int64]) -> NDArray[np.float64]:
    origin, scale = _clock(clip)
    out: NDArray[np.float64] = (stamps_ns - np.int64(origin)).astype(np.float64) * (1e-9 * scale)
    return out


def _check_overlap(
    clip: BagClip, name: str, times: NDArray[np.float64], logs: NDArray[np.int64], stamped: bool
) -> None:
    ts = clip.info.timestamps_s
    last = float(ts[-1]) if ts is not None and len(ts) else 0.0
    if times[-1] >= 0.0 and times[0] <= last:
        return
    hint = ""
    if stamped:
        log_t = _to_clip_seconds(clip, np.sort(logs))
        if log_t[-1] >= 0.0 and log_t[0] <= last:
            hint = (
                " (its messages were received while the frames were: the sensor stamps them on its own "
                "clock; stamp them with the ROS clock)"
            )
    raise ForceError(
        f"{clip._fmt}: the force topic's clock ({name}: {times[0]:.3f} s to {times[-1]:.3f} s from the "
        f"first frame) does not overlap the frames' (0 s to {last:.3f} s); the recordings are on "
        f"different clocks{hint}"
    )


# ------------------------------------------------------------------------------------------- transforms


def _camera_frame(clip: BagClip) -> str | None:
    """The colour image's ``frame_id`` (None when empty)."""
    msg = clip._peek(clip._color)
    if msg is None:
        return None
    name = _frame_name(msg.header.frame_id)
    return name or None


@dataclass
class _Edge:
    """Transforms of one tf edge: ``v_parent = R v_child``; static ones keep the latest rotation."""

    static: NDArray[np.float64] | None = None
    times: list[int] = field(default_factory=list)
    rots: list[NDArray[np.float64]] = field(default_factory=list)


def _rotation_between(
    src: _Source, child: str, target: str, stamps_ns: NDArray[np.int64]
) -> NDArray[np.float64] | None:
    """Rotation taking vectors in ``child`` to ``target`` through the bag's tf tree: (3, 3), or (N, 3, 3)
    when a dynamic edge is on the chain (its transform nearest in time to each stamp); None if no chain."""
    if child == target:
        return np.eye(3)
    edges = _tf_edges(src)
    path = _chain(edges, child, target)
    if path is None:
        return None
    total: NDArray[np.float64] = np.eye(3)
    for a, b in pairwise(path):
        if (b, a) in edges:  # b is a's parent: v_b = R v_a
            step = _edge_rotation(edges[(b, a)], stamps_ns)
        else:  # a is b's parent: v_a = R v_b, so v_b = R^T v_a
            step = np.swapaxes(_edge_rotation(edges[(a, b)], stamps_ns), -1, -2)
        total = np.matmul(step, total)
    return total


def _edge_rotation(edge: _Edge, stamps_ns: NDArray[np.int64]) -> NDArray[np.float64]:
    if edge.static is not None:
        return edge.static
    times = np.asarray(edge.times, dtype=np.int64)
    order = np.argsort(times, kind="stable")
    times = times[order]
    rots = np.stack(edge.rots)[order]
    hi = np.clip(np.searchsorted(times, stamps_ns), 1, max(len(times) - 1, 1))
    lo = hi - 1
    if len(times) == 1:
        idx = np.zeros(len(stamps_ns), dtype=np.int64)
    else:
        idx = np.where(np.abs(stamps_ns - times[lo]) <= np.abs(times[hi] - stamps_ns), lo, hi)
    picked: NDArray[np.float64] = rots[idx]
    return picked


def _chain(edges: dict[tuple[str, str], _Edge], start: str, goal: str) -> list[str] | None:
    """Frames from ``start`` to ``goal`` along tf edges (either direction), shortest first; None if none."""
    links: dict[str, set[str]] = {}
    for parent, child in edges:
        links.setdefault(parent, set()).add(child)
        links.setdefault(child, set()).add(parent)
    if start not in links or goal not in links:
        return None
    prev: dict[str, str | None] = {start: None}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        if node == goal:
            path = [node]
            while (back := prev[path[-1]]) is not None:
                path.append(back)
            return path[::-1]
        for nxt in sorted(links[node]):
            if nxt not in prev:
                prev[nxt] = node
                queue.append(nxt)
    return None


def _tf_edges(src: _Source) -> dict[tuple[str, str], _Edge]:
    """Every ``(parent, child)`` edge of the bag's tf topics with its rotations."""
    conns = [c for c in src.connections if c.msgtype in TF_TYPES]
    if not conns or not _tf_types_known(src, {str(c.msgtype) for c in conns}):
        return {}
    static_ids = {id(c) for c in conns if str(c.topic).rstrip("/").endswith("tf_static")}
    edges: dict[tuple[str, str], _Edge] = {}
    for conn, logtime, data in src.messages(conns):
        msg = src.deserialize(data, conn.msgtype)
        for tf in msg.transforms:
            parent, child = _frame_name(tf.header.frame_id), _frame_name(tf.child_frame_id)
            if not parent or not child or parent == child:
                continue
            rot = quaternion_to_matrix(tf.transform.rotation)
            if rot is None:
                continue
            edge = edges.setdefault((parent, child), _Edge())
            if id(conn) in static_ids:
                edge.static = rot
            else:
                edge.times.append(_stamp_ns(tf.header.stamp) or int(logtime))
                edge.rots.append(rot)
    return edges


def _tf_types_known(src: _Source, msgtypes: set[str]) -> bool:
    """Register tf's message in the bag's typestore when it lacks it (rosbags' ROS 1 store has none)."""
    from rosbags.typesys import get_types_from_msg

    for msgtype in msgtypes - set(src.typestore.types):
        try:
            src.typestore.register(get_types_from_msg(_TF_DEFINITION, msgtype))
        except Exception:  # a conflicting definition: the force stays in the sensor's frame
            return False
    return True


def quaternion_to_matrix(q: Any) -> NDArray[np.float64] | None:
    """Rotation matrix of a ``geometry_msgs/Quaternion`` (x, y, z, w), normalised; None if degenerate."""
    x, y, z, w = (float(q.x), float(q.y), float(q.z), float(q.w))
    norm = float(np.sqrt(x * x + y * y + z * z + w * w))
    if not (np.isfinite(norm) and norm > 1e-9):
        return None
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )
