"""The small numerical replacements that keep scipy.optimize and scipy.ndimage out of start-up, checked
against the scipy functions they replace, and the faster per-pixel median against numpy's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage, optimize

from workers.pipeline.fft import RfftPlans, median_rows
from workers.pipeline.lstsq import least_squares
from workers.pipeline.peaks import noise_floor
from workers.pipeline.segmentation import _fill_holes
from workers.pipeline.spectra import pixel_spectra


@pytest.mark.parametrize("bins", [1, 2, 3, 124, 125])
def test_median_rows_equals_numpy_median(bins):
    rows = np.random.default_rng(bins).exponential(size=(500, bins)).astype(np.float32)
    np.testing.assert_allclose(median_rows(rows), np.median(rows, axis=1), rtol=1e-6)


@pytest.mark.parametrize(
    ("band_hz", "threads"), [((0.5, 12.0), 2), ((2.0, 3.0), 1), ((14.9, 15.0), 2), ((0.0, 15.0), 2)]
)
def test_band_medians_taken_with_the_transforms_equal_those_taken_after(band_hz, threads):
    """Per-pixel band medians computed block by block inside the FFT equal the separate pass's, and
    the narrow band that holds fewer than three bins falls back to every bin above zero in both."""
    flow = np.random.default_rng(7).normal(size=(100, 37, 53, 2)).astype(np.float32)
    plans = RfftPlans(threads=threads, block=256)  # several blocks, the last one partial
    together = pixel_spectra(flow, sample_rate_hz=30.0, plans=plans, band_hz=band_hz)
    after = pixel_spectra(flow, sample_rate_hz=30.0, plans=plans)
    np.testing.assert_array_equal(together.power, after.power)
    medians = together.band_median(band_hz)
    np.testing.assert_array_equal(medians, after.band_median(band_hz))
    freqs = after.frequencies_hz
    band = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    if band.sum() < 3:
        band = freqs > 0
    np.testing.assert_allclose(medians, np.median(after.power[band], axis=0), rtol=1e-6)
    summary, direct = together.band_summary(band_hz), after.band_summary(band_hz)
    np.testing.assert_array_equal(summary.argmax, direct.argmax)
    np.testing.assert_array_equal(summary.peak, direct.peak)
    first = int(np.flatnonzero(band)[0])
    np.testing.assert_array_equal(summary.argmax + first, np.argmax(after.power[band], axis=0) + first)
    np.testing.assert_array_equal(summary.peak, after.power[band].max(axis=0))


@pytest.mark.parametrize("width", [3, 8, 9, 41])
@pytest.mark.parametrize("length", [5, 129, 513])
def test_noise_floor_equals_scipy_median_filter(width, length):
    power = np.random.default_rng(length + width).exponential(size=length)
    expected = ndimage.median_filter(power, size=max(3, width | 1), mode="nearest")
    np.testing.assert_allclose(noise_floor(power, width=width), expected)


def test_fill_holes_equals_scipy():
    rng = np.random.default_rng(0)
    for _ in range(100):
        mask = (rng.random((30, 40)) < rng.uniform(0.2, 0.8)).astype(np.uint8)
        assert np.array_equal(_fill_holes(mask).astype(bool), ndimage.binary_fill_holes(mask.astype(bool)))


def test_least_squares_matches_scipy_on_a_damped_sine():
    rng = np.random.default_rng(3)
    k = np.arange(80, dtype=np.float64)
    for _ in range(20):
        omega, sigma = rng.uniform(0.3, 2.5), rng.uniform(0.005, 0.1)
        y = np.exp(-sigma * k) * np.cos(omega * k) + rng.normal(0, 0.05, k.size)

        def residual(p, y=y):
            return np.exp(-p[1] * k) * np.cos(p[0] * k) - y

        x0 = np.array([omega * 1.02, sigma * 2])
        lower, upper = np.array([1e-4, 0.0]), np.array([math.pi, 1.0])
        ours = least_squares(residual, x0, lower=lower, upper=upper)
        ref = optimize.least_squares(residual, x0, bounds=(lower, upper))
        assert ours.cost <= ref.cost * (1 + 1e-9)
        np.testing.assert_allclose(ours.x, ref.x, rtol=1e-5, atol=1e-8)
        # Both are forward differences: they agree to their truncation error.
        np.testing.assert_allclose(ours.jac, ref.jac, rtol=1e-3, atol=1e-4)


def test_least_squares_stays_in_bounds():
    sol = least_squares(
        lambda p: np.array([p[0] + 5.0, p[1] - 3.0]),
        np.array([0.5, 0.5]),
        lower=np.array([0.0, 0.0]),
        upper=np.array([1.0, 1.0]),
    )
    np.testing.assert_allclose(sol.x, [0.0, 1.0])


@pytest.mark.parametrize("frames", [1, 2, 5, 24])
def test_nanmedian_over_time_equals_numpy(frames):
    import warnings

    from workers.pipeline.peaks import nanmedian_over_time

    rng = np.random.default_rng(frames)
    stack = rng.random((frames, 30, 40)).astype(np.float32)
    stack[rng.random(stack.shape) < 0.3] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        expected = np.nanmedian(stack, axis=0)
    np.testing.assert_allclose(nanmedian_over_time(stack), expected, rtol=1e-6, equal_nan=True)
