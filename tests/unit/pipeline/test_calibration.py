"""The law of the scan statistic under noise (workers.pipeline.calibration): artefact lines left out of
the fit, a short band's slow course followed by a parabola, and no course fitted when too few frequencies
are left beside an object."""

from __future__ import annotations

import numpy as np
import pytest

from workers.pipeline.calibration import fit_calibration
from workers.pipeline.significance import MAX_FALSE_ALARM


def test_known_artefact_lines_are_left_out_of_the_fit():
    """A comb of strong lines (a codec's keyframes) inflates the fitted spread unless it is left out."""
    rng = np.random.default_rng(3)
    freqs = np.linspace(1, 29, 120)
    statistic = np.exp(rng.gumbel(2.0, 0.2, 120))
    comb = [2.5 * m for m in range(1, 12)]
    for f in comb:
        statistic[np.argmin(np.abs(freqs - f))] *= 8.0
    polluted = fit_calibration(statistic, frequencies_hz=freqs, rounds=1)
    clean = fit_calibration(statistic, frequencies_hz=freqs, exclude_hz=comb, rounds=1)
    assert clean.scale < polluted.scale
    assert clean.scale == pytest.approx(0.2, rel=0.35)


def _short_band(rng: np.random.Generator, bins: int = 29) -> tuple[np.ndarray, np.ndarray]:
    """The scan statistic of a short window (64 frames: 29 bins): Gumbel noise of scale 0.2 on a slow
    U-shaped course over the band (flow noise rises at both ends under H.264)."""
    x = np.linspace(-1, 1, bins)
    course = rng.uniform(0.5, 1.0) * x**2 + rng.uniform(-0.3, 0.3) * x
    return np.linspace(1, 14, bins), np.exp(course + rng.gumbel(2.0, 0.2, bins))


def test_a_short_band_follows_the_noise_s_course():
    """On a band of 24 to 29 bins the calibration follows the noise's course with a parabola: a line
    standing sixteen noise scales above its neighbourhood is significant, as on a flat course (the
    course alone spreads log T over several scales)."""
    rng = np.random.default_rng(11)
    freqs, statistic = _short_band(rng)
    flat = np.exp(rng.gumbel(2.0, 0.2, len(freqs)))
    for series in (statistic, flat):
        series[14] = np.exp(np.log(series[14]) + 16 * 0.2)
    on_course = fit_calibration(statistic, frequencies_hz=freqs)
    on_flat = fit_calibration(flat, frequencies_hz=freqs)
    assert on_course.trend is not None
    assert on_course.scale < 1.5 * on_flat.scale
    assert float(on_course.p_clip(on_course.z(statistic)[14])) <= MAX_FALSE_ALARM


def test_a_short_band_with_few_surrogates_left_fits_no_course():
    """When an object's skirt leaves fewer than MIN_TREND_SURROGATES bins to fit, a parabola beside the
    law would follow the noise itself: the law is fitted to log T as it is."""
    rng = np.random.default_rng(12)
    freqs, statistic = _short_band(rng)
    statistic[2:14] *= np.exp(np.linspace(1.0, 4.0, 12))  # a strong, broad object over 12 bins
    cal = fit_calibration(statistic, frequencies_hz=freqs)
    assert cal.bins_fitted < 20
    assert cal.trend is None
