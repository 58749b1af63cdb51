"""Spring-mass physics: k and m from a held force or an impulse."""

from __future__ import annotations

import math

import pytest

from workers.pipeline.mechanics import stiffness_and_mass


def test_step_release_gives_k_from_force_over_amplitude_and_m_from_omega():
    k_true, m_true = 400.0, 0.25
    fn = math.sqrt(k_true / m_true) / (2 * math.pi)
    mech = stiffness_and_mass(
        kind="step_release",
        value=8.0,
        value_sd=0.0,
        amplitude_m=8.0 / k_true,
        amplitude_sd_m=0.0,
        natural_frequency_hz=fn,
        damped_frequency_hz=fn,
        frequency_sd_hz=0.0,
    )
    assert mech.stiffness_n_per_m == pytest.approx(k_true)
    assert mech.mass_kg == pytest.approx(m_true)


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
        amplitude_sd_m=amplitude * 0.02,
        natural_frequency_hz=wn / (2 * math.pi),
        damped_frequency_hz=wd / (2 * math.pi),
        frequency_sd_hz=0.0,
    )
    assert mech.mass_kg == pytest.approx(m_true)
    assert mech.stiffness_n_per_m == pytest.approx(k_true)
    assert mech.mass_sd == pytest.approx(m_true * math.hypot(0.05, 0.02))


def test_zero_amplitude_is_reported_not_divided():
    mech = stiffness_and_mass(
        kind="step_release",
        value=1.0,
        value_sd=0.0,
        amplitude_m=0.0,
        amplitude_sd_m=0.0,
        natural_frequency_hz=5.0,
        damped_frequency_hz=5.0,
        frequency_sd_hz=0.0,
    )
    assert mech.stiffness_n_per_m is None
    assert mech.null_reasons
