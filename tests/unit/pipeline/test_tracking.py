"""Unit tests of :mod:`workers.pipeline.tracking`'s ring-down fit from the release (``_Fitter``)."""

from __future__ import annotations

import numpy as np
import pytest

from workers.pipeline.mechanics import detect_release
from workers.pipeline.tracking import FitHints, _Fitter

RATE = 240.0
N = 255


def _fitter(guess_hz: float) -> _Fitter:
    return _Fitter(sample_rate_hz=RATE, hints=FitHints(guess_hz), times_s=np.arange(N + 1) / RATE)


def test_a_codec_start_up_jump_does_not_take_the_fit_off_the_objects_line():
    """A thin bar steady at 41 Hz through H.264: the codec drew it only from the fifth frame, a jump 30
    times its motion (these numbers are from such a clip), which the fit from the release followed (17 Hz,
    damping ratio 0.44). Made again a period later, the fit is on the line."""
    rng = np.random.default_rng(0)
    t = np.arange(N)
    velocity = 0.1 * np.sin(2 * np.pi * 41.0 / RATE * t) + 0.01 * rng.standard_normal(N)
    velocity[:4] = 0.01  # the same frame four times: nothing drawn yet
    velocity[4:10] += [1.56, 0.44, 0.23, -0.05, -3.13, -0.46]
    onset, fit = _fitter(41.06)(velocity)
    assert fit.frequency_hz == pytest.approx(41.0, abs=0.2)
    assert fit.damping_ratio < 0.01
    assert onset > detect_release(velocity)


def test_a_ring_down_on_its_line_is_fitted_from_its_release():
    t = np.arange(N)
    velocity = np.where(
        t >= 20, 0.5 * np.exp(-0.02 * (t - 20)) * np.cos(2 * np.pi * 12.0 / RATE * (t - 20)), 0.0
    )
    velocity += 0.002 * np.random.default_rng(1).standard_normal(N)
    onset, fit = _fitter(12.1)(velocity)
    assert onset == detect_release(velocity)
    assert fit.frequency_hz == pytest.approx(12.0, abs=0.05)
