"""What the paper could not measure (issue 5), each on several seeds against rendered ground truth:
several objects, shadows, anti-phase parts, damping, impulse excitation, motion out of the image plane,
short clips, release detection and honest uncertainty."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tests.scenes import ACCURACY_ROWS
from workers.pipeline.analysis import Excitation
from workers.pipeline.synth import Scene, SceneObject

SEEDS = [0, 1, 2]


def _iou(a, b):
    return float((a & b).sum() / max((a | b).sum(), 1))


def _match(run, true_label):
    """The measured object whose mask overlaps true object ``true_label`` most."""
    truth = run.clip.mask == true_label
    best = max(run.analysis.objects, key=lambda o: ((run.analysis.labels == o.id) & truth).sum())
    return best, _iou(run.analysis.labels == best.id, truth)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_two_objects_at_distinct_frequencies_get_their_own_masks_and_mechanics(seed, run_scene):
    left = SceneObject(center_px=(170, 250), size_px=(120, 100), frequency_hz=4.0, mass_kg=0.6, force_n=9.0)
    right = SceneObject(
        center_px=(470, 220), size_px=(110, 120), frequency_hz=7.3, mass_kg=0.3, force_n=8.0, depth_m=1.2
    )
    scene = Scene(objects=(left, right), seed=seed)
    excitations = [
        Excitation(kind="step_release", value=9.0, point_px=(170, 250)),
        Excitation(kind="step_release", value=8.0, box_px=(420, 170, 100, 100)),
    ]
    run = run_scene(scene, excitation=excitations)
    assert len(run.analysis.objects) == 2
    for true_label in (1, 2):
        obj, iou = _match(run, true_label)
        truth = run.clip.truth["objects"][true_label - 1]
        assert iou >= 0.7
        assert obj.eigenfrequency_hz == pytest.approx(truth["eigenfrequency_hz"], rel=0.01)
        assert obj.stiffness_n_per_m == pytest.approx(truth["stiffness_n_per_m"], rel=0.1)
        assert obj.mass_kg == pytest.approx(truth["mass_kg"], rel=0.1)
    assert set(np.unique(run.analysis.labels)) == {0, 1, 2}


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_a_shadow_on_the_background_is_kept_out_of_the_object(seed, run_scene):
    scene = Scene(objects=(SceneObject(shadow_offset_px=(45, 35)),), seed=seed)
    run = run_scene(scene)
    obj = run.analysis.objects[0]
    mask = run.analysis.labels == obj.id
    assert run.clip.shadow_mask is not None
    shadow = run.clip.shadow_mask
    assert shadow.sum() > 2000  # the scene really has a visible shadow
    assert run.iou() >= 0.7
    assert (mask & shadow).sum() / shadow.sum() < 0.05
    assert any("background surface" in note for note in obj.notes)
    assert run.rel("stiffness_n_per_m") < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_parts_moving_in_anti_phase_do_not_cancel(seed, run_scene):
    """Two tines ringing at one frequency in opposite directions: signed flow averaged over both would
    cancel; their power adds and the decomposition keeps both."""
    common = {"frequency_hz": 6.0, "mass_kg": 0.4, "force_n": 8.0, "size_px": (80, 160)}
    tines = (
        SceneObject(center_px=(260, 240), direction=(1.0, 0.0, 0.0), **common),
        SceneObject(center_px=(380, 240), direction=(-1.0, 0.0, 0.0), **common),
    )
    run = run_scene(Scene(objects=tines, seed=seed), excitation=None)
    assert len(run.analysis.objects) == 1
    obj = run.analysis.objects[0]
    assert obj.eigenfrequency_hz == pytest.approx(run.clip.truth["objects"][0]["eigenfrequency_hz"], rel=0.01)
    mask = run.analysis.labels == obj.id
    for label in (1, 2):
        assert _iou(mask & (run.clip.mask == label), run.clip.mask == label) >= 0.7
    # The summed spectrum has its peak at f, not at 2f and not at DC.
    a = run.analysis
    band = (a.frequencies_hz >= a.band_hz[0]) & (a.frequencies_hz <= a.band_hz[1])
    peak_f = a.frequencies_hz[band][np.argmax(a.power[band])]
    assert peak_f == pytest.approx(6.0, abs=a.fps / (a.frames_used[1] - a.frames_used[0]))


@pytest.mark.slow
@pytest.mark.parametrize("zeta", [0.01, 0.03, 0.06, 0.1])
def test_damping_ratio_within_20_percent(zeta, run_scene):
    for seed in SEEDS[:2]:
        scene = Scene(objects=(SceneObject(damping_ratio=zeta, frequency_hz=5.5),), seed=seed)
        run = run_scene(scene)
        obj = run.analysis.objects[0]
        assert obj.damping_ratio == pytest.approx(zeta, rel=0.2)
        # The natural frequency is the damped one corrected for damping.
        assert obj.natural_frequency_hz == pytest.approx(5.5, rel=0.01)
        assert obj.ringdown is not None
        # The sliding-window envelope decays at σ = ζ ω_n while it stands above the noise.
        amp, times = obj.ringdown.amplitude, obj.ringdown.times_s
        above = amp >= 0.15 * amp[0]
        slope = -np.polyfit(times[above], np.log(amp[above]), 1)[0]
        assert slope == pytest.approx(zeta * 2 * math.pi * 5.5, rel=0.3)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_impulse_gives_stiffness_and_mass_within_10_percent(seed, run_scene):
    obj = SceneObject(
        excitation="impulse", impulse_ns=0.25 + 0.1 * seed, frequency_hz=4.0 + 2 * seed, mass_kg=0.5
    )
    run = run_scene(Scene(objects=(obj,), seed=seed))
    assert run.rel("stiffness_n_per_m") < 0.1
    assert run.rel("mass_kg") < 0.1


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_amplitude_within_10_percent_for_motion_45_degrees_out_of_the_image_plane(seed, run_scene):
    direction = [(1.0, 0.0, 1.0), (0.0, 1.0, 1.0), (1.0, 1.0, -1.4142)][seed]
    obj = SceneObject(direction=direction, center_px=(300 + 20 * seed, 230))
    run = run_scene(Scene(objects=(obj,), seed=seed))
    measured = run.analysis.objects[0]
    assert run.rel("amplitude_m") < 0.1
    assert run.rel("stiffness_n_per_m") < 0.1
    unit = np.asarray(direction) / np.linalg.norm(direction)
    assert abs(float(np.dot(unit, measured.motion_direction))) > 0.97


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_32_frame_clips_give_frequency_within_2_percent(seed, run_scene):
    f = [3.7, 6.2, 9.1][seed]
    scene = Scene(frames=32, objects=(SceneObject(frequency_hz=f, mass_kg=0.3, force_n=6.0),), seed=seed)
    run = run_scene(scene)
    assert run.rel("eigenfrequency_hz") < 0.02


@pytest.mark.slow
def test_still_frames_are_detected_and_amplitude_is_taken_at_release(run_scene):
    scene = Scene(frames=96, objects=(SceneObject(release_frame=20, damping_ratio=0.08),), seed=5)
    run = run_scene(scene)
    obj = run.analysis.objects[0]
    assert obj.release_time_s == pytest.approx(20 / 30, abs=0.5 / 30)
    # A decayed peak would be ~30 % low at ζ = 0.08 after one period; the release amplitude is not.
    assert run.rel("amplitude_m") < 0.03


@pytest.mark.slow
def test_reported_95_percent_intervals_cover_the_truth_in_90_percent_of_random_seeds(run_scene):
    hits = {"eigenfrequency_hz": 0, "stiffness_n_per_m": 0, "mass_kg": 0, "damping_ratio": 0}
    sd_name = {
        "eigenfrequency_hz": "eigenfrequency_uncertainty_hz",
        "stiffness_n_per_m": "stiffness_uncertainty_n_per_m",
        "mass_kg": "mass_uncertainty_kg",
        "damping_ratio": "damping_ratio_uncertainty",
    }
    trials = 20
    for seed in range(trials):
        rng = np.random.default_rng(500 + seed)
        f, m = rng.uniform(3, 10), rng.uniform(0.2, 2.0)
        depth = rng.uniform(0.8, 1.6)
        k = m * (2 * math.pi * f) ** 2
        amplitude = rng.uniform(3, 14) * depth / 525
        angle = rng.uniform(0, 2 * math.pi)
        obj = SceneObject(
            frequency_hz=f,
            mass_kg=m,
            depth_m=depth,
            damping_ratio=rng.uniform(0.01, 0.1),
            force_n=k * amplitude,
            direction=(math.cos(angle), math.sin(angle), rng.uniform(0, 0.8)),
            release_frame=int(rng.integers(0, 10)),
        )
        # The middle 320x240 of the 640x480 picture: the same object, motion (3-14 px), focal length
        # (525 px) and noise, without the still background around it, which costs three quarters of the
        # rendering and carries no part of what is checked here (whether the reported intervals are
        # honest); the analysis then measures the object at full resolution instead of half.
        scene = Scene(
            width=320,
            height=240,
            focal_px=525.0,
            frames=int(rng.choice([64, 128])),
            objects=(replace(obj, center_px=(160.0, 120.0)),),
            seed=seed,
            rgb_noise=rng.uniform(1, 6),
        )
        run = run_scene(scene, excitation=Excitation(kind="step_release", value=k * amplitude))
        measured = run.analysis.objects[0]
        truth = run.clip.truth["objects"][0]
        for key in hits:
            value, sd = getattr(measured, key), getattr(measured, sd_name[key])
            hits[key] += abs(value - truth[key]) <= 1.96 * sd
    coverage = {key: count / trials for key, count in hits.items()}
    ACCURACY_ROWS.append({"scene": "95% coverage", **{k[:14]: v for k, v in coverage.items()}})
    assert min(coverage.values()) >= 0.9, coverage


def _string(*, width, y, frequency_hz, amplitude_px):
    """A guitar string seen across the picture: long, 4 px thick, one plain colour, vibrating across
    its length with overtones (a plucked string's 2nd and 3rd partials)."""
    focal = 525.0 * width / 640.0
    mass = 0.005
    k = mass * (2 * math.pi * frequency_hz) ** 2
    return SceneObject(
        center_px=(width / 2, y),
        size_px=(0.85 * width, 4.0),
        frequency_hz=frequency_hz,
        damping_ratio=0.002,
        mass_kg=mass,
        force_n=k * amplitude_px / focal,
        direction=(0.0, 1.0, 0.0),
        harmonics=(0.3, 0.15),
        texture="flat",
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    ("pitches_hz", "amplitudes_px", "seed"),
    [((110.0, 147.0), (0.6, 0.8), 0), ((196.0, 247.0), (0.3, 1.0), 1)],
    ids=["A2-D3", "G3-B3"],
)
def test_two_strings_ringing_at_different_pitches_are_two_objects(pitches_hz, amplitudes_px, seed):
    """A guitar filmed at 600 fps: two strings, sub-pixel to 1 px, overtones folded back below the
    Nyquist rate (3 x 110 Hz shows at 270 Hz, 2 x 247 Hz at 106 Hz).

    Masks: dense flow (DIS, 8 px patches) spreads a 4 px string's motion over a few pixels on either
    side, so a mask cannot be as thin as the string (IoU is bounded near 0.3). What it must do is cover
    its own string and stay near it: at least 90 % of the string's pixels in its mask, at least 85 % of
    the mask within 6 px of the string, next to nothing near the other string.
    """
    import cv2

    from workers.pipeline.analysis import analyze
    from workers.pipeline.synth import SceneReader

    width, height = 240, 160
    strings = tuple(
        _string(width=width, y=y, frequency_hz=f, amplitude_px=a)
        for y, f, a in zip((55.0, 105.0), pitches_hz, amplitudes_px, strict=True)
    )
    scene = Scene(width=width, height=height, frames=160, fps=600.0, objects=strings, seed=seed)
    with SceneReader(scene, depth=False) as reader:
        result = analyze(reader)
        truth = reader.mask
    assert len(result.objects) == 2, [o.eigenfrequency_hz for o in result.objects]
    near = [
        cv2.dilate((truth == label).astype(np.uint8), np.ones((13, 13), np.uint8)).astype(bool)
        for label in (1, 2)
    ]
    matched = set()
    for label, string in enumerate(strings, start=1):
        obj = min(result.objects, key=lambda o: abs(o.eigenfrequency_hz - string.damped_frequency_hz))
        matched.add(obj.id)
        assert obj.eigenfrequency_hz == pytest.approx(string.damped_frequency_hz, rel=0.005)
        mask = result.labels == obj.id
        own = truth == label
        coverage = float((mask & own).sum() / own.sum())
        within = float((mask & near[label - 1]).sum() / mask.sum())
        other = float((mask & near[2 - label]).sum() / mask.sum())
        ACCURACY_ROWS.append(
            {
                "scene": f"string {string.frequency_hz:g} Hz",
                "f_err": abs(obj.eigenfrequency_hz / string.damped_frequency_hz - 1),
                "coverage": coverage,
                "within_6px": within,
                "iou": _iou(mask, own),
            }
        )
        assert coverage >= 0.9
        assert within >= 0.85
        assert other <= 0.01
    assert matched == {1, 2}
