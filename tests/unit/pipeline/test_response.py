"""The response between a recorded force and the measured motion (``workers.pipeline.response``): k, m and
c of one degree of freedom from the two records, with ground truth simulated independently (scipy's
``lsim`` at 10 kHz), and the data that cannot support the fit refused with the reason."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from workers.pipeline.errors import ForceError
from workers.pipeline.response import MAX_REL_SD, fit_response

K, M, ZETA = 200.0, 0.8, 0.03
C = 2 * ZETA * math.sqrt(K * M)
FN = math.sqrt(K / M) / (2 * math.pi)
FPS, RATE = 30.0, 200.0
T_FORCE = np.arange(-1.0, 10.0, 1 / RATE)
FRAMES = np.arange(0.0, 9.5, 1 / FPS)


def _motion(force: np.ndarray, rng: np.random.Generator, noise_m: float) -> np.ndarray:
    """The spring-mass's displacement at the frames, from rest at the force's first sample, with white
    measurement noise and the slow drift of a displacement integrated from flow."""
    fine = np.arange(T_FORCE[0], T_FORCE[-1], 1e-4)
    _, x, _ = signal.lsim(signal.lti([1.0], [M, C, K]), np.interp(fine, T_FORCE, force), fine - fine[0])
    return np.interp(FRAMES, fine, x) + rng.normal(0.0, noise_m, FRAMES.size) + 2e-4 * FRAMES + 0.003


def _multisine(rng: np.random.Generator) -> np.ndarray:
    freqs = np.linspace(0.5 * FN, 2.0 * FN, 12)
    phases = rng.uniform(0, 2 * math.pi, freqs.size)
    waves = 0.3 * np.cos(2 * math.pi * freqs[:, None] * T_FORCE[None, :] + phases[:, None]).sum(0)
    return np.where(T_FORCE >= 0.5, waves, 0.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_multisine_gives_k_m_and_c_within_their_uncertainty(seed: int) -> None:
    rng = np.random.default_rng(seed)
    force = _multisine(rng)
    x = _motion(force, rng, noise_m=2e-4)  # about 1 % of the motion's RMS
    fit = fit_response(T_FORCE, force + rng.normal(0, 0.03, force.size), FRAMES, x, frequency_hz=FN * 1.03)
    for value, sd, truth in [
        (fit.stiffness_n_per_m, fit.stiffness_uncertainty_n_per_m, K),
        (fit.mass_kg, fit.mass_uncertainty_kg, M),
        (fit.damping_n_s_per_m, fit.damping_uncertainty_n_s_per_m, C),
    ]:
        assert value == pytest.approx(truth, rel=0.02)
        assert abs(value - truth) < 4 * sd + 0.002 * truth  # the stated uncertainty holds
    assert fit.damping_ratio == pytest.approx(ZETA, rel=0.05)
    assert fit.natural_frequency_hz == pytest.approx(FN, rel=0.005)
    assert fit.explained > 0.95


def test_one_tone_switched_on_in_the_window_shows_the_resonance_in_its_transient() -> None:
    rng = np.random.default_rng(3)
    force = np.where(T_FORCE >= 2.0, 3.0 * np.sin(2 * math.pi * 0.85 * FN * T_FORCE), 0.0)
    fit = fit_response(T_FORCE, force, FRAMES, _motion(force, rng, 2e-4), frequency_hz=0.85 * FN)
    assert fit.stiffness_n_per_m == pytest.approx(K, rel=0.02)
    assert fit.mass_kg == pytest.approx(M, rel=0.02)


def test_one_steady_tone_does_not_determine_k_and_m() -> None:
    """The object has long settled into the tone: one point of H(ω) for three unknowns."""
    rng = np.random.default_rng(4)
    w0 = 2 * math.pi * 0.85 * FN
    h = 1 / (K - M * w0**2 + 1j * C * w0)
    force = 3.0 * np.sin(w0 * T_FORCE)
    for noise in (2e-6, 2e-4, 1e-3):
        x = 3.0 * abs(h) * np.sin(w0 * FRAMES + np.angle(h)) + rng.normal(0, noise, FRAMES.size)
        with pytest.raises(ForceError, match="do not determine stiffness and mass") as raised:
            fit_response(T_FORCE, force, FRAMES, x, frequency_hz=0.85 * FN)
        assert "sweep or a random force" in str(raised.value)
        assert f"{MAX_REL_SD:.0%}" in str(raised.value)


def test_a_force_that_did_not_move_the_object_is_refused() -> None:
    rng = np.random.default_rng(5)
    other = _multisine(np.random.default_rng(50))
    x = _motion(_multisine(rng), rng, 2e-4)
    with pytest.raises(ForceError, match=r"explains \d+ % of the object's motion"):
        fit_response(T_FORCE, other, FRAMES, x, frequency_hz=FN)


def test_records_that_barely_overlap_are_refused() -> None:
    rng = np.random.default_rng(6)
    force = _multisine(rng)
    x = _motion(force, rng, 2e-4)
    late = FRAMES + 9.0  # the frames begin when the force record ends
    with pytest.raises(ForceError, match=r"overlap for .* periods"):
        fit_response(T_FORCE, force, late, x, frequency_hz=FN)
