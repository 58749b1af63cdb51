"""Spring-mass physics: k and m from a held force or an impulse."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.mechanics import DIRECTION_SD_RAD, along_motion, at_frequency, stiffness_and_mass
from workers.pipeline.model import Excitation


def test_step_release_gives_k_from_force_over_amplitude_and_m_from_omega():
    k_true, m_true = 400.0, 0.25
    fn = math.sqrt(k_true / m_true) / (2 * math.pi)
    mech = stiffness_and_mass(
        kind="step_release",
        value=8.0,
        value_sd=0.0,
        amplitude_m=8.0 / k_true,
        amplitude_uncertainty_m=0.0,
        natural_frequency_hz=fn,
        damped_frequency_hz=fn,
        frequency_sd_hz=0.0,
    )
    assert mech.stiffness_n_per_m == pytest.approx(k_true)
    assert mech.mass_kg == pytest.approx(m_true)


def _recorded(direction: tuple[float, float, float] | None, value: float = 6.0) -> Excitation:
    return Excitation(
        kind="step_release", value=value, uncertainty=0.05, source="topic /ft", direction=direction
    )


@pytest.mark.parametrize("angle_deg", [0.0, 20.0, 35.0, 60.0])
def test_a_force_in_the_camera_frame_acts_along_the_motion(angle_deg: float):
    a = math.radians(angle_deg)
    push = (math.cos(a), 0.0, math.sin(a))  # tilted towards the line of sight
    used, reasons = along_motion(_recorded(push, value=6.0 / math.cos(a)), (-1.0, 0.0, 0.0))  # sign free
    assert reasons == []
    assert used is not None
    assert used.value == pytest.approx(6.0, rel=1e-9)
    expected_sd = math.hypot(0.05 * math.cos(a), 6.0 / math.cos(a) * math.sin(a) * DIRECTION_SD_RAD)
    assert used.uncertainty == pytest.approx(expected_sd, rel=1e-9)
    assert used.source == "topic /ft"
    assert any(f"{angle_deg:.1f}°" in n and "projected" in n for n in used.notes), used.notes


def test_a_force_without_a_frame_or_without_a_motion_direction_is_used_as_it_is():
    typed = _recorded(None)
    assert along_motion(typed, (1.0, 0.0, 0.0)) == (typed, [])
    used, reasons = along_motion(_recorded((0.6, 0.8, 0.0)), None)
    assert reasons == []
    assert used is not None
    assert used.value == 6.0
    assert any("motion direction is unknown" in n for n in used.notes)


def test_a_force_across_the_motion_gives_no_stiffness_and_says_why():
    used, reasons = along_motion(_recorded((0.1, 0.995, 0.0)), (1.0, 0.0, 0.0))
    assert used is None
    assert len(reasons) == 1
    assert "across the object's motion" in reasons[0]
    assert "84°" in reasons[0]


def _sampled(kind: str, force: np.ndarray, t: np.ndarray, span: tuple[float, float]) -> Excitation:
    return Excitation(
        kind=kind,  # type: ignore[arg-type]
        value=6.0,
        uncertainty=0.06,
        release_time_s=0.5,
        source="topic /ft",
        force_times_s=t,
        force_along_n=force,
        event_s=span,
    )


@pytest.mark.parametrize(("width_s", "frequency_hz"), [(0.04, 2.5), (0.04, 10.0), (0.15, 2.5), (0.1, 8.0)])
def test_a_release_that_takes_time_counts_for_what_it_excites(width_s: float, frequency_hz: float):
    """A force falling linearly over T starts sin(ωT/2) / (ωT/2) of a sudden release's oscillation."""
    t = np.arange(0.0, 1.0, 1 / 500)
    force = 6.0 * np.clip((0.5 + width_s / 2 - t) / width_s, 0.0, 1.0)
    half = math.pi * frequency_hz * width_s
    used = at_frequency(
        _sampled("step_release", force, t, (0.5 - width_s / 2, 0.5 + width_s / 2)), frequency_hz=frequency_hz
    )
    assert used.value / 6.0 == pytest.approx(math.sin(half) / half, abs=2e-3)
    assert used.uncertainty / 0.06 == pytest.approx(used.value / 6.0)
    assert any(f"{width_s * 1000:.0f} ms" in n and "excites" in n for n in used.notes), used.notes


def test_a_long_strike_counts_for_its_fourier_component_and_a_short_one_for_its_impulse():
    t = np.arange(0.0, 1.0, 1 / 2000)
    for width, frequency, expected in [(0.009, 2.5, None), (0.06, 10.0, "computed")]:
        phase = (t - 0.5 + width / 2) / width
        force = np.where((phase >= 0) & (phase <= 1), np.sin(np.pi * np.clip(phase, 0, 1)), 0.0)
        exc = _sampled("impulse", force, t, (0.5 - width / 2, 0.5 + width / 2))
        used = at_frequency(exc, frequency_hz=frequency)
        if expected is None:
            assert used is exc  # 9 ms at 2.5 Hz: the impulse itself
            continue
        fine = np.linspace(0, width, 20001)
        pulse = np.sin(np.pi * fine / width)
        truth = abs(np.trapezoid(pulse * np.exp(-2j * np.pi * frequency * fine), fine)) / np.trapezoid(
            pulse, fine
        )
        assert used.value / 6.0 == pytest.approx(truth, abs=2e-3)
        assert truth < 0.9


def test_a_typed_excitation_is_not_weighed():
    typed = Excitation(kind="step_release", value=6.0, uncertainty=0.1)
    assert at_frequency(typed, frequency_hz=10.0) is typed


def test_impulse_gives_m_from_v0_over_omega():
    k_true, m_true, j = 900.0, 0.5, 0.2
    wn = math.sqrt(k_true / m_true)
    zeta = 0.05
    wd = wn * math.sqrt(1 - zeta**2)
    amplitude = (j / m_true) / wd
    mech = stiffness_and_mass(
        kind="impulse",
        value=j,
        value_sd=0.01,
        amplitude_m=amplitude,
        amplitude_uncertainty_m=amplitude * 0.02,
        natural_frequency_hz=wn / (2 * math.pi),
        damped_frequency_hz=wd / (2 * math.pi),
        frequency_sd_hz=0.0,
    )
    assert mech.mass_kg == pytest.approx(m_true)
    assert mech.stiffness_n_per_m == pytest.approx(k_true)
    assert mech.mass_uncertainty_kg == pytest.approx(m_true * math.hypot(0.05, 0.02))


def test_zero_amplitude_is_reported_not_divided():
    mech = stiffness_and_mass(
        kind="step_release",
        value=1.0,
        value_sd=0.0,
        amplitude_m=0.0,
        amplitude_uncertainty_m=0.0,
        natural_frequency_hz=5.0,
        damped_frequency_hz=5.0,
        frequency_sd_hz=0.0,
    )
    assert mech.stiffness_n_per_m is None
    assert mech.null_reasons


def _textured(rng, shape, sigma):
    import cv2

    noise = rng.random(shape).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), sigma)
    return (tex - tex.min()) / (tex.max() - tex.min()) * 200 + 25


@pytest.mark.parametrize("affine", [False, True])
def test_registration_ignores_static_background_inside_the_outline(affine):
    """Flow smears motion past an object's trailing edge, so the outline handed to registration holds a
    strip of static background; the registered displacement must still be the object's. (Taken as is,
    the strip pulls it 3 % low here.)"""
    import cv2

    from workers.pipeline.registration import register_translation

    rng = np.random.default_rng(7)
    h, w, s = 160, 200, 4  # rendered at s times the size and area-averaged, like a camera
    background = _textured(rng, (h * s, w * s), 2.0 * s)
    obj = _textured(rng, (h * s, w * s), 1.5 * s)
    inside = np.zeros((h * s, w * s), np.float32)
    inside[50 * s : 110 * s, 70 * s : 140 * s] = 1.0
    t = np.arange(48)
    truth = 6.0 * np.cos(2 * np.pi * t / 9.5) * np.exp(-t / 60)  # px along x
    frames = np.empty((len(t), h, w), np.uint8)
    for k, dx in enumerate(truth):
        move = np.float32([[1, 0, dx * s], [0, 1, 0]])
        alpha = cv2.warpAffine(inside, move, (w * s, h * s), flags=cv2.INTER_LINEAR)
        moved = cv2.warpAffine(obj, move, (w * s, h * s), flags=cv2.INTER_LINEAR)
        big = alpha * moved + (1 - alpha) * background
        frames[k] = np.clip(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA) + 0.5, 0, 255)
    ref = 3  # the object near its rest position, moving fast: the outline is smeared on both sides
    outline = np.zeros((h, w), bool)
    outline[52:108, 60:150] = True
    outline = np.roll(outline, round(truth[ref]), axis=1)  # 8-10 px of background beyond each side
    shift = truth - truth[ref]
    initial = np.stack([shift * 0.9, np.zeros_like(shift)], axis=1)  # flow: biased low by 10 %
    disp, failed = register_translation(frames, outline, ref_index=ref, initial_px=initial, affine=affine)
    assert failed == 0
    gain = float(disp[:, 0] @ shift / (shift @ shift))
    assert gain == pytest.approx(1.0, abs=0.01)
    assert np.abs(disp[:, 0] - shift).max() < 0.12
    assert np.abs(disp[:, 1]).max() < 0.12


def test_registration_stops_once_more_frames_failed_than_the_caller_keeps():
    """Frames that show nothing of the reference's texture fail to register (each after three starts of up
    to 60 iterations); a caller that discards a registration failing more than a tenth of its frames has
    it stop as soon as that many did: the share returned is then just over the bound, not the whole."""
    from workers.pipeline.registration import register_translation

    rng = np.random.default_rng(9)
    frames = np.stack([_textured(rng, (96, 128), 2.0) for _ in range(60)]).astype(np.uint8)
    outline = np.zeros((96, 128), bool)
    outline[30:70, 40:90] = True
    initial = np.zeros((60, 2))
    _, every = register_translation(frames, outline, ref_index=0, initial_px=initial)
    assert every > 0.9
    disp, stopped = register_translation(frames, outline, ref_index=0, initial_px=initial, max_failed=0.1)
    assert 0.1 < stopped <= 0.1 + 2 / 59
    np.testing.assert_array_equal(disp, initial)  # failed frames keep their starting estimate


def test_masked_fit_measures_translation_and_scale_to_hundredths_of_a_pixel():
    """The registration's fitter on a textured object rendered at known sub-pixel shifts and scales
    (4x supersampled, area-averaged, 1 grey level of noise): translations within 0.04 px from a start
    10 % off, and an affine fit that recovers a 2 % scale change and the centroid's shift."""
    import cv2

    from workers.pipeline.registration import MaskedFit

    rng = np.random.default_rng(3)
    h, w, s = 200, 240, 4
    background = _textured(rng, (h * s, w * s), 2.0 * s)
    obj = _textured(rng, (h * s, w * s), 1.5 * s)
    inside = np.zeros((h * s, w * s), np.float32)
    inside[60 * s : 150 * s, 70 * s : 180 * s] = 1.0
    centre = np.array([125.0, 105.0]) * s

    def frame(dx: float, dy: float, scale: float = 1.0) -> np.ndarray:
        move = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), 0.0, scale)
        move[:, 2] += (dx * s, dy * s)
        alpha = cv2.warpAffine(inside, move, (w * s, h * s), flags=cv2.INTER_LINEAR)
        moved = cv2.warpAffine(obj, move, (w * s, h * s), flags=cv2.INTER_LINEAR)
        big = alpha * moved + (1 - alpha) * background
        small = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA) + rng.normal(0, 1.0, (h, w))
        return np.clip(small + 0.5, 0, 255).astype(np.uint8)

    mask = np.zeros((h, w), bool)
    mask[64:146, 74:176] = True
    reference = frame(0.0, 0.0)
    translation = MaskedFit(reference, mask)
    for dx, dy in [(0.37, -0.21), (3.6, 1.15), (-7.25, 0.5), (0.0, 0.0)]:
        found = translation(frame(dx, dy), np.array([0.9 * dx, 0.9 * dy]))
        assert found is not None
        rho, warp = found
        assert rho > 0.95
        assert np.allclose(warp[:, :2], np.eye(2))
        assert np.abs(warp[:, 2] - (dx, dy)).max() < 0.04, (dx, dy, warp[:, 2])

    affine = MaskedFit(reference, mask, affine=True, max_iterations=25)
    found = affine(frame(2.0, -1.0, scale=1.02), np.array([2.0, -1.0]))
    assert found is not None
    _, warp = found
    assert math.sqrt(np.linalg.det(warp[:, :2])) == pytest.approx(1.02, abs=0.003)
    c = centre / s - 0.5 * (s - 1) / s  # the centre in the small frame's pixel coordinates
    moved = warp[:, :2] @ c + warp[:, 2]
    assert np.abs(moved - c - (2.0, -1.0)).max() < 0.05

    flat = MaskedFit(reference, mask)
    assert flat(np.full((h, w), 128, np.uint8), np.zeros(2)) is None
    with pytest.raises(np.linalg.LinAlgError):
        MaskedFit(np.full((h, w), 128, np.uint8), mask)


def _flat_bar(dx: float, shape: tuple[int, int] = (200, 200)) -> np.ndarray:
    """A plain bar 7 px wide and 140 long on a flat wall, moved ``dx`` px across itself (rendered 4x
    finer and area-averaged)."""
    import cv2

    h, w, s = *shape, 4
    big = np.full((h * s, w * s), 100, np.float32)
    bar = np.zeros((h * s, w * s), np.float32)
    bar[30 * s : 170 * s, 97 * s : 104 * s] = 60
    big += cv2.warpAffine(bar, np.float32([[1, 0, dx * s], [0, 1, 0]]), (w * s, h * s))
    return np.clip(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA) + 0.5, 0, 255).astype(np.uint8)


def test_an_affine_fit_a_flat_bar_cannot_hold_is_no_measurement_when_strict():
    """A flat bar holds its motion across itself, not its scale along itself: the translation converges
    on the shift, the affine fit wanders for all of its iterations (its scale off by percents), and a
    strict call says so (None) rather than return where it stopped."""
    from workers.pipeline.registration import MaskedFit

    reference, frame = _flat_bar(0.0), _flat_bar(0.6)
    mask = np.zeros(reference.shape, bool)
    mask[20:180, 85:116] = True
    found = MaskedFit(reference, mask)(frame, np.zeros(2), strict=True)
    assert found is not None
    assert found[1][:, 2] == pytest.approx((0.6, 0.0), abs=0.01)
    affine = MaskedFit(reference, mask, affine=True, max_iterations=25)
    wandered = affine(frame, np.zeros(2))
    assert wandered is not None
    assert abs(np.linalg.det(wandered[1][:, :2]) - 1) > 0.01
    assert affine(frame, np.zeros(2), strict=True) is None


def test_a_flat_bar_is_registered_by_translation_without_refining_every_frame():
    """The affine refinement runs on every frame only where the probe frames' scales change; a flat
    bar's affine fits never converge, so they decide nothing (refining all 40 frames with fits that
    wander cost a thin bar's analysis 1.5 s) and the translations stand, to hundredths of a pixel."""
    from workers.pipeline import registration
    from workers.pipeline.registration import register_translation

    t = np.arange(40)
    truth = 0.8 * np.sin(2 * np.pi * t / 9.0)
    frames = np.stack([_flat_bar(float(dx)) for dx in truth])
    outline = np.zeros(frames.shape[1:], bool)
    outline[20:180, 80:121] = True
    calls = []
    original = registration.MaskedFit.__call__

    def counted(self, frame, start, **kwargs):  # type: ignore[no-untyped-def]
        calls.append(self._affine)
        return original(self, frame, start, **kwargs)

    registration.MaskedFit.__call__ = counted  # type: ignore[method-assign]
    try:
        disp, failed = register_translation(
            frames, outline, ref_index=0, initial_px=np.stack([truth * 0.9, 0 * truth], axis=1)
        )
    finally:
        registration.MaskedFit.__call__ = original  # type: ignore[method-assign]
    assert failed == 0
    assert sum(calls) <= registration.AFFINE_PROBE_FRAMES  # the probe, not every frame
    assert np.abs(disp[:, 0] - (truth - truth[0])).max() < 0.03
