"""The robot's force sensor as the excitation (issue 31), end to end: rendered spring-mass scenes written as
ROS 1 and ROS 2 bags with a wrist force/torque topic beside the camera and depth, analysed with no
excitation given. The push, hold and release (or the strike) read from the topic gives stiffness and mass
within 5 %, the release instant within a frame, and the result names the topic; in a rotated sensor
frame with and without /tf_static, from a noisy drifting sensor; two force topics are refused with the
fix, or chosen; a typed force overrides the recording and says so."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from api_schemas import AnalysisParameters, StepReleaseExcitation
from tests.scenes import ACCURACY_ROWS
from workers.pipeline.clipio import writers as w
from workers.pipeline.errors import ForceError
from workers.pipeline.synth import Scene, SceneObject, render
from workers.runner import run_analysis

pytestmark = pytest.mark.slow

FPS = 30.0
RELEASE_FRAME = 24
RATE_HZ = 500.0
T0_NS = 1_700_000_000_000_000_000
#: The sensor's frame in the camera's optical frame (a wrist sensor turned every which way).
CAMERA_FROM_SENSOR = Rotation.from_euler("zyx", [90.0, -25.0, 30.0], degrees=True)


def _scene(excitation: str, seed: int) -> Scene:
    obj = SceneObject(
        center_px=(160.0, 120.0),
        size_px=(90.0, 70.0),
        frequency_hz=2.5,
        damping_ratio=0.02,
        mass_kg=0.8,
        excitation=excitation,  # type: ignore[arg-type]
        force_n=6.0,
        impulse_ns=0.16,
        direction=(1.0, 0.0, 0.0),
        release_frame=RELEASE_FRAME,
        depth_m=0.9,
    )
    return Scene(width=320, height=240, frames=150, fps=FPS, objects=(obj,), seed=seed)


def _force_profile(obj: SceneObject, t: np.ndarray, rng: np.random.Generator, *, noise: float, drift: float):
    """The robot's force along the push (N) at times ``t`` (s from frame 0): the hold until the release
    (a 40 ms ramp down), or a 9 ms half-sine strike centred on the release instant with J = impulse."""
    release = RELEASE_FRAME / FPS
    if obj.excitation == "step_release":
        held = obj.force_n * np.clip((release + 0.02 - t) / 0.04, 0.0, 1.0)
        ramp_up = np.clip((t + 0.6) / 0.2, 0.0, 1.0)  # the push began before the recording's frames
        force = held * ramp_up
    else:
        width = 0.009
        phase = (t - release + width / 2) / width
        pulse = np.where((phase >= 0) & (phase <= 1), np.sin(np.pi * np.clip(phase, 0, 1)), 0.0)
        force = obj.impulse_ns * math.pi / (2 * width) * pulse  # ∫ = J
    return force + rng.normal(0.0, noise, t.shape) + drift * (t - t[0]) / (t[-1] - t[0])


def _bag(
    folder: Path,
    scene: Scene,
    *,
    version: int = 1,
    topics: tuple[str, ...] = ("/ft_sensor/wrench",),
    tf: bool = False,
    noise: float = 0.03,
    drift: float = 0.0,
) -> Path:
    clip = render(scene)
    obj = scene.objects[0]
    rng = np.random.default_rng(scene.seed + 100)
    t = np.arange(-0.9, scene.frames / FPS + 0.2, 1 / RATE_HZ)
    along = _force_profile(obj, t, rng, noise=noise, drift=drift)
    # The force pushes the object along +x of the camera; the sensor measures it in its own frame.
    in_sensor = CAMERA_FROM_SENSOR.inv().apply(np.outer(along, [1.0, 0.0, 0.0]))
    stamps = (T0_NS + np.rint(t * 1e9)).astype(np.int64)
    wrenches = [w.WrenchTopic(stamps_ns=stamps, force_n=in_sensor, name=name) for name in topics]
    transforms = []
    if tf:
        q = CAMERA_FROM_SENSOR.as_quat()
        transforms = [w.StaticTransform("camera_color_optical_frame", "ft_sensor_link", tuple(q))]
    frame_stamps = T0_NS + np.rint(np.arange(scene.frames) / FPS * 1e9).astype(np.int64)
    path = folder / ("scene.bag" if version == 1 else "scene-bag")
    return w.write_ros_bag(
        path,
        clip.rgb,
        stamps_ns=frame_stamps,
        intrinsics=scene.intrinsics,
        depth=clip.depth,
        version=version,  # type: ignore[arg-type]
        wrenches=wrenches,
        transforms=transforms,
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
    scene = _scene(excitation, seed=11)
    bag = _bag(tmp_path, scene, version=version)
    result = run_analysis(bag, tmp_path / "out")
    _check(result, scene)
    o = result.objects[0]
    assert o.excitation.type == excitation
    # No transform recorded: the magnitude along the force's dominant direction, as the note says.
    assert any("dominant direction" in n or "transform" in n for n in o.excitation.notes), o.excitation.notes


def test_a_sensor_with_its_transform_recorded(tmp_path: Path) -> None:
    scene = _scene("step_release", seed=12)
    result = run_analysis(_bag(tmp_path, scene, tf=True), tmp_path / "out")
    _check(result, scene)
    assert not any("no transform" in n for n in result.objects[0].excitation.notes)


def test_a_noisy_drifting_sensor(tmp_path: Path) -> None:
    scene = _scene("step_release", seed=13)
    result = run_analysis(_bag(tmp_path, scene, noise=0.25, drift=0.5), tmp_path / "out")
    _check(result, scene)


def test_two_force_topics_are_refused_with_the_fix_or_chosen(tmp_path: Path) -> None:
    scene = _scene("step_release", seed=14)
    bag = _bag(tmp_path, scene, topics=("/left/wrench", "/right/wrench"))
    with pytest.raises(ForceError, match="--force-topic"):
        run_analysis(bag, tmp_path / "refused")
    result = run_analysis(bag, tmp_path / "out", parameters=AnalysisParameters(force_topic="/right/wrench"))
    _check(result, scene, topic="/right/wrench")


def test_a_typed_force_overrides_the_recording_and_says_so(tmp_path: Path) -> None:
    scene = _scene("step_release", seed=15)
    typed = StepReleaseExcitation(type="step_release", force_n=3.0)
    result = run_analysis(_bag(tmp_path, scene), tmp_path / "out", excitation=typed)
    o = result.objects[0]
    assert o.excitation is not None
    assert o.excitation.source == "request"
    assert o.excitation.value == 3.0
    assert any("overrides" in n and "/ft_sensor/wrench" in n for n in o.excitation.notes)
    # Half the true force: k is half the truth (the typed value is used, as asked).
    assert o.stiffness_n_per_m == pytest.approx(scene.objects[0].stiffness_n_per_m / 2, rel=0.05)
