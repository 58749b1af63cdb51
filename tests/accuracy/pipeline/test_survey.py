"""The whole-clip survey and the window it chooses (issue 6, long clips), on rendered ground truth: where
the ring-down starts, which frequencies are there, how long and how sparse the window must be, and
that memory does not grow with the clip."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from workers.pipeline.errors import ParameterError
from workers.pipeline.model import Survey
from workers.pipeline.survey import (
    MAX_BLOCKS,
    MAX_SEGMENTS,
    survey_motion,
)
from workers.pipeline.synth import Scene, SceneObject, SceneReader
from workers.pipeline.window import WindowRules, plan_window

FPS = 30.0


def _scene(*, frequency_hz, amplitude_px, release_frame, frames, seed=0, width=96, height=72):
    focal = 525.0 * width / 640.0
    mass = 0.5
    k = mass * (2 * math.pi * frequency_hz) ** 2
    obj = SceneObject(
        center_px=(width * 0.5, height * 0.5),
        size_px=(width * 0.3, height * 0.3),
        frequency_hz=frequency_hz,
        damping_ratio=0.01,
        mass_kg=mass,
        force_n=k * amplitude_px / focal,
        release_frame=release_frame,
    )
    return Scene(width=width, height=height, frames=frames, fps=FPS, objects=(obj,), seed=seed)


def _grays(scene):
    with SceneReader(scene, depth=False) as reader:
        for frame in reader.frames():
            yield cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)


def _survey(scene, **kwargs):
    return survey_motion(_grays(scene), fps=scene.fps, total_frames=scene.frames, **kwargs)


@pytest.mark.parametrize(("frequency_hz", "release_frame", "seed"), [(3.1, 500, 0), (1.7, 160, 1)])
def test_survey_finds_the_frequency_and_where_the_ring_down_starts(frequency_hz, release_frame, seed):
    scene = _scene(
        frequency_hz=frequency_hz, amplitude_px=3.0, release_frame=release_frame, frames=900, seed=seed
    )
    survey = _survey(scene)
    assert survey.frames == 900
    assert survey.object_peaks, survey.peaks
    main = survey.object_peaks[0]
    assert main.frequency_hz == pytest.approx(frequency_hz, abs=survey.bin_hz)
    assert survey.explains(frequency_hz)
    assert not survey.explains(frequency_hz * 1.37)
    plan = plan_window(survey, total_frames=900, default_frames=256, max_samples=1024, grid_scale=1.0)
    # The window starts at the release, at most a few frames early, never after it.
    assert release_frame - 12 <= plan.start_frame <= release_frame
    assert plan.frame_step == 1  # 256 frames hold more than ten periods: no need to skip frames
    assert plan.stop_frame - plan.start_frame >= 256
    assert plan.periods >= 10


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_steady_vibration_is_analysed_from_where_it_is_first_seen(seed):
    """A vibration steady over the whole clip (a motor, a turning wheel) has no burst: its survey segments
    differ by their noise alone, and its window starts at the clip's start, not at the segment its noise
    made strongest (a wheel was once analysed over its last 0.9 s only, its rate 2 % off)."""
    focal = 525.0 * 96 / 640.0
    obj = SceneObject(
        center_px=(48.0, 36.0),
        size_px=(29.0, 22.0),
        frequency_hz=3.1,
        excitation="steady",
        steady_amplitude_m=2.0 / focal,
    )
    scene = Scene(width=96, height=72, frames=900, fps=FPS, objects=(obj,), seed=seed)
    survey = _survey(scene)
    assert survey.object_peaks[0].frequency_hz == pytest.approx(3.1, abs=survey.bin_hz)
    plan = plan_window(survey, total_frames=900, default_frames=256, max_samples=1024, grid_scale=1.0)
    assert plan.start_frame <= 8, plan.reason


def test_slow_motion_is_sampled_sparsely_over_enough_periods():
    """A 0.5 Hz swing at 30 fps: ten periods are 600 frames; every k-th frame keeps the buffer near its
    default size while the harmonics stay far below the reduced Nyquist rate."""
    scene = _scene(frequency_hz=0.5, amplitude_px=6.0, release_frame=40, frames=1000)
    survey = _survey(scene)
    assert survey.object_peaks[0].frequency_hz == pytest.approx(0.5, abs=survey.bin_hz)
    plan = plan_window(survey, total_frames=1000, default_frames=256, max_samples=1024, grid_scale=1.0)
    assert plan.frame_step >= 2
    assert plan.samples <= 256
    assert plan.periods >= 10
    assert 28 <= plan.start_frame <= 40
    assert (plan.stop_frame - plan.start_frame - 1) % plan.frame_step == 0
    # Motion between analysed frames is bounded: a tighter bound gives a smaller step.
    tight = plan_window(
        survey,
        total_frames=1000,
        default_frames=256,
        max_samples=1024,
        grid_scale=1.0,
        rules=WindowRules(max_step_grid_px=0.5),
    )
    assert tight.frame_step < plan.frame_step
    # The memory budget caps the window whatever the frequency asks for.
    capped = plan_window(
        survey,
        total_frames=1000,
        default_frames=64,
        max_samples=64,
        grid_scale=1.0,
        rules=WindowRules(max_step_grid_px=0.5),
    )
    assert capped.samples <= 64


def test_a_still_clip_keeps_the_default_window():
    scene = Scene(width=96, height=72, frames=400, fps=FPS, objects=(), seed=3)
    survey = _survey(scene)
    assert survey.object_peaks == []
    plan = plan_window(survey, total_frames=400, default_frames=256, max_samples=1024, grid_scale=1.0)
    assert (plan.start_frame, plan.stop_frame, plan.frame_step) == (0, 256, 1)
    assert "nothing stood out" in plan.reason


def test_camera_shake_is_not_taken_for_an_object():
    scene = Scene(
        width=96,
        height=72,
        frames=600,
        fps=FPS,
        objects=(),
        seed=4,
        shake_px=1.0,
        shake_hz=4.3,
    )
    survey = _survey(scene)
    assert survey.object_peaks == [], [p.frequency_hz for p in survey.peaks]


def test_memory_does_not_grow_with_the_clip():
    """Segment spectra and energy blocks merge pairwise beyond a fixed count, and span the whole clip."""
    rng = np.random.default_rng(0)
    base = cv2.GaussianBlur(rng.uniform(0, 255, (40, 48)).astype(np.float32), (0, 0), 2.0)
    frames = 2600

    def grays():
        for i in range(frames):
            shift = 1.5 * math.sin(2 * math.pi * 2.0 * i / FPS)
            m = np.float32([[1, 0, shift], [0, 1, 0]])
            yield np.clip(cv2.warpAffine(base, m, (48, 40), borderMode=cv2.BORDER_REFLECT), 0, 255).astype(
                np.uint8
            )

    survey = survey_motion(grays(), fps=FPS, total_frames=frames, segment_frames=16)
    assert len(survey.segment_starts) <= MAX_SEGMENTS
    assert survey.segment_power.shape[0] == len(survey.segment_starts)
    assert len(survey.block_energy) <= MAX_BLOCKS
    assert survey.segments >= (frames - 1) // 8 - 2  # every hop was transformed ...
    assert survey.segment_starts[-1] + survey.segment_span >= frames - 2 * survey.segment_span
    assert survey.block_frames * len(survey.block_energy) >= frames - 1  # ... and every frame counted
    assert isinstance(survey, Survey)


def test_bad_input_says_how_to_fix_it():
    frames = [np.zeros((24, 32), np.uint8)] * 40
    with pytest.raises(ParameterError, match="fps"):
        survey_motion(iter(frames), fps=0.0, total_frames=40)
    with pytest.raises(ParameterError, match="too short"):
        survey_motion(iter(frames[:10]), fps=FPS, total_frames=10)
    mixed = [*frames[:20], np.zeros((30, 32), np.uint8), *frames[:19]]
    with pytest.raises(ParameterError, match="one size"):
        survey_motion(iter(mixed), fps=FPS, total_frames=40)
