"""Frequency and damping estimators on 1-D damped sines with known truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.peaks import find_peaks, interpolate_peak
from workers.pipeline.ringdown import fit_ringdown


def damped_velocity(f_hz, zeta, fps, n, *, amplitude=5.0, phase=0.3, noise=0.0, rng=None):
    wn = 2 * math.pi * f_hz
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.arange(n + 1) / fps
    x = amplitude * np.exp(-zeta * wn * t) * np.cos(wd * t + phase)
    v = np.diff(x)
    if noise:
        v = v + (rng or np.random.default_rng(0)).normal(0, noise * np.abs(v).max(), n)
    return v, wd / (2 * math.pi)


@pytest.mark.parametrize("n", [32, 64, 128])
def test_ringdown_fit_beats_one_bin_by_far(n):
    rng = np.random.default_rng(n)
    errors = []
    for _ in range(60):
        f = rng.uniform(2, 12)
        zeta = rng.uniform(0.01, 0.1)
        v, fd = damped_velocity(f, zeta, 30.0, n, phase=rng.uniform(0, 6.28), noise=0.03, rng=rng)
        fit = fit_ringdown(v, sample_rate_hz=30.0)
        errors.append(abs(fit.frequency_hz - fd) / fd)
    errors = np.array(errors)
    bin_rel = (30.0 / n) / 7.0  # one bin relative to a mid-band frequency
    assert np.median(errors) < 0.005
    assert np.percentile(errors, 95) < 0.02
    assert np.median(errors) < bin_rel / 10


def test_ringdown_fit_measures_damping_within_20_percent():
    rng = np.random.default_rng(7)
    rel = []
    for _ in range(60):
        zeta = rng.uniform(0.01, 0.1)
        v, _ = damped_velocity(
            rng.uniform(3, 10), zeta, 30.0, 128, phase=rng.uniform(0, 6), noise=0.02, rng=rng
        )
        fit = fit_ringdown(v, sample_rate_hz=30.0)
        rel.append(abs(fit.damping_ratio - zeta) / zeta)
    assert np.percentile(rel, 90) < 0.2


def test_ringdown_fit_skips_still_samples_before_release():
    v, fd = damped_velocity(4.0, 0.03, 30.0, 80)
    signal = np.concatenate([np.zeros(20), v])
    fit = fit_ringdown(signal, sample_rate_hz=30.0, start_index=20)
    assert fit.frequency_hz == pytest.approx(fd, rel=1e-3)
    assert fit.amplitude == pytest.approx(5.0, rel=1e-2)


def test_magnitude_of_signed_oscillation_rings_at_twice_the_frequency():
    """The physics check behind the default method: |v| peaks at 2f, signed v at f."""
    fps, n, f = 30.0, 128, 3.0
    t = np.arange(n) / fps
    v = np.sin(2 * math.pi * f * t)
    freqs = np.fft.rfftfreq(n, 1 / fps)
    signed = np.abs(np.fft.rfft(v - v.mean())) ** 2
    magnitude = np.abs(np.fft.rfft(np.abs(v) - np.abs(v).mean())) ** 2
    assert freqs[np.argmax(signed)] == pytest.approx(f, abs=fps / n)
    assert freqs[np.argmax(magnitude)] == pytest.approx(2 * f, abs=fps / n)


def test_find_peaks_folds_harmonics_into_their_fundamental():
    freqs = np.linspace(0, 15, 301)
    power = np.full_like(freqs, 1.0)
    for f, p in ((3.0, 1000.0), (6.0, 80.0), (9.0, 30.0), (4.4, 400.0)):
        power += p * np.exp(-0.5 * ((freqs - f) / 0.08) ** 2)
    peaks = find_peaks(freqs, power, band_hz=(0.5, 14.0))
    assert [round(p.frequency_hz, 1) for p in peaks] == [3.0, 4.4]
    assert [round(h, 1) for h in peaks[0].harmonics_hz] == [6.0, 9.0]


def test_find_peaks_finds_a_peak_in_the_bands_last_line_and_nothing_beyond_the_band():
    """A vibration in the band's edge line (128 Hz filmed at 250 fps shows at 122 Hz, inside a band that
    ends at 0.98 of the Nyquist rate) is judged with its neighbour outside the band; a peak just outside
    the band is never reported, even when its flank reaches into the band."""
    freqs = np.arange(257) * 250.0 / 512
    power = np.full_like(freqs, 1.0)
    power[250] = 1000.0  # 122.07 Hz
    band = (1.0, 0.98 * 125.0)
    assert [round(p.frequency_hz, 1) for p in find_peaks(freqs, power, band_hz=band)] == [122.1]
    power[:] = 1.0
    power[252] = 1000.0  # 123.05 Hz: outside the band
    power[251] = 30.0  # its flank, the band's last line
    assert find_peaks(freqs, power, band_hz=band) == []


def test_interpolate_peak_recovers_gaussian_centre():
    k = np.arange(20, dtype=float)
    power = np.exp(-0.5 * ((k - 7.3) / 1.2) ** 2)
    assert interpolate_peak(power, 7) == pytest.approx(7.3, abs=1e-6)


def test_fast_length_is_scipys_next_fast_len_for_real_transforms():
    """The FFT length is chosen without importing scipy.fft (a fifth of a second of every analysis), and
    must be the same as scipy's, so spectra keep their frequency grid."""
    from scipy.fft import next_fast_len

    from workers.pipeline.fft import fast_length

    assert [fast_length(n) for n in range(1, 3000)] == [next_fast_len(n, real=True) for n in range(1, 3000)]
    with pytest.raises(ValueError, match="positive"):
        fast_length(0)


def test_a_long_transform_goes_in_smaller_blocks_with_the_same_spectra():
    """Per-pixel spectra are taken a block of columns at a time; a long window's blocks are narrower (a
    block's buffer within BLOCK_MIB, not 24 MiB a thread at 3000 frames), and the spectra the same."""
    from workers.pipeline.fft import BLOCK_MIB, RfftPlans

    plans = RfftPlans(threads=2)
    assert plans.block_for(1000) == 2048
    assert plans.block_for(3000) * 3000 * 4 <= BLOCK_MIB * 2**20
    assert plans.block_for(3000) % 2 == 0
    data = np.random.default_rng(2).normal(size=(3000, 2 * 800)).astype(np.float32)
    assert 2 * plans.block_for(3000) < 2 * 800  # three blocks, split between two threads
    power = plans.power(data, nfft=3000)
    spectra = np.fft.rfft((data - data.mean(axis=0)).astype(np.float64), axis=0)
    expected = (np.abs(spectra) ** 2).reshape(len(spectra), 800, 2).sum(axis=2)
    np.testing.assert_allclose(power, expected, rtol=1e-3, atol=1e-3 * float(expected.max()))
