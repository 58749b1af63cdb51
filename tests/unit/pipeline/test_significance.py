"""The scan statistic and its false-alarm probability (workers.pipeline.significance), and the
candidates taken from it (workers.pipeline.detection.find_candidates), on flow arrays with known truth:
noise alone, a weak vibration of a small patch, the same on flat pixels, a whole-picture pulse, a
harmonic and a fundamental on one patch."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.pipeline.confidence import flow_confidence
from workers.pipeline.detection import find_candidates
from workers.pipeline.significance import MAX_FALSE_ALARM, motion_scan

FPS = 60.0
N, H, W = 128, 48, 64
BAND = (2 * FPS / N, 0.98 * FPS / 2)


def _picture(seed: int = 0, flat_left: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = cv2.GaussianBlur(rng.uniform(40, 200, (H, W)).astype(np.float32), (0, 0), 1.0)
    if flat_left:
        image[:, : W // 2] = 120.0
    return image


def _noise(seed: int, *, heavy: bool = False) -> np.ndarray:
    """Flow noise, spatially smooth (as dense flow is), optionally with a codec's impulses."""
    rng = np.random.default_rng(seed)
    flow = rng.normal(0, 0.05, (N, H, W, 2)).astype(np.float32)
    flow = np.stack([cv2.GaussianBlur(f, (0, 0), 1.5) for f in flow])
    if heavy:
        jumps = rng.random(N) < 0.05
        flow[jumps] += rng.normal(0, 0.3, (int(jumps.sum()), H, W, 2)).astype(np.float32)
    return flow


def _vibrate(flow: np.ndarray, f: float, amplitude: float, region: tuple[slice, slice], phase: float = 0.0):
    t = np.arange(N)
    flow[:, region[0], region[1], 0] += (amplitude * np.sin(2 * np.pi * f * t / FPS + phase))[:, None, None]
    return flow


def _scan(flow: np.ndarray, picture: np.ndarray, **kw):
    return motion_scan(
        flow, flow_confidence(picture, frame_noise=1.0), sample_rate_hz=FPS, band_hz=BAND, **kw
    )


def test_noise_alone_is_rarely_significant_and_the_rate_is_not_above_the_stated_one():
    """40 windows of noise (half with impulses): the most significant peak of each, as a false-alarm
    probability per clip, is at most alpha in no more than about alpha of them (a conservative law)."""
    best = []
    for seed in range(40):
        scan = _scan(_noise(seed, heavy=seed % 2 == 1), _picture(seed))
        best.append(float(scan.calibration.p_clip(scan.z.max())))
    best_arr = np.asarray(best)
    assert (best_arr <= MAX_FALSE_ALARM).sum() == 0
    for alpha in (0.1, 0.3):
        assert float(np.mean(best_arr <= alpha)) <= alpha + 0.1, (alpha, np.sort(best_arr)[:8])


def test_a_long_windows_band_transformed_in_groups_gives_the_same_statistic(monkeypatch):
    """A window whose band's spectra exceed SPECTRA_BUDGET_MIB is transformed in groups of frequencies
    (memory flat in the window's length): the statistic is the one of a single pass, exactly."""
    from workers.pipeline import significance

    flow = _vibrate(_noise(7), 9.0, 0.04, (slice(20, 28), slice(30, 34)))
    whole = _scan(flow, _picture(7))
    per_bin_mib = H * W * 2 * 8 / 2**20
    monkeypatch.setattr(significance, "_CHUNK", 8)
    monkeypatch.setattr(significance, "SPECTRA_BUDGET_MIB", 20.5 * per_bin_mib)  # groups of 16 bins
    assert len(whole.frequencies_hz) > 3 * 16
    grouped = _scan(flow, _picture(7))
    np.testing.assert_array_equal(grouped.statistic, whole.statistic)
    np.testing.assert_array_equal(grouped.z, whole.z)


def test_the_law_is_fitted_on_each_tiles_largest_block_power(monkeypatch):
    """The tiles the law is fitted on: at each frequency, the largest normalised power of the counted
    blocks (every shape) whose centre lies in the tile, as a plain loop over the tiles gives it; and the
    statistic is the largest of all."""
    from workers.pipeline import significance

    fitted = {}
    fit = significance.fit_calibration

    def spy(statistic, **kw):
        fitted["tiles"] = kw["tiles"]
        return fit(statistic, **kw)

    monkeypatch.setattr(significance, "fit_calibration", spy)
    flow = _vibrate(_noise(5), 9.0, 0.04, (slice(20, 28), slice(30, 34)))
    scan = _scan(flow, _picture(5, flat_left=True))
    tiles = significance.TILES
    expected = np.zeros((tiles * tiles, len(scan.frequencies_hz)))
    largest = np.zeros(len(scan.frequencies_hz))
    for level in scan._levels:
        if not level.positions.size:
            continue
        cy, cx = np.divmod(significance._centres(level, (H, W)), W)
        tile_of = (cy * tiles // H) * tiles + cx * tiles // W
        power = level.power(slice(None))
        largest = np.maximum(largest, power.max(axis=1))
        for t in range(tiles * tiles):
            if (tile_of == t).any():
                expected[t] = np.maximum(expected[t], power[:, tile_of == t].max(axis=1))
    assert (~expected.any(axis=1)).sum() >= 1  # the flat half's tiles hold no block
    np.testing.assert_array_equal(fitted["tiles"], expected[expected.any(axis=1)])
    np.testing.assert_array_equal(scan.statistic, largest)


def test_a_weak_small_vibration_is_found_where_and_at_what_it_moves():
    flow = _vibrate(_noise(7), 9.0, 0.04, (slice(20, 28), slice(30, 34)))  # below the noise per sample
    scan = _scan(flow, _picture(7))
    assert scan.false_alarm(9.0) <= MAX_FALSE_ALARM
    k = int(np.argmax(scan.z))
    assert scan.frequencies_hz[k] == pytest.approx(9.0, abs=scan.bin_hz)
    region = scan.region(9.0)
    assert region[20:28, 30:34].mean() > 0.5
    assert region.sum() < 0.1 * H * W
    assert scan.localised_share(9.0, region) > 0.5


def test_motion_on_flat_pixels_is_codec_noise_and_never_an_object():
    """The same patch's flow 'vibrating' strongly on a flat part of the picture (where flow is only the
    codec's noise) stands out of nothing."""
    flow = _vibrate(_noise(8), 9.0, 0.5, (slice(20, 28), slice(6, 14)))
    scan = _scan(flow, _picture(8, flat_left=True))
    assert scan.false_alarm(9.0) > MAX_FALSE_ALARM


def test_a_pulse_of_the_whole_picture_is_not_localised():
    flow = _vibrate(_noise(9), 12.0, 0.05, (slice(0, H), slice(0, W)))
    scan = _scan(flow, _picture(9))
    assert scan.false_alarm(12.0) <= MAX_FALSE_ALARM  # something happens at 12 Hz ...
    assert scan.localised_share(12.0, scan.region(12.0)) < 0.5  # ... everywhere at once


def test_the_band_must_hold_frequencies():
    with pytest.raises(ValueError, match="band"):
        motion_scan(_noise(1)[:16], flow_confidence(_picture()), sample_rate_hz=FPS, band_hz=(20.0, 21.0))


def test_an_overtone_on_the_same_pixels_is_a_harmonic_and_two_objects_stay_two():
    patch = (slice(18, 30), slice(20, 32))
    flow = _vibrate(_noise(11), 6.0, 0.3, patch)
    flow = _vibrate(flow, 12.0, 0.15, patch, phase=0.4)  # a non-sinusoidal motion's overtone
    flow = _vibrate(flow, 17.0, 0.3, (slice(30, 40), slice(44, 56)))  # another object
    found = find_candidates(_scan(flow, _picture(11)), band_hz=BAND, max_objects=8)
    freqs = [c.peak.frequency_hz for c in found.found]
    assert len(freqs) == 2
    assert freqs[0] == pytest.approx(6.0, abs=0.3) or freqs[1] == pytest.approx(6.0, abs=0.3)
    six = next(c for c in found.found if abs(c.peak.frequency_hz - 6.0) < 0.3)
    assert any(abs(h - 12.0) < 0.5 for h in six.peak.harmonics_hz)
    assert any(abs(f - 17.0) < 0.5 for f in freqs)


def test_a_stronger_overtone_resolves_to_its_fundamental_on_the_same_pixels():
    """A wheel whose marks pass twice a turn: its second harmonic is stronger than its rate, but the
    rate moves the same pixels; the fundamental is reported, the overtone among its harmonics."""
    patch = (slice(14, 34), slice(18, 38))
    flow = _vibrate(_noise(12), 3.75, 0.06, patch)
    flow = _vibrate(flow, 7.5, 0.3, patch)
    found = find_candidates(_scan(flow, _picture(12)), band_hz=BAND, max_objects=8)
    assert len(found.found) == 1
    peak = found.found[0].peak
    assert peak.frequency_hz == pytest.approx(3.75, abs=0.3)
    assert any(abs(h - 7.5) < 0.5 for h in peak.harmonics_hz)


def test_an_object_the_user_says_was_excited_is_a_candidate_however_weak_its_line():
    """A vibration below the bound is no candidate, unless an excitation says an object was pushed: then
    the strongest line is one (where and at what it moves), with its own false-alarm probability."""
    flow = _vibrate(_noise(13), 9.0, 0.012, (slice(20, 28), slice(30, 34)))
    scan = _scan(flow, _picture(13))
    assert scan.false_alarm(9.0) > MAX_FALSE_ALARM
    assert not find_candidates(scan, band_hz=BAND, max_objects=8).found
    asserted = find_candidates(scan, band_hz=BAND, max_objects=8, asserted=1).found
    assert len(asserted) == 1
    assert asserted[0].peak.frequency_hz == pytest.approx(9.0, abs=scan.bin_hz)
    assert asserted[0].false_alarm > MAX_FALSE_ALARM
    assert len(find_candidates(scan, band_hz=BAND, max_objects=1, asserted=3).found) <= 1


def test_the_taper_is_scipys_tukey_window():
    from scipy.signal.windows import tukey as scipy_tukey

    from workers.pipeline.significance import tukey

    for n in (2, 3, 64, 255, 999):
        for alpha in (0.1, 0.5, 1.0):
            np.testing.assert_allclose(tukey(n, alpha), scipy_tukey(n, alpha), atol=1e-6)


def test_a_steady_flow_is_no_line_at_the_lowest_frequencies():
    """A pixel block that moves steadily (a turning wheel's rim, 9 px a frame) and vibrates faintly at
    3.75 Hz: the constant is no oscillation, so the lowest bins hold nothing beside the line (tapered
    with its mean, the constant became the taper's spectrum, 7 times the line two bins below it)."""
    patch = (slice(14, 34), slice(18, 38))
    flow = _noise(14)
    flow[:, patch[0], patch[1], 0] += 9.0
    flow = _vibrate(flow, 3.75, 0.3, patch)
    scan = _scan(flow, _picture(14))
    k = scan.peak_bin(3.75, half_width_bins=1.0)
    assert scan.frequencies_hz[k] == pytest.approx(3.75, abs=scan.bin_hz)
    assert scan.statistic[0] < scan.statistic[k]
    assert scan.false_alarm(3.75) <= MAX_FALSE_ALARM


def test_a_thin_edge_is_pooled_along_its_length():
    """An edge one grid pixel wide and 32 long vibrating faintly: a square block of its length holds
    mostly noise, a strip along it (:data:`~workers.pipeline.significance.STRIPS`) holds the edge alone.
    Found in every one of six noise draws (four of six with square blocks only)."""
    for seed in range(20, 26):
        flow = _vibrate(_noise(seed), 9.0, 0.015, (slice(8, 40), slice(30, 31)))
        scan = _scan(flow, _picture(seed))
        assert scan.false_alarm(9.0) <= MAX_FALSE_ALARM, seed


def test_an_object_stands_out_by_its_strongest_line_its_rate_or_an_overtone():
    """A wheel reported at its turning rate, faint, with its marks' passing (twice as fast, strong) among
    its harmonics on the same pixels, is significant by that line; reported at the faint rate alone it is
    not; and an overtone line elsewhere in the picture does not lend the object its significance."""
    from workers.pipeline.model import ObjectMeasurement
    from workers.pipeline.verdicts import significance_verdict

    patch = (slice(14, 34), slice(18, 38))
    flow = _vibrate(_noise(21), 3.75, 0.004, patch)
    flow = _vibrate(flow, 7.5, 0.3, patch)
    flow = _vibrate(flow, 11.25, 0.3, (slice(30, 44), slice(44, 60)))  # another object's line
    scan = _scan(flow, _picture(21))
    assert scan.false_alarm(3.75) > MAX_FALSE_ALARM
    region = np.zeros((H, W), bool)
    region[patch] = True

    def wheel(harmonics_hz: list[float]) -> ObjectMeasurement:
        return ObjectMeasurement(
            id=1, eigenfrequency_hz=3.75, eigenfrequency_uncertainty_hz=0.05, natural_frequency_hz=3.75,
            damping_ratio=0.0, damping_ratio_uncertainty=0.001, amplitude_px=0.3, amplitude_m=None,
            amplitude_uncertainty_m=None, depth_m=None, motion_direction=None, stiffness_n_per_m=None,
            stiffness_uncertainty_n_per_m=None, mass_kg=None, mass_uncertainty_kg=None, pixel_count=400,
            bbox_px=(18, 14, 20, 20),
            harmonics_hz=harmonics_hz, release_time_s=0.0, snr_db=10.0, detection_db=20.0,
            concentration=0.9,
        )  # fmt: skip

    with_overtone = wheel([7.5])
    assert significance_verdict(with_overtone, scan, region=region) is None
    assert with_overtone.false_alarm_probability is not None
    assert with_overtone.false_alarm_probability <= MAX_FALSE_ALARM
    alone = significance_verdict(wheel([]), scan, region=region)
    assert alone is not None
    assert alone.evidence == "not_significant"
    elsewhere = significance_verdict(wheel([11.25]), scan, region=region)
    assert elsewhere is not None
    assert elsewhere.evidence == "not_significant"


@pytest.mark.parametrize("bins", [1, 2, 3, 5, 10, 17, 64, 490])
def test_line_contrast_is_t_over_the_median_of_its_neighbours_2_to_8_bins_away(bins: int) -> None:
    from workers.pipeline.significance import CONTRAST_WIDTH_BINS, line_contrast

    rng = np.random.default_rng(bins)
    t = rng.gamma(2.0, size=bins)
    t[rng.random(bins) < 0.1] = 0.0
    log_t = np.log(np.maximum(t, 1e-30))
    expected = np.empty(bins)
    for k in range(bins):
        around = [log_t[j] for j in range(bins) if 2 <= abs(j - k) <= CONTRAST_WIDTH_BINS]
        expected[k] = np.exp(log_t[k] - (np.median(around) if around else log_t[k]))
    np.testing.assert_allclose(line_contrast(t), expected, rtol=1e-12)


def _ring(flow: np.ndarray, f: float, zeta: float, amplitude: float, start: int, region) -> np.ndarray:
    t = np.arange(N - start) / FPS
    motion = amplitude * np.exp(-zeta * 2 * np.pi * f * t) * np.sin(2 * np.pi * f * t)
    flow[start:, region[0], region[1], 0] += motion[:, None, None].astype(np.float32)
    return flow


def test_a_strongly_damped_ring_down_is_a_line_beyond_its_own_width():
    """A ring-down of damping 0.08 at 20 Hz makes a line several bins wide: its neighbours two to eight
    bins away lie inside it (contrast under LINE_CONTRAST), but beyond its width it stands out, and it is
    found."""
    from workers.pipeline.detection import LINE_CONTRAST, significant_bins

    flow = _ring(_noise(21), 20.0, 0.08, 0.6, 30, (slice(18, 30), slice(20, 32)))
    scan = _scan(flow, _picture(21))
    k = int(np.argmin(np.abs(scan.frequencies_hz - 20.0)))
    near = slice(k - 2, k + 3)
    assert scan.contrast[near].max() < LINE_CONTRAST  # the line is broad ...
    found = [scan.frequencies_hz[j] for j in significant_bins(scan)]
    assert any(abs(f - 20.0) <= 2 * scan.bin_hz for f in found), found  # ... and found


def test_a_broad_stretch_of_motion_is_no_line_however_strong():
    """Band-limited random motion over 5-15 Hz (a strong object's broadband flow errors, a codec's noise)
    lifts a whole stretch at once, speckled: no peak inside it is taken for a damped oscillation's broad
    line (its cliffs at the stretch's edges are the plain contrast's to judge)."""
    from workers.pipeline.detection import LINE_CONTRAST, significant_bins

    rng = np.random.default_rng(22)
    freqs = np.linspace(5.0, 15.0, 60)
    t = np.arange(N) / FPS
    motion = np.sin(2 * np.pi * freqs[None, :] * t[:, None] + rng.uniform(0, 2 * np.pi, 60)).sum(axis=1)
    flow = _noise(22)
    flow[:, 18:30, 20:32, 0] += (0.08 * motion)[:, None, None].astype(np.float32)
    scan = _scan(flow, _picture(22))
    inside = (scan.frequencies_hz > 6.0) & (scan.frequencies_hz < 14.0)
    assert scan.calibration.p_clip(scan.z[inside].max()) <= MAX_FALSE_ALARM  # it stands out ...
    broad = [scan.frequencies_hz[j] for j in significant_bins(scan) if scan.contrast[j] < LINE_CONTRAST]
    assert not [f for f in broad if 6.0 < f < 14.0], broad  # ... as no broad line


def test_a_mask_on_part_of_where_the_line_was_found_is_judged_over_where_it_was_found():
    """Issue 25: a thin bar's mask held the part of its edge that moves the most; its line stood out over
    the whole edge (where the scan found it) but not over the mask's few grid pixels, and the bar was
    rejected as not significant on its own pixels. A mask lying where its line was found is judged over
    that region; a mask elsewhere is still judged over itself alone."""
    from workers.pipeline.model import ObjectMeasurement
    from workers.pipeline.verdicts import Footing, significance_verdict

    edge = (slice(8, 40), slice(30, 31))
    scan = _scan(_vibrate(_noise(22), 9.0, 0.01, edge), _picture(22))
    assert scan.false_alarm(9.0) <= MAX_FALSE_ALARM  # p 2e-4 over the picture (0.11 over the mask alone)
    found = np.zeros((H, W), bool)
    found[edge] = True
    part = np.zeros((H, W), np.float32)
    part[20:22, 30] = 1.0  # two of the edge's 32 grid pixels
    elsewhere = np.zeros((H, W), np.float32)
    elsewhere[20:22, 50] = 1.0

    def bar() -> ObjectMeasurement:
        return ObjectMeasurement(
            id=1, eigenfrequency_hz=9.0, eigenfrequency_uncertainty_hz=0.05, natural_frequency_hz=9.0,
            damping_ratio=0.0, damping_ratio_uncertainty=0.001, amplitude_px=0.01, amplitude_m=None,
            amplitude_uncertainty_m=None, depth_m=None, motion_direction=None, stiffness_n_per_m=None,
            stiffness_uncertainty_n_per_m=None, mass_kg=None, mass_uncertainty_kg=None, pixel_count=8,
            bbox_px=(30, 20, 1, 2), harmonics_hz=[], release_time_s=0.0, snr_db=10.0, detection_db=20.0,
            concentration=0.9,
        )  # fmt: skip

    assert significance_verdict(bar(), scan, region=part > 0) is not None  # the mask alone: too few pixels
    on_edge = Footing(found=found, held=part)
    assert on_edge.own_pixels().sum() == found.sum()
    assert significance_verdict(bar(), scan, region=on_edge.own_pixels()) is None
    off_edge = Footing(found=found, held=elsewhere)
    assert np.array_equal(off_edge.own_pixels(), elsewhere > 0)
    rejected = significance_verdict(bar(), scan, region=off_edge.own_pixels())
    assert rejected is not None
    assert rejected.evidence == "not_significant"
