"""Segmentation helpers on synthetic per-pixel spectra with known truth: weak motion confined to a region
(found by the local scan although no whole-picture spectrum shows it), and overtones folded back below
the Nyquist rate."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.pipeline.peaks import Peak, PeakCriteria, find_peaks, fold_aliased_harmonics, noise_floor
from workers.pipeline.segmentation import local_peaks
from workers.pipeline.spectra import PixelSpectra, whitened_spectrum

FPS, N = 30.0, 128
H, W = 120, 160
BAND = (1.5 * FPS / N, 0.98 * FPS / 2)


def _spectra(*, seed, region_snr, k0=40, box=(50, 60, 30, 30)):
    """Noise whose power is correlated over a few pixels (as dense flow's is) and varies from pixel to
    pixel (texture), plus power ``region_snr`` times each pixel's level at bin ``k0`` inside ``box``."""
    rng = np.random.default_rng(seed)
    n_freq = N // 2 + 1
    level = np.exp(rng.normal(0, 0.7, (H, W))).astype(np.float32)
    level = cv2.GaussianBlur(level, (0, 0), 4.0)
    power = np.empty((n_freq, H * W), np.float32)
    for k in range(n_freq):
        re = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 1.0)
        im = cv2.GaussianBlur(rng.standard_normal((H, W)).astype(np.float32), (0, 0), 1.0)
        power[k] = ((re**2 + im**2) * level).ravel()
    x, y, w, h = box
    region = np.zeros((H, W), bool)
    region[y : y + h, x : x + w] = True
    scale = float(np.median(power))
    power[k0, region.ravel()] += region_snr * scale * level[region]
    freqs = np.fft.rfftfreq(N, d=1.0 / FPS)
    return PixelSpectra(frequencies_hz=freqs, power=power, sample_rate_hz=FPS, n=N), region, float(freqs[k0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_weak_region_no_whole_picture_spectrum_shows_is_found(seed):
    spectra, region, f0 = _spectra(seed=seed, region_snr=6.0)
    # The whole-picture detector of the analysis misses it: 400 of 19 200 pixels ...
    whitened, _ = whitened_spectrum(spectra, band_hz=BAND)
    whole = find_peaks(
        spectra.frequencies_hz,
        whitened,
        band_hz=BAND,
        noise=noise_floor(whitened, width=max(15, len(whitened) // 6)),
        criteria=PeakCriteria(min_snr_db=3.0),
    )
    assert all(abs(p.frequency_hz - f0) > spectra.bin_hz for p in whole)
    # ... the neighbourhood scan finds it, at the right frequency, and nothing else.
    found = local_peaks(spectra, grid_shape=(H, W), band_hz=BAND)
    assert len(found) == 1, [p.frequency_hz for p in found]
    assert found[0].frequency_hz == pytest.approx(f0, abs=0.5 * spectra.bin_hz)
    assert found[0].snr_db > 10 * np.log10(3.0)
    # Pixels already explained do not vote; a known peak, or one it is a harmonic of, is not repeated.
    assert local_peaks(spectra, grid_shape=(H, W), band_hz=BAND, exclude=region) == []
    known = Peak(frequency_hz=f0, bin=40, power=1.0, prominence_db=10.0)
    assert local_peaks(spectra, grid_shape=(H, W), band_hz=BAND, known=[known]) == []
    half = Peak(frequency_hz=f0 / 2, bin=20, power=1.0, prominence_db=10.0)
    assert local_peaks(spectra, grid_shape=(H, W), band_hz=BAND, known=[half]) == []


def test_noise_alone_gives_no_local_peak():
    for seed in range(3):
        spectra, _, _ = _spectra(seed=10 + seed, region_snr=0.0)
        assert local_peaks(spectra, grid_shape=(H, W), band_hz=BAND) == []


def test_local_peaks_checks_the_grid():
    spectra, _, _ = _spectra(seed=0, region_snr=0.0)
    with pytest.raises(ValueError, match="grid"):
        local_peaks(spectra, grid_shape=(H, W + 1), band_hz=BAND)


def _peak(f):
    return Peak(frequency_hz=f, bin=0, power=1.0, prominence_db=10.0)


def test_overtones_folded_below_nyquist_join_their_fundamental():
    # 600 fps: 3 x 110 = 330 Hz shows at 270 Hz, 2 x 247 = 494 Hz at 106 Hz.
    kept = fold_aliased_harmonics([_peak(110.0), _peak(270.2)], sample_rate_hz=600.0, bin_hz=2.3)
    assert [p.frequency_hz for p in kept] == [110.0]
    assert kept[0].harmonics_hz == [270.2]
    kept = fold_aliased_harmonics(
        [_peak(247.0), _peak(106.1), _peak(196.0)], sample_rate_hz=600.0, bin_hz=2.3
    )
    assert [p.frequency_hz for p in kept] == [247.0, 196.0]
    assert kept[0].harmonics_hz == [106.1]
    # Two strings a fourth apart stay two objects; unfolded multiples are left to fold_harmonics.
    kept = fold_aliased_harmonics(
        [_peak(110.0), _peak(147.0), _peak(220.0)], sample_rate_hz=600.0, bin_hz=2.3
    )
    assert [p.frequency_hz for p in kept] == [110.0, 147.0, 220.0]


def test_a_thin_object_s_weak_stretch_and_sub_pixel_sweep_stay_in_its_region():
    """A string 4 px thick whose motion dips far below the rest over a stretch (little contrast against the
    background there): the stretch and the string's weak end belong to it, and no row beside it does; a
    sub-pixel amplitude does not erode it (no whole pixel was swept)."""
    from workers.pipeline.segmentation import SegmentationConfig, _bridged, at_rest

    h, w = 40, 200
    string = np.zeros((h, w), bool)
    string[18:22, 10:190] = True
    region = string.copy()
    region[:, 90:112] = False  # the weak stretch, 22 px: wider than a square closing's reach
    region[:, 170:] = False  # the weak end
    core = region.copy()
    moving = np.zeros((h, w), bool)
    moving[16:24, 5:195] = True  # above the noise at the frequency: the string and the flow's fringe
    grown = region | _bridged(region, moving, SegmentationConfig(), core=core)
    assert grown[18:22, 90:112].all()
    assert grown[18:22, 170:180].all()  # up to BRIDGE_SHARE of its length beyond its end
    assert not grown[16:18].any()
    assert not grown[22:24].any()
    assert (at_rest(grown, axis_px=(0.0, 1.0), amplitude_px=0.8) == grown).all()
    assert at_rest(grown, axis_px=(0.0, 1.0), amplitude_px=1.2).sum() < grown.sum()
