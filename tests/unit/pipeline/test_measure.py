"""One object measured (``workers.pipeline.measure``) from a small synthetic flow buffer with a known
ring-down: frequency, damping, release, amplitude in pixels and metres, stiffness and mass; the
uncertainty floors; the object's box; and which object each excitation applies to."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.clipio.types import Intrinsics
from workers.pipeline.errors import ParameterError
from workers.pipeline.measure import Region, WindowContext, assign_excitations, bounding_box, measure_object
from workers.pipeline.model import Excitation
from workers.pipeline.peaks import Peak
from workers.pipeline.ringdown import (
    DAMPING_ABS_FLOOR,
    DAMPING_REL_FLOOR,
    FREQUENCY_LINEWIDTH_FLOOR,
    FREQUENCY_REL_FLOOR,
    RingdownFit,
    damping_sd,
    frequency_sd_hz,
)
from workers.pipeline.stream import FrameBuffers

FPS, N, H, W = 40.0, 160, 24, 32
F_N, ZETA, A_PX, RELEASE = 3.0, 0.02, 2.0, 20
OMEGA_N = 2 * math.pi * F_N
SIGMA = ZETA * OMEGA_N
OMEGA_D = OMEGA_N * math.sqrt(1 - ZETA**2)
F_D = OMEGA_D / (2 * math.pi)
#: The object's pixels on the grid (= input pixels): rows 8-15, columns 10-21.
MASK = np.zeros((H, W), bool)
MASK[8:16, 10:22] = True
DEPTH_M, FOCAL = 2.0, 500.0
FORCE_N = 5.0


def _buffers(kind: str = "step_release") -> FrameBuffers:
    """Flow of a window at 40 fps of an object that rings at 3 Hz with damping 0.02 from frame 20: held
    A_PX to the right until then and released (``step_release``), or struck from rest into a ring-down of
    envelope A_PX (``impulse``); or vibrating steadily from the start (``sustained``). 0.01 px of noise
    everywhere."""
    t = np.arange(N + 1) / FPS
    tr = np.maximum(t - RELEASE / FPS, 0.0)
    decay = np.exp(-SIGMA * tr)
    if kind == "sustained":
        x = A_PX * np.cos(OMEGA_D * t)
    elif kind == "impulse":
        x = A_PX * decay * np.sin(OMEGA_D * tr)
    else:
        x = np.where(
            t < RELEASE / FPS,
            A_PX,
            A_PX * decay * (np.cos(OMEGA_D * tr) + SIGMA / OMEGA_D * np.sin(OMEGA_D * tr)),
        )
    rng = np.random.default_rng(0)
    flow = rng.normal(0, 0.01, (N, H, W, 2)).astype(np.float32)
    flow[:, MASK, 0] += np.diff(x)[:, None].astype(np.float32)
    return FrameBuffers(
        flow=flow,
        depth=None,
        gray=None,
        first_rgb=rng.integers(60, 200, (H, W, 3), dtype=np.uint8),
        count=N,
        times_s=t,
        camera_px=np.zeros((N, 2), np.float32),
        start_s=0.0,
    )


REGION = Region(
    label=1, peak=Peak(frequency_hz=F_D, bin=0, power=1.0, prominence_db=20.0), mask=MASK, full_mask=MASK
)


def _window(buffers: FrameBuffers, **changes) -> WindowContext:
    base = {
        "buffers": buffers,
        "sample_rate_hz": FPS,
        "pixel_scale": 1.0,
        "intrinsics": Intrinsics(FOCAL, FOCAL, 16.0, 12.0),
        "depth_override_m": DEPTH_M,
        "band_hz": (0.5, 15.0),
    }
    return WindowContext(**{**base, **changes})


@pytest.fixture(scope="module")
def ringing() -> FrameBuffers:
    return _buffers()


def test_a_held_and_released_object_is_measured_against_its_ground_truth(ringing):
    excitation = Excitation(kind="step_release", value=FORCE_N, uncertainty=0.05)
    obj = measure_object(REGION, _window(ringing), excitation=excitation)
    amplitude_m = A_PX * DEPTH_M / FOCAL  # 8 mm
    stiffness = FORCE_N / amplitude_m  # F = k A: 625 N/m
    assert obj.id == 1
    assert obj.eigenfrequency_hz == pytest.approx(F_D, rel=1e-3)
    assert obj.natural_frequency_hz == pytest.approx(F_N, rel=1e-3)
    assert obj.damping_ratio == pytest.approx(ZETA, rel=0.05)
    assert obj.regime == "ring_down"
    assert obj.release_time_s == pytest.approx(RELEASE / FPS, abs=0.5 / FPS)
    assert obj.amplitude_px == pytest.approx(A_PX, rel=0.02)
    assert obj.axis_px == pytest.approx((1.0, 0.0), abs=0.01)
    # The pinhole's scaling of the measured amplitude, exactly; the truth within the measurement.
    assert obj.amplitude_m == pytest.approx(obj.amplitude_px * DEPTH_M / FOCAL, rel=1e-6)
    assert obj.amplitude_m == pytest.approx(amplitude_m, rel=0.02)
    assert obj.depth_m == DEPTH_M
    assert obj.stiffness_n_per_m == pytest.approx(stiffness, rel=0.03)
    assert obj.mass_kg == pytest.approx(stiffness / OMEGA_N**2, rel=0.03)
    assert 0 < obj.stiffness_uncertainty_n_per_m < 0.1 * stiffness
    assert obj.null_reasons == []
    # The uncertainties include the floors, and the truth lies within a few of them.
    assert obj.eigenfrequency_uncertainty_hz >= FREQUENCY_REL_FLOOR * obj.eigenfrequency_hz
    assert abs(obj.eigenfrequency_hz - F_D) <= 3 * obj.eigenfrequency_uncertainty_hz
    assert abs(obj.damping_ratio - ZETA) <= 3 * obj.damping_ratio_uncertainty
    # What the object is: its pixels, box and series.
    assert obj.pixel_count == 96
    assert obj.bbox_px == (10, 8, 12, 8)
    assert obj.saturated_fraction == 0.0
    assert obj.displacement_px.shape == obj.model_displacement_px.shape == (N + 1,)
    after = np.isfinite(obj.model_displacement_px)
    assert not after[:RELEASE].any()
    assert after[RELEASE + 1 :].all()
    # The integrated motion follows the model after release, aligned to its mean level; it may differ by a
    # straight line (the flow's mean over the window is taken out as drift, not motion).
    diff = obj.displacement_px[after] - obj.model_displacement_px[after]
    assert abs(float(diff.mean())) < 1e-9
    k = np.arange(len(diff))
    assert np.max(np.abs(diff - np.polyval(np.polyfit(k, diff, 1), k))) < 0.03
    assert obj.ringdown is not None
    assert obj.fitted_duration_s == pytest.approx((N - RELEASE) / FPS, abs=2 / FPS)


def test_without_excitation_or_camera_the_figures_that_need_them_are_null_with_reasons(ringing):
    obj = measure_object(REGION, _window(ringing, intrinsics=None, depth_override_m=None))
    assert obj.eigenfrequency_hz == pytest.approx(F_D, rel=1e-3)
    assert obj.amplitude_px == pytest.approx(A_PX, rel=0.02)  # no excitation: the envelope at release
    assert obj.amplitude_m is None
    assert obj.stiffness_n_per_m is None
    assert obj.mass_kg is None
    reasons = " ".join(obj.null_reasons)
    assert "no depth" in reasons
    assert "no excitation given" in reasons


def test_a_struck_object_gets_its_mass_from_the_impulse():
    """Struck by J from rest: v0 = J / m, and the ring-down's envelope at release is v0 / ω_d (8 mm here),
    so J = m ω_d A for a known mass."""
    mass = 1.5
    amplitude_m = A_PX * DEPTH_M / FOCAL
    impulse = mass * OMEGA_D * amplitude_m
    obj = measure_object(
        REGION, _window(_buffers("impulse")), excitation=Excitation(kind="impulse", value=impulse)
    )
    assert obj.eigenfrequency_hz == pytest.approx(F_D, rel=1e-3)
    assert obj.release_time_s == pytest.approx(RELEASE / FPS, abs=0.5 / FPS)
    assert obj.amplitude_m == pytest.approx(amplitude_m, rel=0.03)
    assert obj.mass_kg == pytest.approx(mass, rel=0.03)
    assert obj.stiffness_n_per_m == pytest.approx(mass * OMEGA_N**2, rel=0.03)


def test_a_sustained_vibration_has_no_damping():
    obj = measure_object(REGION, _window(_buffers("sustained")))
    assert obj.eigenfrequency_hz == pytest.approx(F_D, rel=1e-3)
    assert obj.regime != "ring_down"
    assert obj.damping_ratio is None
    assert obj.damping_ratio_uncertainty is None
    assert any("not a ring-down" in r for r in obj.null_reasons)


# --- uncertainty floors -------------------------------------------------------------------------------


def _fit(**changes) -> RingdownFit:
    base = {
        "frequency_hz": 10.0,
        "natural_frequency_hz": 10.0,
        "damping_ratio": 0.001,
        "amplitude": 1.0,
        "phase_rad": 0.0,
        "decay_per_s": 0.06,
        "start_index": 0,
        "frequency_sd_hz": 0.01,
        "damping_sd": 2e-4,
        "amplitude_sd": 0.01,
        "residual_rms": 0.01,
        "snr_db": 20.0,
    }
    return RingdownFit(**{**base, **changes})


def test_the_frequency_uncertainty_adds_the_relative_or_the_linewidth_floor():
    light = _fit()  # damping 0.001: the relative floor (3e-4 of 10 Hz) is the larger
    assert frequency_sd_hz(light) == pytest.approx(math.hypot(0.01, FREQUENCY_REL_FLOOR * 10.0))
    heavy = _fit(damping_ratio=0.05)  # 0.005 of the 2 zeta f = 1 Hz resonance width: 0.005 Hz
    assert frequency_sd_hz(heavy) == pytest.approx(
        math.hypot(0.01, FREQUENCY_LINEWIDTH_FLOOR * 2 * 0.05 * 10)
    )
    assert frequency_sd_hz(light, t_factor=2.5) == pytest.approx(math.hypot(0.025, 3e-4 * 10.0))
    assert frequency_sd_hz(light, rel_floor=0.01) == pytest.approx(math.hypot(0.01, 0.1))
    # A fit that cannot state its own uncertainty is 100 % uncertain.
    assert frequency_sd_hz(_fit(frequency_sd_hz=float("inf"))) >= 10.0


def test_the_damping_uncertainty_adds_its_floors():
    fit = _fit(damping_ratio=0.02, damping_sd=5e-4)
    expected = math.sqrt(5e-4**2 + (DAMPING_REL_FLOOR * 0.02) ** 2 + DAMPING_ABS_FLOOR**2)
    assert damping_sd(fit) == pytest.approx(expected)
    assert damping_sd(fit, t_factor=3.0) == pytest.approx(
        math.sqrt(1.5e-3**2 + (DAMPING_REL_FLOOR * 0.02) ** 2 + DAMPING_ABS_FLOOR**2)
    )
    assert damping_sd(_fit(damping_sd=float("nan"))) == pytest.approx(1.0, rel=1e-6)


# --- bounding_box -------------------------------------------------------------------------------------


def test_the_bounding_box_is_x_y_width_height():
    assert bounding_box(MASK) == (10, 8, 12, 8)
    one = np.zeros((5, 7), bool)
    one[4, 6] = True
    assert bounding_box(one) == (6, 4, 1, 1)
    scattered = np.zeros((20, 20), bool)
    scattered[[2, 17], [15, 3]] = True
    assert bounding_box(scattered) == (3, 2, 13, 16)
    assert bounding_box(np.zeros((4, 4), bool)) == (0, 0, 0, 0)


# --- assign_excitations -------------------------------------------------------------------------------


def _labels() -> np.ndarray:
    """Two objects on a 100 x 200 frame: 1 at rows 10-39, columns 10-59; 2 at rows 50-89, columns 120-179."""
    labels = np.zeros((100, 200), np.uint16)
    labels[10:40, 10:60] = 1
    labels[50:90, 120:180] = 2
    return labels


def _step(**where) -> Excitation:
    return Excitation(kind="step_release", value=5.0, **where)


@pytest.mark.parametrize(
    ("where", "label"),
    [
        ({}, 1),  # the main object
        ({"object_id": 2}, 2),
        ({"point_px": (150.0, 70.0)}, 2),
        ({"point_px": (62.0, 20.0)}, 1),  # just outside object 1, within 5 % of the diagonal
        ({"box_px": (100.0, 40.0, 90.0, 60.0)}, 2),
        ({"box_px": (0.0, 0.0, 65.0, 95.0)}, 1),
    ],
)
def test_an_excitation_applies_to_the_object_it_names(where, label):
    exc = _step(**where)
    assert assign_excitations([exc], _labels(), 2) == {label: exc}


def test_two_excitations_apply_to_two_objects():
    first, second = _step(object_id=1), _step(point_px=(130.0, 60.0))
    assert assign_excitations([first, second], _labels(), 2) == {1: first, 2: second}


@pytest.mark.parametrize(
    ("excitations", "message"),
    [
        ([_step(point_px=(250.0, 20.0))], "outside the 200x100 frame"),
        ([_step(point_px=(100.0, 95.0))], "matches no object"),
        ([_step(object_id=3)], "2 object(s) were found"),
        ([_step(box_px=(0.0, 92.0, 50.0, 8.0))], "matches no object"),
        ([_step(object_id=2), _step(point_px=(150.0, 70.0))], "two excitations apply to object 2"),
    ],
)
def test_an_excitation_that_names_no_object_or_one_twice_is_an_error(excitations, message):
    with pytest.raises(ParameterError) as caught:
        assign_excitations(excitations, _labels(), 2)
    assert message in str(caught.value)


def test_with_no_object_an_excitation_applies_to_nothing():
    assert assign_excitations([_step(object_id=1)], np.zeros((100, 200), np.uint16), 0) == {}
