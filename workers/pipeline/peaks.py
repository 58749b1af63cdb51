"""Peaks of spectra: position to a fraction of a bin, prominence and height above a noise floor, width,
and the harmonics and folded-back overtones that belong to a stronger peak rather than to an object of
their own; :func:`detect_peaks` runs the detectors a :class:`PeakPolicy` names (the thresholds of the
window and of the survey are part of the detection policy, :mod:`workers.pipeline.detection`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Peak:
    """A spectral peak.

    Attributes
    ----------
    frequency_hz : float
        Interpolated peak position.
    bin : int
        Index of the maximum bin.
    power : float
        Peak power.
    prominence_db : float
        Height above the key saddle (topographic prominence), dB.
    snr_db : float
        Height above the background's noise spectrum, dB (inf when no noise spectrum was given).
    harmonics_hz : list of float
        Integer multiples of this peak found in the spectrum (not separate objects).
    """

    frequency_hz: float
    bin: int
    power: float
    prominence_db: float
    snr_db: float = float("inf")
    harmonics_hz: list[float] = field(default_factory=list)
    width_bins: float = 1.0
    """Half of the peak's full width at half power, in bins."""


@dataclass(frozen=True)
class PeakPolicy:
    """How peaks of a motion spectrum are found: the detectors and their thresholds.

    Up to three detectors look at one spectrum: the *summed* spectrum against static background finds
    strong motion, however damped; the *whitened* spectrum (each pixel against its own noise) finds weak,
    sub-pixel vibration spread over many pixels; the *median pixel* (a survey only) finds a vibration of
    most of the picture (a compressor shaking everything near it) that a stronger peak beside it hides in
    the sums. The first detector's peaks keep the harmonics they folded; the others' are folded in as
    found, up to ``max_order`` (with many peaks about, a higher multiple matches a weak object's frequency
    by chance; the segmentation and :func:`judge_objects` recognise a real overtone by the pixels it
    shares).

    Attributes
    ----------
    strong_min_snr_db : float
        A peak of the summed spectrum stands this far above the background's.
    weak_min_snr_db : float
        A peak of the whitened (and median) spectrum stands this far above its running median.
    weak_floor_bins, weak_floor_fraction : int
        That running median spans ``max(weak_floor_bins, F // weak_floor_fraction)`` bins.
    median_pixel : bool
        Run the median-pixel detector.
    min_separation_bins : float
        Peaks closer than this (in bins) are one.
    max_order : int
        Highest harmonic order folded in.
    min_bins : float
        Peaks below this many bins (unresolved from the mean and slow drift) are dropped.
    peaks_per_object : int
        Candidates kept per object sought (peaks that give no region drop out in the segmentation).
    """

    strong_min_snr_db: float
    weak_min_snr_db: float
    weak_floor_bins: int
    weak_floor_fraction: int
    median_pixel: bool
    min_separation_bins: float
    max_order: int
    min_bins: float
    peaks_per_object: int


def interpolate_peak(power: NDArray[np.floating[Any]], k: int) -> float:
    """Sub-bin peak offset by a parabola through the log power of bins k-1, k, k+1.

    Returns
    -------
    float
        Fractional bin index of the peak.
    """
    if k <= 0 or k >= len(power) - 1:
        return float(k)
    a, b, c = (math.log(max(float(x), 1e-30)) for x in power[k - 1 : k + 2])
    denom = a - 2 * b + c
    if denom >= 0:
        return float(k)
    return k + 0.5 * (a - c) / denom


def noise_floor(power: NDArray[np.floating[Any]], *, width: int = 9) -> NDArray[np.float64]:
    """Running median of a spectrum: the floor against which peaks are judged.

    Parameters
    ----------
    power : ndarray, shape (F,)
    width : int
        Median window in bins (odd).

    Returns
    -------
    ndarray of float64, shape (F,)
    """
    width = max(3, width | 1)
    values = np.asarray(power, np.float64)
    padded = np.pad(values, width // 2, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, width)
    return np.asarray(np.median(windows, axis=1), np.float64)


@dataclass(frozen=True)
class PeakSpectra:
    """The spectra of one motion that :func:`detect_peaks`'s detectors look at.

    Attributes
    ----------
    frequencies_hz : ndarray of float64, shape (F,)
    bin_hz : float
        Spectral resolution.
    summed : ndarray of float64, shape (F,)
        Power summed over pixels.
    background : ndarray of float64, shape (F,)
        What ``summed`` would be over static background.
    whitened : ndarray of float64, shape (F,)
        Mean over pixels of each pixel's power over its own noise.
    median_snr : ndarray of float64, shape (F,), optional
        The median pixel's power over its noise (for ``PeakPolicy.median_pixel``).
    """

    frequencies_hz: NDArray[np.float64]
    bin_hz: float
    summed: NDArray[np.float64]
    background: NDArray[np.float64]
    whitened: NDArray[np.float64]
    median_snr: NDArray[np.float64] | None = None


def detect_peaks(
    spectra: PeakSpectra,
    *,
    band_hz: tuple[float, float],
    max_objects: int = 8,
    policy: PeakPolicy,
) -> list[Peak]:
    """Peaks of a motion spectrum that may be objects, strongest first, harmonics folded in.

    Parameters
    ----------
    spectra : PeakSpectra
        The summed, background, whitened (and median pixel's) spectra and their resolution.
    band_hz : (float, float)
        Band searched.
    max_objects : int
        Objects sought (``policy.peaks_per_object`` candidates each, at most 8 per detector when 1).
    policy : PeakPolicy
        The detectors and thresholds (:data:`workers.pipeline.detection.WINDOW_PEAKS` or
        :data:`~workers.pipeline.detection.SURVEY_PEAKS`).
    """
    cap = policy.peaks_per_object * max_objects
    freqs, bin_hz, median_snr = spectra.frequencies_hz, spectra.bin_hz, spectra.median_snr

    def floor(power: NDArray[np.float64]) -> NDArray[np.float64]:
        return noise_floor(power, width=max(policy.weak_floor_bins, len(power) // policy.weak_floor_fraction))

    def found(power: NDArray[np.float64], noise: NDArray[np.float64], min_snr_db: float) -> list[Peak]:
        criteria = PeakCriteria(min_snr_db=min_snr_db)
        return find_peaks(freqs, power, band_hz=band_hz, noise=noise, criteria=criteria, max_peaks=cap)

    strong = found(spectra.summed, spectra.background, policy.strong_min_snr_db)
    others = found(spectra.whitened, floor(spectra.whitened), policy.weak_min_snr_db)
    if policy.median_pixel and median_snr is not None:
        others += found(median_snr, np.maximum(floor(median_snr), 1.0), policy.weak_min_snr_db)
    candidates = [*strong, *(Peak(**{**vars(p), "harmonics_hz": []}) for p in others)]
    candidates = [p for p in candidates if p.frequency_hz >= policy.min_bins * bin_hz]
    return fold_harmonics(
        candidates,
        bin_hz=bin_hz,
        max_peaks=cap,
        min_separation_bins=policy.min_separation_bins,
        max_order=policy.max_order,
    )


def topographic_prominence(power: NDArray[np.float64], k: int) -> float:
    """Ratio of a peak to its key saddle: the higher of the lowest points between it and the nearest
    higher sample on each side (or the end of the array).

    Parameters
    ----------
    power : ndarray of float64, shape (F,)
    k : int
        Index of a local maximum.

    Returns
    -------
    float
        power[k] / saddle (>= 1).
    """
    height = power[k]
    left = power[:k][::-1]
    higher = np.flatnonzero(left > height)
    left_min = (
        float(left[: higher[0]].min())
        if higher.size and higher[0] > 0
        else (float(left.min()) if left.size and not higher.size else height)
    )
    right = power[k + 1 :]
    higher = np.flatnonzero(right > height)
    right_min = (
        float(right[: higher[0]].min())
        if higher.size and higher[0] > 0
        else (float(right.min()) if right.size and not higher.size else height)
    )
    saddle = max(left_min, right_min, 1e-30)
    return float(height / saddle)


def _half_width(power: NDArray[np.float64], k: int) -> float:
    """Half of the full width at half maximum of the peak at ``k``, in bins (linear interpolation)."""
    half = power[k] / 2
    left = k
    while left > 0 and power[left - 1] > half:
        left -= 1
    right = k
    while right < len(power) - 1 and power[right + 1] > half:
        right += 1
    lo = left - ((power[left] - half) / max(power[left] - power[left - 1], 1e-30) if left > 0 else 0.0)
    hi = right + (
        (power[right] - half) / max(power[right] - power[right + 1], 1e-30) if right < len(power) - 1 else 0.0
    )
    return float(max(hi - lo, 1.0) / 2)


@dataclass(frozen=True)
class PeakCriteria:
    """What makes a local maximum of a spectrum a peak of its own (:func:`find_peaks`).

    Attributes
    ----------
    min_prominence_db : float
        Height above the key saddle inside the band (topographic prominence), dB.
    min_snr_db : float
        Height above the noise spectrum, when one is given, dB.
    resolved_snr_db, resolved_prominence_db : float
        A peak that stands ``resolved_snr_db`` above the noise needs only ``resolved_prominence_db`` of
        prominence (two oscillations a few lines apart share a high saddle).
    harmonic_tolerance : float
        Relative error within which (or one bin) a peak at an integer multiple of a stronger peak is that
        peak's harmonic.
    """

    min_prominence_db: float = 6.0
    min_snr_db: float = 10.0
    resolved_snr_db: float = 20.0
    resolved_prominence_db: float = 3.0
    harmonic_tolerance: float = 0.04


def find_peaks(
    frequencies_hz: NDArray[np.float64],
    power: NDArray[np.floating[Any]],
    *,
    band_hz: tuple[float, float],
    noise: NDArray[np.floating[Any]] | None = None,
    criteria: PeakCriteria = PeakCriteria(),
    max_peaks: int = 8,
) -> list[Peak]:
    """Peaks of a summed spectrum inside ``band_hz``, strongest first, harmonics folded in.

    A peak must stand ``criteria.min_prominence_db`` above its key saddle inside the band (topographic
    prominence: a broad, heavily damped peak on a sloping background still counts, a wiggle on a
    plateau does not) and ``criteria.min_snr_db`` above the ``noise`` spectrum when one is given (the
    spectrum a frame of static background would sum to). Two oscillations a few lines apart share a
    high saddle: a peak that stands ``criteria.resolved_snr_db`` above the noise needs only
    ``criteria.resolved_prominence_db`` of prominence. A peak at an integer multiple (2, 3, ...) of a
    stronger peak, within ``criteria.harmonic_tolerance`` relative error (or one bin), is recorded as
    that peak's harmonic instead of a peak of its own.

    Parameters
    ----------
    frequencies_hz : ndarray of float64, shape (F,)
    power : ndarray, shape (F,)
    band_hz : (low, high)
    noise : ndarray, shape (F,), optional
    criteria : PeakCriteria
    max_peaks : int

    Returns
    -------
    list of Peak
    """
    values: NDArray[np.float64] = np.asarray(power, np.float64)
    bin_hz = float(frequencies_hz[1] - frequencies_hz[0]) if len(frequencies_hz) > 1 else 1.0
    lo, hi = band_hz
    inside = (frequencies_hz >= lo) & (frequencies_hz <= hi)
    band = np.flatnonzero(inside)
    if band.size < 3:
        return []
    # A peak must lie in the band, but it is judged with its neighbours outside it (one bin each side):
    # a vibration in the band's last line is a peak when the line beyond it is lower.
    first, last = max(int(band[0]) - 1, 0), min(int(band[-1]) + 1, len(values) - 1)
    sub = values[first : last + 1]
    padded = np.concatenate(([-np.inf], sub, [-np.inf]))
    local = np.flatnonzero((padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:]))
    candidates: list[Peak] = []
    for j in local:
        k = first + int(j)
        if not inside[k]:
            continue
        peak = _judged_peak(values, k, window=(first, last), noise=noise, criteria=criteria, bin_hz=bin_hz)
        if peak is not None:
            candidates.append(peak)
    candidates.sort(key=lambda p: -p.power)
    return fold_harmonics(
        candidates, bin_hz=bin_hz, max_peaks=max_peaks, harmonic_tolerance=criteria.harmonic_tolerance
    )


def _judged_peak(
    power: NDArray[np.float64],
    k: int,
    *,
    window: tuple[int, int],
    noise: NDArray[np.floating[Any]] | None,
    criteria: PeakCriteria,
    bin_hz: float,
) -> Peak | None:
    """The peak at the local maximum ``k`` of ``power``, or None when it fails ``criteria``.

    Parameters
    ----------
    power : ndarray of float64, shape (F,)
    k : int
        Index of a local maximum.
    window : (int, int)
        First and last bin (inclusive) its prominence is judged in: the band and a bin each side.
    noise : ndarray, shape (F,), optional
    criteria : PeakCriteria
    bin_hz : float

    Returns
    -------
    Peak or None
    """
    if not power[k] > 0:  # a flat, motionless spectrum has no peaks
        return None
    first, last = window
    prom = 10 * math.log10(topographic_prominence(np.asarray(power[first : last + 1], np.float64), k - first))
    snr = float("inf")
    if noise is not None:
        snr = 10 * math.log10(power[k] / max(float(noise[k]), 1e-30))
        if snr < criteria.min_snr_db:
            return None
    if prom < criteria.min_prominence_db and not (
        prom >= criteria.resolved_prominence_db and snr >= criteria.resolved_snr_db
    ):
        return None
    return Peak(
        frequency_hz=interpolate_peak(power, k) * bin_hz,
        bin=k,
        power=float(power[k]),
        prominence_db=prom,
        snr_db=snr,
        width_bins=_half_width(power, k),
    )


def fold_harmonics(
    candidates: list[Peak],
    *,
    bin_hz: float,
    max_peaks: int = 8,
    harmonic_tolerance: float = 0.04,
    min_separation_bins: float = 1.5,
    max_order: int = 1_000_000,
) -> list[Peak]:
    """Keep peaks in the given order (strongest first), folding integer multiples of a kept peak into
    its ``harmonics_hz`` and dropping repeats of a kept peak (within its width or
    ``min_separation_bins``).

    Parameters
    ----------
    candidates : list of Peak
    bin_hz : float
    max_peaks : int
    harmonic_tolerance : float
    min_separation_bins : float
    max_order : int
        Highest multiple folded as a harmonic.

    Returns
    -------
    list of Peak
    """
    kept: list[Peak] = []
    for peak in candidates:
        if any(
            abs(peak.frequency_hz - base.frequency_hz) <= max(min_separation_bins, base.width_bins) * bin_hz
            for base in kept
        ):
            continue
        parent = None
        for base in kept:
            ratio = peak.frequency_hz / base.frequency_hz
            order = round(ratio)
            if 2 <= order <= max_order and abs(peak.frequency_hz - order * base.frequency_hz) <= max(
                harmonic_tolerance * peak.frequency_hz, 1.01 * bin_hz
            ):
                parent = base
                break
        if parent is not None:
            if all(abs(h - peak.frequency_hz) > bin_hz for h in parent.harmonics_hz):
                parent.harmonics_hz.append(peak.frequency_hz)
        elif len(kept) < max_peaks:
            kept.append(peak)
    for peak in kept:
        peak.harmonics_hz.sort()
    return kept


def fold_aliased_harmonics(
    peaks: list[Peak], *, sample_rate_hz: float, bin_hz: float, tolerance: float = 0.01, max_order: int = 5
) -> list[Peak]:
    """Fold peaks that are overtones of a stronger peak seen through aliasing into that peak.

    An overtone n f above the Nyquist rate shows at |n f - m fps|, which is no integer multiple of f, so
    a harmonic test on the spectrum alone keeps it as a peak of its own. Each peak (strongest first) that
    lies within ``tolerance`` (relative, or one bin) of such a folded overtone of an earlier peak is
    appended to that peak's ``harmonics_hz`` instead.

    Parameters
    ----------
    peaks : list of Peak
        Strongest first.
    sample_rate_hz : float
        Sampling rate of the spectra, Hz.
    bin_hz : float
    tolerance : float
    max_order : int
        Highest overtone considered.

    Returns
    -------
    list of Peak
        The peaks kept, in order (copies where harmonics were added).
    """
    kept: list[Peak] = []
    for peak in peaks:
        f = peak.frequency_hz
        parent = None
        for i, base in enumerate(kept):
            for order in range(2, max_order + 1):
                multiple = order * base.frequency_hz
                image = folded(multiple, sample_rate_hz)
                if image != multiple and abs(f - image) <= max(tolerance * f, 1.01 * bin_hz):
                    parent = i
                    break
            if parent is not None:
                break
        if parent is None:
            kept.append(peak)
        else:
            base = kept[parent]
            kept[parent] = dataclasses.replace(base, harmonics_hz=sorted([*base.harmonics_hz, f]))
    return kept


def folded(frequency_hz: float, sample_rate_hz: float) -> float:
    """Where a frequency shows in samples taken at ``sample_rate_hz``: folded back below the Nyquist rate,
    |f - m fs| for the nearest whole m (the frequency itself below it)."""
    return abs(frequency_hz - sample_rate_hz * round(frequency_hz / sample_rate_hz))


def explained(
    frequency_hz: float, peaks: list[Peak], *, bin_hz: float, tolerance: float, sample_rate_hz: float
) -> bool:
    """Whether a frequency is one of ``peaks``, one of their harmonics, or an integer multiple of one,
    possibly folded back below the Nyquist rate (an overtone above fps / 2 shows at |n f - m fps|)."""
    for peak in peaks:
        for f in (peak.frequency_hz, *peak.harmonics_hz):
            if abs(frequency_hz - f) <= max(1.5, peak.width_bins) * bin_hz:
                return True
        slack = max(tolerance * frequency_hz, 1.01 * bin_hz)
        for order in range(2, 33):
            if abs(frequency_hz - folded(order * peak.frequency_hz, sample_rate_hz)) <= slack:
                return True
    return False


def nanmedian_over_time(stack: NDArray[np.floating]) -> NDArray[np.floating]:
    """``np.nanmedian(stack, axis=0)`` (NaN where a pixel has no valid value), five times faster: the
    frames of each pixel are sorted (NaNs last) along a contiguous axis and the middle valid ones taken
    (averaged in double precision, returned in the stack's own).

    Parameters
    ----------
    stack : ndarray of float32 or float64, shape (T, ...)

    Returns
    -------
    ndarray of the stack's dtype, shape (...)
    """
    t = stack.shape[0]
    rows = np.sort(np.ascontiguousarray(stack.reshape(t, -1).T), axis=1)
    valid = np.count_nonzero(~np.isnan(rows), axis=1)
    lo = np.maximum(valid - 1, 0) // 2
    hi = valid // 2
    pick = np.arange(rows.shape[0])
    with np.errstate(invalid="ignore"):
        median = (rows[pick, lo].astype(np.float64) + rows[pick, np.minimum(hi, t - 1)]) / 2
    median[valid == 0] = np.nan
    return np.asarray(median, stack.dtype).reshape(stack.shape[1:])


__all__ = [
    "Peak",
    "PeakCriteria",
    "PeakPolicy",
    "PeakSpectra",
    "detect_peaks",
    "explained",
    "find_peaks",
    "fold_aliased_harmonics",
    "fold_harmonics",
    "folded",
    "interpolate_peak",
    "nanmedian_over_time",
    "noise_floor",
    "topographic_prominence",
]
