"""One flow pass: the default flow is the fast DIS "fine" preset over the region that moves, at the
resolution it needs, decided before the pass; no clip is analysed twice for its flow (issue 26)."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from workers.pipeline.analysis import AnalysisConfig
from workers.pipeline.flow import FlowConfig
from workers.pipeline.synth import Scene, SceneObject, render


def _codes(run):
    return {q.code for q in run.analysis.quality}


def test_clear_motion_stays_on_the_fast_flow(run_scene):
    scene = Scene(
        width=320, height=240, objects=(SceneObject(center_px=(160, 120), size_px=(70, 55)),), seed=3
    )
    run = run_scene(scene)
    assert run.analysis.parameters["dis_preset"] == "fine"
    assert "careful_flow" not in _codes(run)
    assert "fast_flow_pass" not in run.analysis.timings_s
    assert run.rel("eigenfrequency_hz") < 0.01
    assert run.rel("stiffness_n_per_m") < 0.02


def _with_random_motion(clip, *, rms_px: float, band_hz: tuple[float, float], seed: int):
    """``clip`` with a textured patch pasted into its top-left quarter that moves sideways with
    narrow-band random motion: a spectral peak whose motion is no ring-down (an incoherent region)."""
    rng = np.random.default_rng(seed)
    n = len(clip.rgb)
    freqs = np.fft.rfftfreq(4 * n, 1 / clip.fps)
    spectrum = np.fft.rfft(rng.standard_normal(4 * n))
    spectrum[(freqs < band_hz[0]) | (freqs > band_hz[1])] = 0
    shift = np.fft.irfft(spectrum)[:n]
    shift *= rms_px / shift.std()
    texture = cv2.GaussianBlur(rng.integers(0, 255, (140, 160), dtype=np.uint8), (0, 0), 1.5)
    rgb = clip.rgb.copy()
    y0, x0, h, w = 100, 80, 100, 120
    for t in range(n):
        move = np.float32([[1, 0, -20 + shift[t]], [0, 1, -20]])
        patch = cv2.warpAffine(texture, move, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        rgb[t, y0 : y0 + h, x0 : x0 + w] = patch[..., None]
    return dataclasses.replace(clip, rgb=rgb)


@pytest.mark.slow
def test_a_noise_region_beside_a_clear_object_is_no_object_and_costs_no_second_pass(run_scene):
    """A region whose motion is narrow-band noise (2 px RMS between 7 and 9 Hz: no line, no ring-down)
    beside a clear object is no object, and the clip is measured in one pass on the fast flow."""
    obj = SceneObject(
        center_px=(420.0, 240.0), size_px=(140.0, 110.0), frequency_hz=5.0, mass_kg=0.5, release_frame=10
    )
    scene = Scene(width=640, height=480, frames=128, objects=(obj,), seed=1)
    clip = _with_random_motion(render(scene), rms_px=2.0, band_hz=(7.0, 9.0), seed=1)
    run = run_scene(scene, clip=clip)
    analysis = run.analysis
    assert analysis.parameters["dis_preset"] == "fine"
    assert "fast_flow_pass" not in analysis.timings_s
    assert len(analysis.objects) == 1, [o.eigenfrequency_hz for o in analysis.objects]
    assert run.rel("eigenfrequency_hz") < 1e-3
    assert run.rel("stiffness_n_per_m") < 0.01


@pytest.mark.slow
def test_a_clear_object_at_1280x720_stays_on_the_fast_flow(run_scene):
    """At 1280x720 (a quarter-resolution flow grid) a clear object is measured on the fast flow alone."""
    obj = SceneObject(
        center_px=(640.0, 360.0), size_px=(280.0, 220.0), frequency_hz=5.0, mass_kg=0.5, release_frame=10
    )
    run = run_scene(Scene(width=1280, height=720, frames=128, objects=(obj,), seed=1))
    analysis = run.analysis
    assert analysis.parameters["dis_preset"] == "fine"
    assert "fast_flow_pass" not in analysis.timings_s
    assert len(analysis.objects) == 1
    assert run.rel("eigenfrequency_hz") < 1e-3
    assert run.rel("stiffness_n_per_m") < 0.01


@pytest.mark.slow
def test_weak_motion_is_measured_in_one_pass(run_scene):
    """0.03 px of ring-down (about 3 dB above the noise at half resolution) is found by the look and
    measured on its region at full resolution, once: no second pass on a more careful flow."""
    k = 0.5 * (2 * math.pi * 5.0) ** 2
    force = k * 0.03 / 525.0
    scene = Scene(objects=(SceneObject(frequency_hz=5.0, force_n=force, damping_ratio=0.01),), seed=9)
    run = run_scene(scene)
    assert "fast_flow_pass" not in run.analysis.timings_s
    assert "careful_flow" not in _codes(run)
    assert run.analysis.parameters["region"]["pixel_scale"] == pytest.approx(1.0)
    assert run.rel("eigenfrequency_hz") < 0.01


def test_a_flow_the_user_chose_is_kept(run_scene):
    k = 0.5 * (2 * math.pi * 5.0) ** 2
    scene = Scene(
        width=320,
        height=240,
        objects=(SceneObject(center_px=(160, 120), size_px=(70, 55), force_n=k * 0.1 / 262.5),),
        seed=4,
    )
    run = run_scene(scene, config=AnalysisConfig(flow=FlowConfig(dis_preset="ultrafast")))
    assert run.analysis.parameters["dis_preset"] == "ultrafast"
    assert "careful_flow" not in _codes(run)
