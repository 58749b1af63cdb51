"""Long clips (issue 6): thousands of frames are surveyed once with bounded memory, and the window is
chosen where the ring-down is, long enough for its periods, every k-th frame when the motion is slow.
Rendered frame by frame (:class:`SceneReader`), so the clips never sit in memory whole."""

from __future__ import annotations

import math

import pytest

from tests.scenes import ACCURACY_ROWS
from workers.pipeline.analysis import DEFAULT_MAX_FRAMES, AnalysisConfig, analyze
from workers.pipeline.synth import Scene, SceneObject, SceneReader


def _object(*, width, height, frequency_hz, amplitude_px, release_frame, damping_ratio=0.01):
    focal = 525.0 * width / 640.0
    mass = 0.5
    k = mass * (2 * math.pi * frequency_hz) ** 2
    return SceneObject(
        center_px=(width * 0.5, height * 0.5),
        size_px=(width * 0.25, height * 0.25),
        frequency_hz=frequency_hz,
        damping_ratio=damping_ratio,
        mass_kg=mass,
        force_n=k * amplitude_px / focal,  # A = F / k, in pixels through the pinhole at 1 m
        release_frame=release_frame,
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    ("frequency_hz", "amplitude_px", "seed"), [(0.45, 30.0, 0), (0.65, 20.0, 1), (0.85, 40.0, 2)]
)
def test_a_pendulum_under_one_hertz_filmed_at_60_fps(frequency_hz, amplitude_px, seed):
    """20 s at 60 fps (1200 frames), a swing of tens of pixels: the first 256 frames hold barely two
    periods; the surveyed window holds about ten, sampled every few frames."""
    width, height, fps = 160, 120, 60.0
    obj = _object(
        width=width,
        height=height,
        frequency_hz=frequency_hz,
        amplitude_px=amplitude_px,
        release_frame=90 + 30 * seed,
    )
    scene = Scene(width=width, height=height, frames=1200, fps=fps, objects=(obj,), seed=seed)
    with SceneReader(scene, depth=False) as reader:
        result = analyze(reader)
    assert len(result.objects) == 1, [o.eigenfrequency_hz for o in result.objects]
    measured = result.objects[0].eigenfrequency_hz
    truth = obj.damped_frequency_hz
    ACCURACY_ROWS.append(
        {
            "scene": f"pendulum {frequency_hz} Hz",
            "true_hz": truth,
            "measured_hz": measured,
            "rel_err": abs(measured - truth) / truth,
            "frames": f"{result.frames_used[0]}-{result.frames_used[1]}/{result.frame_step}",
        }
    )
    assert measured == pytest.approx(truth, rel=0.002)
    first, last = result.frames_used
    assert truth * (last - first - 1) / fps >= 8  # enough periods ...
    assert result.frame_step >= 2  # ... in a sparse buffer
    assert result.sample_rate_hz == pytest.approx(fps / result.frame_step)
    assert result.window_survey is not None
    assert result.window_survey.explains(measured)
    assert not any(q.code == "survey_disagrees" for q in result.quality)
    assert any(q.code == "window" for q in result.quality)


@pytest.mark.slow
def test_a_ring_down_late_in_a_long_clip_is_found():
    """Struck after 50 s of nothing: the first 256 frames show a still object."""
    width, height, fps, release = 160, 120, 30.0, 1500
    obj = _object(
        width=width,
        height=height,
        frequency_hz=4.2,
        amplitude_px=4.0,
        release_frame=release,
        damping_ratio=0.02,
    )
    scene = Scene(width=width, height=height, frames=2000, fps=fps, objects=(obj,), seed=5)
    with SceneReader(scene, depth=False) as reader:
        result = analyze(reader)
        blind = analyze(reader, config=AnalysisConfig(auto_window=False))
    assert release - 12 <= result.frames_used[0] <= release
    assert result.frame_step == 1
    assert len(result.objects) == 1
    assert result.objects[0].eigenfrequency_hz == pytest.approx(obj.damped_frequency_hz, rel=0.005)
    assert result.objects[0].release_time_s == pytest.approx(release / fps, abs=1.5 / fps)
    assert result.parameters["start_frame"] == result.frames_used[0]
    # Without the survey the first frames are analysed, and nothing moves in them.
    assert blind.frames_used == (0, DEFAULT_MAX_FRAMES)
    assert blind.window_survey is None
    assert not blind.objects


def test_a_short_clip_and_a_given_window_are_not_surveyed():
    width, height = 96, 72
    obj = _object(width=width, height=height, frequency_hz=3.0, amplitude_px=3.0, release_frame=0)
    short = Scene(width=width, height=height, frames=DEFAULT_MAX_FRAMES, fps=30.0, objects=(obj,), seed=1)
    with SceneReader(short, depth=False) as reader:
        result = analyze(reader)
    assert result.window_survey is None
    assert result.frames_used == (0, DEFAULT_MAX_FRAMES)
    assert result.frame_step == 1
    assert result.objects[0].eigenfrequency_hz == pytest.approx(obj.damped_frequency_hz, rel=0.01)
    long = Scene(width=width, height=height, frames=5000, fps=30.0, objects=(obj,), seed=1)
    with SceneReader(long, depth=False) as reader:
        given = analyze(reader, config=AnalysisConfig(frames=96))
        started = analyze(reader, config=AnalysisConfig(start_frame=10))
    assert given.window_survey is None
    assert given.frames_used == (0, 96)
    assert started.window_survey is None
    assert started.frames_used == (10, 10 + DEFAULT_MAX_FRAMES)
