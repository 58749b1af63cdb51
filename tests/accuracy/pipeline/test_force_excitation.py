"""The robot's force sensor as the excitation (issue 31), end to end: rendered spring-mass scenes written as
ROS 1 and ROS 2 bags with a wrist force/torque topic beside the camera and depth, analysed with no
excitation given. The push, hold and release (or the strike) read from the topic gives stiffness and mass
within 5 %, the release instant within a frame, and the result names the topic; in a rotated sensor
frame with and without /tf_static, from a noisy drifting sensor; two force topics are refused with the
fix, or chosen; a typed force overrides the recording and says so."""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from api_schemas import AnalysisParameters, StepReleaseExcitation
from tests.robot_force import FPS, RELEASE_FRAME, pushed_spring, robot_force
from tests.scenes import ACCURACY_ROWS
from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.errors import ForceError
from workers.pipeline.synth import Scene, render
from workers.runner import run_analysis

pytestmark = pytest.mark.slow

RATE_HZ = 500.0
T0_NS = 1_700_000_000_000_000_000
#: The sensor's frame in the camera's optical frame (a wrist sensor turned every which way).
CAMERA_FROM_SENSOR = Rotation.from_euler("zyx", [90.0, -25.0, 30.0], degrees=True)


def _bag(
    folder: Path,
    scene: Scene,
    *,
    version: int = 1,
    topics: tuple[str, ...] = ("/ft_sensor/wrench",),
    tf: bool = False,
    noise: float = 0.03,
    drift: float = 0.0,
    push_deg: float = 0.0,
    wrist_turn_deg: float = 0.0,
) -> Path:
    """The scene as a bag with its force topic(s). The robot pushes ``push_deg`` off the object's motion
    (+x of the camera, in the image plane): the force along the motion is the scene's, the whole force
    1 / cos larger. ``wrist_turn_deg``: the wrist (and its sensor) turns this far during the record, and
    its orientation is recorded on /tf (``tf`` must be set)."""
    clip = render(scene)
    obj = scene.objects[0]
    rng = np.random.default_rng(scene.seed + 100)
    t = np.arange(-0.9, scene.frames / FPS + 0.2, 1 / RATE_HZ)
    along = robot_force(obj, t, rng, noise=noise, drift=drift)
    tilt = math.radians(push_deg)
    push = np.array([math.cos(tilt), math.sin(tilt), 0.0]) / math.cos(tilt)
    turns = Rotation.from_euler("x", np.linspace(0.0, wrist_turn_deg, len(t))[:, None], degrees=True)
    camera_from_sensor = CAMERA_FROM_SENSOR * turns  # one rotation per force sample
    in_sensor = camera_from_sensor.inv().apply(np.outer(along, push))
    stamps = (T0_NS + np.rint(t * 1e9)).astype(np.int64)
    wrenches = [bw.WrenchTopic(stamps_ns=stamps, force_n=in_sensor, name=name) for name in topics]
    transforms: list[bw.StaticTransform | bw.MovingTransform] = []
    if tf and wrist_turn_deg:
        every = 5  # /tf at 100 Hz
        transforms = [
            bw.MovingTransform(
                "camera_color_optical_frame",
                "ft_sensor_link",
                stamps[::every],
                camera_from_sensor[::every].as_quat(),
            )
        ]
    elif tf:
        q = CAMERA_FROM_SENSOR.as_quat()
        transforms = [bw.StaticTransform("camera_color_optical_frame", "ft_sensor_link", tuple(q))]
    frame_stamps = T0_NS + np.rint(np.arange(scene.frames) / FPS * 1e9).astype(np.int64)
    path = folder / ("scene.bag" if version == 1 else "scene-bag")
    return bw.write_ros_bag(
        path,
        clip.rgb,
        stamps_ns=frame_stamps,
        intrinsics=scene.intrinsics,
        depth=clip.depth,
        version=version,  # type: ignore[arg-type]
        options=bw.RosBagOptions(wrenches=tuple(wrenches), transforms=tuple(transforms)),
    )


def _check(result, scene: Scene, *, topic: str = "/ft_sensor/wrench") -> None:  # type: ignore[no-untyped-def]
    obj = scene.objects[0]
    assert result.objects, "no object found"
    o = result.objects[0]
    ACCURACY_ROWS.append(
        {
            "scene": f"force {obj.excitation} seed {scene.seed}",
            "k_err": abs(o.stiffness_n_per_m / obj.stiffness_n_per_m - 1)
            if o.stiffness_n_per_m
            else math.nan,
            "m_err": abs(o.mass_kg / obj.mass_kg - 1) if o.mass_kg else math.nan,
            "t_rel_err_frames": abs(o.release_time_s - RELEASE_FRAME / FPS) * FPS
            if o.release_time_s is not None
            else math.nan,
        }
    )
    assert o.excitation is not None
    assert o.excitation.source == f"topic {topic}"
    assert o.stiffness_n_per_m == pytest.approx(obj.stiffness_n_per_m, rel=0.05)
    assert o.mass_kg == pytest.approx(obj.mass_kg, rel=0.05)
    assert o.release_time_s == pytest.approx(RELEASE_FRAME / FPS, abs=1 / FPS)


@pytest.mark.parametrize(
    ("excitation", "version"), [("step_release", 1), ("impulse", 1), ("step_release", 2)]
)
def test_the_force_topic_is_the_excitation(tmp_path: Path, excitation: str, version: int) -> None:
    scene = pushed_spring(excitation, seed=11)
    bag = _bag(tmp_path, scene, version=version)
    result = run_analysis(bag, tmp_path / "out")
    _check(result, scene)
    o = result.objects[0]
    assert o.excitation.type == excitation
    # No transform recorded: the magnitude along the force's dominant direction, as the note says.
    assert any("dominant direction" in n or "transform" in n for n in o.excitation.notes), o.excitation.notes


def test_a_sensor_with_its_transform_recorded(tmp_path: Path) -> None:
    scene = pushed_spring("step_release", seed=12)
    result = run_analysis(_bag(tmp_path, scene, tf=True), tmp_path / "out")
    _check(result, scene)
    assert not any("no transform" in n for n in result.objects[0].excitation.notes)


@pytest.mark.parametrize("wrist_turn_deg", [0.0, 60.0])
def test_a_push_off_the_motion_is_projected_on_it_when_the_transform_is_recorded(
    tmp_path: Path, wrist_turn_deg: float
) -> None:
    """The robot pushes 35° off the object's axis of motion (the force 22 % larger than its component
    along it): with the sensor's orientation on /tf_static, or on /tf while the wrist turns 60°, the
    force's component along the motion gives k and m."""
    scene = pushed_spring("step_release", seed=16)
    bag = _bag(tmp_path, scene, tf=True, push_deg=35.0, wrist_turn_deg=wrist_turn_deg)
    result = run_analysis(bag, tmp_path / "out")
    _check(result, scene)
    notes = result.objects[0].excitation.notes
    assert any("projected on the object's motion direction" in n and "35." in n for n in notes), notes


def _forced_scene(seed: int, forcing_hz: tuple[float, ...]) -> Scene:
    obj = dataclasses.replace(
        pushed_spring("step_release", seed).objects[0],
        excitation="forced",
        damping_ratio=0.04,
        forcing_hz=forcing_hz,
        forcing_n=0.3,
        forcing_seed=seed,
    )
    return Scene(width=320, height=240, frames=300, fps=FPS, objects=(obj,), seed=seed)


def test_a_forced_vibration_gives_k_and_m_from_the_response_between_force_and_motion(tmp_path: Path) -> None:
    """A robot that keeps driving the object (twelve cosines from 1.2 to 5 Hz around its 2.5 Hz, from rest)
    gives no hold and no strike: k and m come from the response between the recorded force and the motion,
    one degree of freedom, and the note gives its damping."""
    scene = _forced_scene(17, tuple(np.linspace(1.2, 5.0, 12)))
    result = run_analysis(_bag(tmp_path, scene), tmp_path / "out")
    obj = scene.objects[0]
    assert result.objects, "no object found"
    o = result.objects[0]
    ACCURACY_ROWS.append(
        {
            "scene": "force forced multisine",
            "k_err": abs(o.stiffness_n_per_m / obj.stiffness_n_per_m - 1)
            if o.stiffness_n_per_m
            else math.nan,
            "m_err": abs(o.mass_kg / obj.mass_kg - 1) if o.mass_kg else math.nan,
        }
    )
    assert o.excitation is not None
    assert o.excitation.type == "forced"
    assert o.excitation.source == "topic /ft_sensor/wrench"
    assert o.stiffness_n_per_m == pytest.approx(obj.stiffness_n_per_m, rel=0.05), o.null_reasons
    assert o.mass_kg == pytest.approx(obj.mass_kg, rel=0.05)
    (note,) = [n for n in o.excitation.notes if "response between the recorded force and the motion" in n]
    ratio = re.search(r"ratio ([0-9.]+)", note)
    assert ratio is not None, note
    assert float(ratio.group(1)) == pytest.approx(0.04, rel=0.25), note


def test_a_force_at_one_steady_frequency_does_not_determine_k_and_m_and_says_so(tmp_path: Path) -> None:
    """One driving tone, the object's start-up transient long gone from the window: one point of the
    frequency response, two numbers for three unknowns. No stiffness or mass, and the reason says what to
    record instead."""
    obj = dataclasses.replace(_forced_scene(18, (2.0,)).objects[0], release_frame=-600)
    scene = Scene(width=320, height=240, frames=150, fps=FPS, objects=(obj,), seed=18)
    result = run_analysis(_bag(tmp_path, scene), tmp_path / "out")
    assert result.objects, "no object found"
    o = result.objects[0]
    assert o.stiffness_n_per_m is None
    assert o.mass_kg is None
    assert any("do not determine stiffness and mass" in r and "sweep" in r for r in o.null_reasons), (
        o.null_reasons
    )


@pytest.mark.parametrize("release_s", [0.15, 0.3])
def test_a_slow_release_counts_for_what_it_excites(tmp_path: Path, release_s: float) -> None:
    """The gripper lets go over 150 or 300 ms (a fifth or more of the 2.5 Hz period): the oscillation it
    starts is 79 % or 39 % of a sudden release's, and F/A alone would read k 27 % or 2.6x high. Weighed at
    the object's frequency, the recorded drop gives k and m, and the note says by how much it counted."""
    scene = pushed_spring("step_release", seed=19, release_s=release_s)
    result = run_analysis(_bag(tmp_path, scene), tmp_path / "out")
    _check(result, scene)
    assert any(
        "excites" in n and f"{release_s * 1000:.0f} ms" in n for n in result.objects[0].excitation.notes
    )


def test_a_noisy_drifting_sensor(tmp_path: Path) -> None:
    scene = pushed_spring("step_release", seed=13)
    result = run_analysis(_bag(tmp_path, scene, noise=0.25, drift=0.5), tmp_path / "out")
    _check(result, scene)


def test_two_force_topics_are_refused_with_the_fix_or_chosen(tmp_path: Path) -> None:
    scene = pushed_spring("step_release", seed=14)
    bag = _bag(tmp_path, scene, topics=("/left/wrench", "/right/wrench"))
    with pytest.raises(ForceError, match="--force-topic"):
        run_analysis(bag, tmp_path / "refused")
    result = run_analysis(bag, tmp_path / "out", parameters=AnalysisParameters(force_topic="/right/wrench"))
    _check(result, scene, topic="/right/wrench")


def test_a_typed_force_overrides_the_recording_and_says_so(tmp_path: Path) -> None:
    scene = pushed_spring("step_release", seed=15)
    typed = StepReleaseExcitation(type="step_release", force_n=3.0)
    result = run_analysis(_bag(tmp_path, scene), tmp_path / "out", excitation=typed)
    o = result.objects[0]
    assert o.excitation is not None
    assert o.excitation.source == "request"
    assert o.excitation.value == 3.0
    assert any("overrides" in n and "/ft_sensor/wrench" in n for n in o.excitation.notes)
    # Half the true force: k is half the truth (the typed value is used, as asked).
    assert o.stiffness_n_per_m == pytest.approx(scene.objects[0].stiffness_n_per_m / 2, rel=0.05)
