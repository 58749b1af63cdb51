"""The detection policy on arrays (workers.pipeline.detection, artefacts, camera, light): what makes a
motion an object, its regime, and the evidence that drops a peak. Each case is built so that the evidence
is there or is not, with the truth known. (The statistic that decides significance is tested in
test_significance.py.)"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from workers.pipeline.artefacts import Suspect, WindowEvidence, artefact_verdict, light_images
from workers.pipeline.camera import CameraRing
from workers.pipeline.codec import region_keyframe_period
from workers.pipeline.model import ObjectMeasurement
from workers.pipeline.ringdown import Ringdown, fit_ringdown, regime_of
from workers.pipeline.tracking import follow_region, second_motion
from workers.pipeline.verdicts import Footing, faint_copy, held_verdict, oscillation_verdict

FPS = 30.0
N = 256


def _object(**changes) -> ObjectMeasurement:
    base = {
        "id": 1,
        "eigenfrequency_hz": 5.0,
        "eigenfrequency_uncertainty_hz": 0.01,
        "natural_frequency_hz": 5.0,
        "damping_ratio": 0.02,
        "damping_ratio_uncertainty": 0.001,
        "amplitude_px": 2.0,
        "amplitude_m": None,
        "amplitude_uncertainty_m": None,
        "depth_m": None,
        "motion_direction": None,
        "stiffness_n_per_m": None,
        "stiffness_uncertainty_n_per_m": None,
        "mass_kg": None,
        "mass_uncertainty_kg": None,
        "pixel_count": 100,
        "bbox_px": (0, 0, 10, 10),
        "harmonics_hz": [],
        "release_time_s": 0.0,
        "snr_db": 20.0,
        "detection_db": 44.0,
        "concentration": 1.0,
    }
    return ObjectMeasurement(**{**base, **changes})


BAND = (0.2, 14.7)


def _footing(found: tuple[slice, slice], held: tuple[slice, slice], share: float = 1.0) -> Footing:
    f = np.zeros((40, 60), bool)
    f[found] = True
    h = np.zeros((40, 60), np.float32)
    h[held] = share
    return Footing(found=f, held=h)


def test_a_line_on_a_stronger_objects_pixels_is_that_objects_second_motion():
    """Where the picture moves at 267 Hz, the fork's mask holds most of the pixels; the region measured
    for the line lies elsewhere (a flat patch of wall): no object of its own, evidence ``same_pixels``."""
    fork = _object(id=1, eigenfrequency_hz=32.0)
    line = _object(id=2, eigenfrequency_hz=267.4)
    on_fork = (slice(5, 35), slice(20, 30))
    stronger = [(fork, _footing(on_fork, on_fork))]
    verdict = held_verdict(line, _footing(on_fork, (slice(0, 5), slice(40, 50))), stronger)
    assert verdict is not None
    assert verdict.evidence == "same_pixels"
    assert verdict.figures["object_id"] == 1
    assert verdict.figures["held_share"] == pytest.approx(1.0)
    assert verdict.figures["own_share"] == 0.0
    # measured where it was found: an object of its own (a string beside another, a part of the fork
    # ringing alone)
    assert (
        held_verdict(line, _footing(on_fork, on_fork, 0.6), [(fork, _footing(on_fork, on_fork, 0.4))]) is None
    )
    # found on pixels of its own, beside the fork
    beside = (slice(5, 35), slice(35, 45))
    assert held_verdict(line, _footing(beside, beside), stronger) is None
    # the fork's mask holds a little of where it moves, less than a third: not the fork's motion
    assert (
        held_verdict(
            line, _footing(on_fork, (slice(0, 5), slice(40, 50))), [(fork, _footing(on_fork, on_fork, 0.2))]
        )
        is None
    )


def _ringing(amplitude: float, *, phase: float = 0.0, release: int = 20, noise: float = 0.0, seed: int = 0):
    t = (np.arange(N) - release) / FPS
    d = amplitude * np.exp(-0.6 * t) * np.cos(2 * np.pi * 5.0 * t + phase) * (t >= 0)
    return d + noise * np.random.default_rng(seed).standard_normal(N)


def test_a_faint_copy_of_a_stronger_motion_elsewhere_is_that_motion():
    """Flow carries a strong motion faintly across the picture: a region at its frequency moving a
    0.04 % copy in step with it, under noise of 40 % of its amplitude per sample, is no object of its
    own. A second object at the same frequency, released later, or out of phase, or as strong, is."""
    base = _object(amplitude_px=12.0, displacement_px=_ringing(12.0))
    copy = _ringing(0.005, noise=0.002)
    assert faint_copy(_object(id=2, amplitude_px=0.005, displacement_px=copy), base, sample_rate_hz=FPS)
    # anti-phase is a copy too (the sign of a projection)
    flipped = _object(id=2, amplitude_px=0.005, displacement_px=-copy)
    assert faint_copy(flipped, base, sample_rate_hz=FPS)
    for other in (_ringing(0.5, release=90), _ringing(0.5, phase=math.pi / 2)):
        second = _object(id=2, amplitude_px=0.5, displacement_px=other)
        assert not faint_copy(second, base, sample_rate_hz=FPS)
    twin = _object(id=2, amplitude_px=12.0, displacement_px=_ringing(12.0, noise=0.05))
    assert not faint_copy(twin, base, sample_rate_hz=FPS)
    assert not faint_copy(_object(id=2, amplitude_px=0.005), base, sample_rate_hz=FPS)


def test_a_clear_ring_down_is_an_object():
    assert oscillation_verdict(_object(), band_hz=BAND) is None


def test_a_weak_oscillation_is_no_verdict_however_faint_each_sample():
    """Weak per sample: significance decides (test_significance.py), not a threshold on the fit."""
    weak = _object(snr_db=-3.0, detection_db=10.0, concentration=0.9)
    assert oscillation_verdict(weak, band_hz=BAND) is None


def test_motion_that_no_oscillation_explains_is_incoherent_unless_it_is_two():
    """An object is a coherent oscillation: where one damped oscillation explains less than half of a
    region's motion near its frequency (narrow-band random motion), the region is no object; where a
    second motion shares the region (two oscillations a longer window separates), it stays."""
    random = _object(concentration=0.46)
    verdict = oscillation_verdict(random, band_hz=BAND)
    assert verdict is not None
    assert verdict.evidence == "incoherent"
    assert verdict.figures["explained_share"] == pytest.approx(0.46)
    assert oscillation_verdict(_object(concentration=0.46, second_motion=0.4), band_hz=BAND) is None


def test_broadband_motion_is_incoherent_however_strong_its_second_motion():
    """Two unresolved oscillations explain nearly all of their region's motion between them (one of them
    1 / (1 + r), r the second's strength); broadband motion spreads over both and explains little with
    either: the shared 128 Hz fork at 250 fps showed a hump at 62 Hz over the whole picture, 24 % explained
    with a second motion of 0.79 beside it (43 % together), reported as a steady object."""
    hump = _object(concentration=0.24, second_motion=0.79)
    verdict = oscillation_verdict(hump, band_hz=BAND)
    assert verdict is not None
    assert verdict.evidence == "incoherent"
    assert verdict.figures["second_motion"] == pytest.approx(0.79)
    assert "43 %" in verdict.reason
    # two tones of nearly equal strength: one explains about half, together all of it
    assert oscillation_verdict(_object(concentration=0.52, second_motion=0.9), band_hz=BAND) is None
    assert oscillation_verdict(_object(concentration=0.3, second_motion=0.9), band_hz=BAND) is None


@pytest.mark.parametrize(
    ("changes", "evidence"),
    [
        ({"eigenfrequency_hz": 20.0}, "out_of_band"),
        ({"eigenfrequency_hz": 0.05}, "out_of_band"),
        ({"eigenfrequency_uncertainty_hz": 1.3}, "uncertain"),  # a quarter of 5 Hz or more
        ({"eigenfrequency_uncertainty_hz": float("nan")}, "uncertain"),
    ],
)
def test_what_is_not_an_object_says_why(changes, evidence):
    verdict = oscillation_verdict(_object(**changes), band_hz=BAND)
    assert verdict is not None
    assert verdict.evidence == evidence
    assert f"{_object(**changes).eigenfrequency_hz:.4g} Hz" in verdict.reason


def _ringdown(amplitudes: list[float]) -> Ringdown:
    times = np.linspace(0.5, 8.0, len(amplitudes))
    return Ringdown(
        times_s=times,
        amplitude=np.asarray(amplitudes, np.float64),
        frequency_hz=np.full(len(amplitudes), 5.0),
        spectrogram_hz=np.zeros(1),
        spectrogram_power=np.zeros((len(amplitudes), 1)),
    )


def test_regimes():
    assert regime_of(None, decay=0.8, decay_sd=0.05) == "ring_down"
    assert regime_of(None, decay=0.02, decay_sd=0.05) == "steady"  # too little decay to be sure
    assert regime_of(None, decay=0.2, decay_sd=0.1) == "steady"  # not three standard deviations clear
    assert regime_of(_ringdown([1.0, 1.2, 1.45, 1.7, 2.0, 2.3]), decay=0.0, decay_sd=0.01) == "growing"
    assert regime_of(_ringdown([1.0, 1.02, 0.99, 1.01, 1.0, 0.98]), decay=0.0, decay_sd=0.01) == "steady"


def test_the_fit_stays_in_the_band():
    """A strong 32 Hz ring-down and a weak 45 Hz tone in one signal: asked for 40-60 Hz, the fit reports
    the tone whatever it starts from, never the stronger motion outside the band."""
    fps = 250.0
    t = np.arange(251) / fps
    x = np.exp(-0.5 * t) * np.cos(2 * np.pi * 32 * t) + 0.25 * np.cos(2 * np.pi * 45 * t + 0.4)
    v = np.diff(x) + np.random.default_rng(0).normal(0, 0.02, 250)
    for guess in (40.5, 45.0, 59.0):
        fit = fit_ringdown(v, sample_rate_hz=fps, frequency_guess_hz=guess, band_hz=(40.0, 60.0))
        assert 40.0 <= fit.frequency_hz <= 60.0
    fit = fit_ringdown(v, sample_rate_hz=fps, frequency_guess_hz=45.0, band_hz=(40.0, 60.0))
    assert fit.frequency_hz == pytest.approx(45.0, abs=0.05)
    with pytest.raises(ValueError, match="band"):
        fit_ringdown(v, sample_rate_hz=fps, band_hz=(200.0, 300.0))


def test_concentration_tells_one_oscillation_from_narrow_band_noise():
    rng = np.random.default_rng(1)
    n = 512
    t = np.arange(n + 1) / FPS
    steady = np.diff(0.05 * np.sin(2 * np.pi * 7.0 * t)) + rng.normal(0, 0.1, n)
    fit = fit_ringdown(steady, sample_rate_hz=FPS, frequency_guess_hz=7.0)
    assert fit.snr_db < 0  # each sample mostly noise ...
    assert fit.concentration > 0.8  # ... but near 7 Hz one oscillation explains it
    assert fit.detection_db > 15
    spectrum = np.fft.rfft(rng.standard_normal(4 * n))
    freqs = np.fft.rfftfreq(4 * n, 1 / FPS)
    spectrum[(freqs < 6.0) | (freqs > 8.0)] = 0
    noise = np.diff(np.fft.irfft(spectrum)[: n + 1])
    noisy = fit_ringdown(noise / noise.std(), sample_rate_hz=FPS, frequency_guess_hz=7.0)
    assert noisy.concentration < 0.8


def _flow_block(n: int, h: int, w: int) -> np.ndarray:
    return np.zeros((n, h, w, 2), np.float32)


def test_the_camera_is_removed_only_when_the_whole_border_moves():
    h, w, n = 60, 80, 64
    ring = CameraRing((h, w), every=1)
    shake = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n) / FPS).astype(np.float32)
    everything = _flow_block(n, h, w)
    everything[..., 0] = shake[:, None, None]
    flat = everything.reshape(n, -1, 2)
    camera = ring.motions(flat)
    assert ring.moves_as_whole(flat, camera)
    # A surface covering the right 55 % of the picture moves; the rest of the border stays put: its
    # median is the surface's motion, but it is not the camera's.
    surface = _flow_block(n, h, w)
    surface[:, :, int(0.45 * w) :, 0] = shake[:, None, None]
    flat = surface.reshape(n, -1, 2)
    camera = ring.motions(flat)
    assert float(np.abs(camera[:, 0]).max()) > 0.4  # the median follows the surface ...
    assert not ring.moves_as_whole(flat, camera)  # ... and is not taken for the camera
    assert ring.still_fraction(flat, camera) > 0.3


def _evidence(**kw) -> WindowEvidence:
    n = kw.pop("n", N)
    freqs = np.fft.rfftfreq(n, 1 / FPS)
    return WindowEvidence(frequencies_hz=freqs, nfft=n, **kw)


def _blocks(n: int, seed: int = 0) -> np.ndarray:
    """Brightness of 8 x 8 blocks over n + 1 frames: a textured still scene with sensor noise."""
    rng = np.random.default_rng(seed)
    level = rng.uniform(60, 200, (8, 8))
    return (level[None] + rng.normal(0, 0.3, (n + 1, 8, 8))).astype(np.float32)


def test_flicker_is_brightness_in_phase_along_rows_also_where_nothing_moves():
    n = N
    t = np.arange(n + 1) / FPS
    base = _blocks(n)
    flicker = base * (1 + 0.03 * np.sin(2 * np.pi * 10.0 * t))[:, None, None]
    small = np.zeros((8, 8))
    small[2:4, 2:4] = 1.0  # the region covers 4 of 64 blocks
    why = _evidence(brightness=flicker.astype(np.float32)).flicker(10.0, 1.0, small)
    assert why is not None
    assert why.evidence == "illumination_flicker"
    assert "illumination flicker" in why.reason
    assert "static background" in why.reason
    assert why.figures["rows_in_phase"] >= 0.6
    # A textured object moving at 10 Hz changes its blocks' brightness with signs set by its texture.
    rng = np.random.default_rng(2)
    moving = base.copy()
    signs = rng.choice([-1.0, 1.0], (2, 2)) * rng.uniform(0.5, 3.0, (2, 2))
    moving[:, 2:4, 2:4] += (np.sin(2 * np.pi * 10.0 * t)[:, None, None] * signs[None]).astype(np.float32)
    assert _evidence(brightness=moving).flicker(10.0, 1.0, small) is None


def test_the_flow_of_a_flickering_picture_holds_the_flickers_overtones_and_mixes_with_objects():
    """Light flickering at 11.3 Hz (30 fps): the flow's overtone 2 folds back to 7.4 Hz, an object at
    2 Hz lit by it moves faintly at 9.3 and 13.3 Hz; none of them is an object. A motion whose picture
    moves more at it than at the flicker, an object's own strong motion there, a frequency the light does
    not explain, or a picture whose light is steady, is not judged so."""
    t = np.arange(N + 1) / FPS
    base = _blocks(N)
    evidence = _evidence(brightness=(base * (1 + 0.03 * np.sin(2 * np.pi * 11.3 * t))[:, None, None]))
    assert evidence.flicker_frequencies() == [pytest.approx(11.3, abs=FPS / N)]

    def moving_most_at(f0: float):
        return lambda f: 100.0 if abs(f - f0) < 0.2 else 10.0

    def judge(f: float, *, ev=evidence, at=11.3, amplitude=0.05, objects=((2.0, 1.0),)):
        return light_images(
            ev, f, tolerance_hz=0.18, motion_at=moving_most_at(at), amplitude_px=amplitude, objects=objects
        )

    overtone = judge(7.4, objects=())
    assert overtone is not None
    assert overtone.evidence == "illumination_flicker"
    assert overtone.figures["order"] == 2.0
    assert "folded back from 22." in overtone.reason
    assert judge(7.4, at=7.4, objects=()) is None
    for mixed in (9.3, 13.3):
        found = judge(mixed)
        assert found is not None
        assert found.figures["object_hz"] == 2.0
        assert "lit by" in found.reason
    assert judge(9.3, amplitude=0.5) is None
    assert judge(5.0) is None
    assert judge(7.4, ev=_evidence(brightness=base)) is None


def test_keyframe_pulses_are_whole_picture_changes_at_a_period():
    n = N
    rng = np.random.default_rng(3)
    change = rng.uniform(0.9, 1.1, (n, 8, 8)).astype(np.float32)
    change[9::10] += 5.0  # every 10th frame the whole picture jumps
    evidence = _evidence(frame_change=change)
    assert evidence.keyframe_period() == 10
    found = evidence.keyframes(6.0, 0.05, FPS)  # 2 x 3 Hz
    assert found is not None
    assert found.figures["keyframe_period_frames"] == 10
    assert found.figures["order"] == 2
    assert evidence.keyframes(5.0, 0.05, FPS) is None  # between the comb's teeth
    # On the comb only within its own frequency uncertainty: 6.4 Hz is 0.4 Hz from a tooth.
    assert evidence.keyframes(6.4, 0.05, FPS) is None
    assert evidence.keyframes(6.4, 0.3, FPS) is not None
    # A fast vibration makes the change pulse where it moves, not everywhere.
    local = rng.uniform(0.9, 1.1, (n, 8, 8)).astype(np.float32)
    local[9::10, :2, :2] += 5.0
    assert _evidence(frame_change=local).keyframe_period() is None


def _redrawn_region(n: int, seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Block change of a codec at a low bit rate in front of a flat wall: every block re-used unchanged
    (change exactly 0) but for rare small updates, and the lower right blocks redrawn at each keyframe
    (every 12 frames, by different amounts); and the region's coverage."""
    rng = np.random.default_rng(seed)
    change = np.where(rng.random((n, 8, 8)) < 0.03, rng.uniform(0.01, 0.06, (n, 8, 8)), 0.0)
    coverage = np.zeros((8, 8))
    coverage[4:, 3:] = 1.0
    change[11::12, 4:, 3:] += rng.uniform(0.05, 0.8, (len(change[11::12]), 1, 1))
    return change.astype(np.float32), coverage


def test_a_codec_redrawing_one_region_at_its_keyframes_makes_a_localised_comb():
    """Issue 25: a stray object at 100 Hz (240 fps, MPEG-4 with a keyframe every 12 frames, 5 x 20 Hz) was
    the codec redrawing the lower right of a flat wall at its keyframes: the whole picture does not pulse,
    the region does, and its line is localised there."""
    change, coverage = _redrawn_region(N)
    evidence = _evidence(frame_change=change)
    assert evidence.keyframe_period() is None  # most blocks never change: not the whole picture
    assert region_keyframe_period(change, coverage) == 12  # not a multiple that scores higher by chance
    tooth = 5 * FPS / 12
    found = evidence.region_keyframes(coverage, tooth, 0.02, FPS)
    assert found is not None
    assert found.evidence == "codec_keyframes"
    assert found.figures["order"] == 5
    assert evidence.region_keyframes(coverage, tooth + 0.3, 0.02, FPS) is None  # between the teeth
    suspect = Suspect(
        frequency_hz=tooth, sd_hz=0.02, width_bins=1.0, localised=0.9, region_power=1.0, coverage=coverage
    )
    rejected = artefact_verdict(evidence, suspect, sample_rate_hz=FPS)
    assert rejected is not None
    assert rejected.evidence == "codec_keyframes"
    # Elsewhere nothing pulses: a suspect there is judged as before (localised: an object).
    other = np.zeros((8, 8))
    other[:3, :3] = 1.0
    assert artefact_verdict(evidence, replace(suspect, coverage=other), sample_rate_hz=FPS) is None


def test_an_object_moving_at_a_tooth_of_the_comb_changes_in_every_frame_and_is_no_redraw():
    change, coverage = _redrawn_region(N)
    t = np.arange(N)
    # A vibration at fps / 12 itself: its region changes in every frame, most in some phases.
    change[:, 4:, 3:] = (0.4 + 0.3 * np.abs(np.sin(2 * np.pi * t / 12)))[:, None, None]
    change[:, 4:, 3:] += np.random.default_rng(5).uniform(0, 0.05, (N, 4, 5))
    assert region_keyframe_period(change, coverage) is None
    assert _evidence(frame_change=change).region_keyframes(coverage, FPS / 12, 0.02, FPS) is None


def test_the_camera_evidence_needs_the_region_to_move_no_more_than_the_border():
    n = N
    t = np.arange(n) / FPS
    border = np.zeros((n, 2), np.float32)
    border[:, 0] = 0.4 * np.sin(2 * np.pi * 8.0 * t)
    evidence = _evidence(border_px=border, camera_removed=True)
    camera_power = float((np.abs(np.fft.rfft(border[:, 0] - border[:, 0].mean())) ** 2).max())
    assert evidence.camera(8.0, 1.0, region_power=0.01 * camera_power, ring_power=None, sample_rate_hz=FPS)
    assert (
        evidence.camera(8.0, 1.0, region_power=5.0 * camera_power, ring_power=None, sample_rate_hz=FPS)
        is None
    )
    assert (
        evidence.camera(5.0, 1.0, region_power=0.01 * camera_power, ring_power=None, sample_rate_hz=FPS)
        is None
    )


def test_a_second_motion_in_a_region_is_measured():
    """Two patches of one region ring at 10.0 and 10.6 Hz (unresolved in 64 samples): rank two near the
    peak. One object whose two halves move in anti-phase (a fork's tines): rank one."""
    n, h, w = 64, 8, 16
    t = np.arange(n) / FPS
    flow = np.zeros((n, h, w, 2), np.float32)
    flow[:, :, :8, 0] = np.sin(2 * np.pi * 10.0 * t)[:, None, None]
    flow[:, :, 8:, 0] = 0.6 * np.sin(2 * np.pi * 10.6 * t + 1.0)[:, None, None]
    flow += np.random.default_rng(4).normal(0, 0.01, flow.shape).astype(np.float32)
    mask = np.ones((h, w), bool)
    assert second_motion(flow, mask, frequency_hz=10.0, sample_rate_hz=FPS) > 0.2
    tines = np.zeros((n, h, w, 2), np.float32)
    tines[:, :, :8, 0] = np.sin(2 * np.pi * 10.0 * t)[:, None, None]
    tines[:, :, 8:, 0] = -np.sin(2 * np.pi * 10.0 * t)[:, None, None]
    tines += np.random.default_rng(5).normal(0, 0.01, tines.shape).astype(np.float32)
    assert second_motion(tines, mask, frequency_hz=10.0, sample_rate_hz=FPS) < 0.05


def test_a_region_is_followed_through_the_flow():
    """A blob swinging 12 px in a flow field that moves it exactly: its path is recovered, while the
    flow at its starting pixels sees it only while it is there."""
    n, h, w = 60, 40, 80
    truth_x = 12.0 * np.sin(2 * np.pi * np.arange(n + 1) / 30.0)
    flow = np.zeros((n, h, w, 2), np.float32)
    for k in range(n):
        x0 = 40 + truth_x[k]
        cols = np.arange(w)
        inside = np.abs(cols - x0) <= 6
        flow[k, 15:25, inside, 0] = truth_x[k + 1] - truth_x[k]
    seed = np.zeros((h, w), bool)
    seed[17:23, 37:43] = True
    path = follow_region(flow, seed, ref_index=0)
    assert path.shape == (n + 1, 2)
    assert np.abs(path[:, 0] - (truth_x - truth_x[0])).max() < 1.0
    assert math.isclose(float(np.abs(path[:, 1]).max()), 0.0, abs_tol=1e-3)
