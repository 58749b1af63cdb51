"""Unit tests of :mod:`workers.pipeline.release_fit`: the ring-down fitted from the release."""

from __future__ import annotations

import numpy as np
import pytest

from workers.pipeline.mechanics import detect_release
from workers.pipeline.release_fit import FitHints, ReleaseFitter

RATE = 240.0
N = 255


def _fitter(guess_hz: float) -> ReleaseFitter:
    return ReleaseFitter(sample_rate_hz=RATE, hints=FitHints(guess_hz), times_s=np.arange(N + 1) / RATE)


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


def test_a_short_window_keeps_its_first_fit_however_far_the_scans_guess(monkeypatch):
    """A live stream stopped early: a 4.5 Hz ring-down released at frame 15, 80 frames at 30 fps. Over so
    few periods the scan's line is broad and its peak a poor guess (2.3 Hz was seen; 2.9 Hz here): the
    fit from the release is the estimate, and no fit is made again to agree with the guess."""
    import workers.pipeline.release_fit as release_fit

    rate, n = 30.0, 80
    t = np.arange(n)
    ring = 0.8 * np.exp(-0.03 * 2 * np.pi * 4.5 / rate * (t - 15)) * np.cos(2 * np.pi * 4.5 / rate * (t - 15))
    velocity = np.where(t >= 15, ring, 0.0) + 0.01 * np.random.default_rng(2).standard_normal(n)
    fits, fit_ringdown = [], release_fit.fit_ringdown

    def counted(*args, **kwargs):
        fits.append(kwargs["start_index"])
        return fit_ringdown(*args, **kwargs)

    monkeypatch.setattr(release_fit, "fit_ringdown", counted)
    fitter = ReleaseFitter(sample_rate_hz=rate, hints=FitHints(2.9), times_s=np.arange(n + 1) / rate)
    onset, fit = fitter(velocity)
    assert fits == [detect_release(velocity)]
    assert onset == fits[0]
    assert fit.frequency_hz == pytest.approx(4.5, abs=0.05)
