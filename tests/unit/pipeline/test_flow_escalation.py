"""The default flow is the fast DIS "fine" preset; clips where it finds only weak motion are analysed again
on DIS "medium", and the result says so."""

from __future__ import annotations

import math

import pytest

from workers.pipeline.analysis import AnalysisConfig
from workers.pipeline.flow import FlowConfig
from workers.pipeline.synth import Scene, SceneObject


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


@pytest.mark.slow
def test_a_noise_region_dropped_beside_a_clear_object_does_not_cost_a_second_pass(run_scene):
    """At 1280x720 (a quarter-resolution flow grid) the fast flow leaves a small incoherent region at
    about -5 dB beside the clear object; it is dropped and noted, and the clip stays on the fast flow."""
    obj = SceneObject(
        center_px=(640.0, 360.0), size_px=(280.0, 220.0), frequency_hz=5.0, mass_kg=0.5, release_frame=10
    )
    run = run_scene(Scene(width=1280, height=720, frames=128, objects=(obj,), seed=1))
    analysis = run.analysis
    assert analysis.incoherent_snr_db, "the scene no longer leaves an incoherent region: pick another"
    assert max(analysis.incoherent_snr_db) < 0.0
    assert "artefact_peak" in _codes(run)
    assert analysis.parameters["dis_preset"] == "fine"
    assert "careful_flow" not in _codes(run)
    assert len(analysis.objects) == 1
    assert run.rel("eigenfrequency_hz") < 1e-3
    assert run.rel("stiffness_n_per_m") < 0.01


@pytest.mark.slow
def test_weak_motion_is_measured_again_on_the_careful_flow(run_scene):
    k = 0.5 * (2 * math.pi * 5.0) ** 2
    force = k * 0.03 / 525.0  # 0.03 px: the ring-down stands ~3 dB above the noise
    scene = Scene(objects=(SceneObject(frequency_hz=5.0, force_n=force, damping_ratio=0.01),), seed=9)
    run = run_scene(scene)
    assert run.analysis.parameters["dis_preset"] == "medium"
    assert "careful_flow" in _codes(run)
    assert run.analysis.timings_s["fast_flow_pass"] > 0
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
