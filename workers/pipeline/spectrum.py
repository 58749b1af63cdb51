"""Spectra of motion: per-pixel power spectra of signed flow, the summed spectrum, peaks and harmonics,
and a parametric ring-down fit that measures frequency and damping far below one FFT bin.

Signed flow is transformed, never its magnitude: |v| of an oscillation rings at twice its frequency.
Per-pixel power is |U|² + |V|² (both flow components), so parts moving in anti-phase add up instead of
cancelling.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray


@functools.cache
def _fftw() -> Any:
    """``pyfftw`` with its builders, imported on first use, or None where pyfftw is missing (numpy is only
    a fallback for exotic platforms).

    Importing pyfftw also loads its ``interfaces`` package, which imports scipy.fftpack and so scipy.fft
    when scipy is installed: 0.2 to 0.4 s of CPU in every analysis, for interfaces this project does not
    use. scipy.fftpack is marked absent for the length of the import (pyfftw then skips those
    interfaces) unless something has loaded it already; nothing else in an analysis imports it.
    """
    import sys

    hide = "scipy.fftpack" not in sys.modules
    if hide:
        sys.modules["scipy.fftpack"] = None  # type: ignore[assignment]
    try:
        import pyfftw.builders
    except ImportError:  # pragma: no cover
        return None
    finally:
        if hide and sys.modules.get("scipy.fftpack", False) is None:
            del sys.modules["scipy.fftpack"]
    return pyfftw


def warm_up() -> None:
    """Import what the spectra need, so a thread can do it while frames are still being decoded."""
    _fftw()


class RfftPlans:
    """Per-pixel power spectra by FFTW, with plans built once per shape and reused.

    Flow arrives frame by frame, so it is stored frame-major (N, P): cheap to write, but a transform
    along axis 0 strides through memory and runs ~10x slower than along a contiguous axis. Pixels are
    therefore processed in blocks of ``block`` columns: each block is transposed into an aligned,
    time-contiguous (block, nfft) buffer that fits in cache, transformed along its last axis, and its
    power written back. Blocks are split between ``threads`` workers, each with its own plan and buffer.
    """

    def __init__(self, *, threads: int = 2, block: int = 2048) -> None:
        self.threads = max(1, threads)
        self.block = block
        self._plans: dict[tuple[int, int], list[tuple[Any, NDArray[np.float32]]]] = {}

    def _workers(self, nfft: int) -> list[tuple[Any, NDArray[np.float32]]]:
        key = (nfft, self.block)
        plans = self._plans.get(key)
        if plans is None:
            plans = []
            pyfftw = _fftw()
            for _ in range(self.threads):
                buf = pyfftw.empty_aligned((self.block, nfft), dtype="float32")
                plan = pyfftw.builders.rfft(
                    buf, axis=1, threads=1, planner_effort="FFTW_ESTIMATE", avoid_copy=True
                )
                plans.append((plan, buf))
            self._plans[key] = plans
        return plans

    def power(
        self,
        data: NDArray[np.float32],
        *,
        nfft: int,
        pairs: int = 2,
        summary: BandSummary | None = None,
    ) -> NDArray[np.float32]:
        """Mean-removed power spectra of every column, summed over groups of ``pairs`` adjacent columns.

        Parameters
        ----------
        data : ndarray of float32, shape (N, C)
            Time along axis 0; C = P * pairs columns (e.g. interleaved u, v flow of P pixels).
        nfft : int
            Transform length (>= N; zero-padded).
        pairs : int
            Columns summed into one spectrum (2 for the two flow components of a pixel).
        summary : BandSummary, optional
            Also write each spectrum's median, maximum and the maximum's position over the summary's
            bins into its arrays, taken per block while the block's spectra lie contiguous in cache (a
            separate pass would first transpose all of them).

        Returns
        -------
        ndarray of float32, shape (nfft // 2 + 1, C // pairs)
        """
        n, cols = data.shape
        if cols % pairs:
            raise ValueError(f"{cols} columns do not split into groups of {pairs}")
        n_freq = nfft // 2 + 1
        out = np.empty((n_freq, cols // pairs), np.float32)
        if _fftw() is None:  # pragma: no cover
            centred = data - data.mean(axis=0)
            spec = np.abs(np.fft.rfft(centred, n=nfft, axis=0)) ** 2
            summed: NDArray[np.float32] = spec.reshape(n_freq, -1, pairs).sum(axis=2).astype(np.float32)
            if summary is not None:
                summary.fill(np.ascontiguousarray(summed[summary.bins].T), 0)
            return summed
        block = self.block - self.block % pairs
        starts = list(range(0, cols, block))
        workers = self._workers(nfft)

        def run(worker: int) -> None:
            plan, buf = workers[worker]
            for c in starts[worker :: len(workers)]:
                w = min(block, cols - c)
                buf[:w, :n] = data[:, c : c + w].T
                buf[:w, n:] = 0.0
                buf[:w, :n] -= buf[:w, :n].mean(axis=1, keepdims=True)
                spec = plan()
                pw = spec.real[:w] ** 2 + spec.imag[:w] ** 2
                per_pixel = pw.reshape(w // pairs, pairs, n_freq).sum(axis=1)
                out[:, c // pairs : (c + w) // pairs] = per_pixel.T
                if summary is not None:
                    summary.fill(np.ascontiguousarray(per_pixel[:, summary.bins]), c // pairs)

        if len(workers) == 1 or len(starts) == 1:
            run(0)
        else:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=len(workers), thread_name_prefix="fft") as pool:
                list(pool.map(run, range(len(workers))))
        return out


@functools.lru_cache(maxsize=4)
def shared_plans(threads: int = 2) -> RfftPlans:
    """A process-wide plan cache, created on first use (not at import)."""
    return RfftPlans(threads=threads)


def background_spectrum(spectra: PixelSpectra, *, percentile: float = 20.0) -> NDArray[np.float64]:
    """What the summed spectrum would be if every pixel were static background.

    The ``percentile``-th pixel's power at each frequency, times the pixel count: robust while moving
    objects cover less than ``100 - percentile`` % of the frame.

    Returns
    -------
    ndarray of float64, shape (F,)
    """
    n_pix = spectra.power.shape[1]
    step = max(1, n_pix // 20_000)
    level: NDArray[np.float64] = np.percentile(spectra.power[:, ::step], percentile, axis=1).astype(
        np.float64
    )
    return level * float(n_pix)


def whitened_spectrum(
    spectra: PixelSpectra, *, band_hz: tuple[float, float]
) -> tuple[NDArray[np.float64], float]:
    """Sum over pixels of each pixel's spectrum divided by its own median power in the band.

    A summed spectrum is dominated by whichever pixels move most (occlusion edges, compression noise);
    a weak vibration spread over many pixels, each a few dB above its own noise, is lost in it. After
    whitening every pixel votes with its own signal-to-noise ratio, so such a tone rises clearly above
    a flat floor (about 1.44 per pixel: the mean over the median of exponential noise power).

    Returns
    -------
    whitened : ndarray of float64, shape (F,)
    floor : float
        The value static noise would give at every frequency.
    """
    median = spectra.band_median(band_hz)
    scale = np.where(median > 0, 1.0 / np.maximum(median, 1e-30), 0.0).astype(np.float32)
    whitened = (spectra.power @ scale).astype(np.float64)
    active = int(np.count_nonzero(scale))
    return whitened, float(active / math.log(2))


@functools.cache
def fast_length(n: int) -> int:
    """Smallest length >= n whose FFT is fast (a product of 2, 3 and 5, as ``scipy.fft.next_fast_len``
    gives for real transforms): a prime n is many times slower."""
    if n < 1:
        raise ValueError(f"an FFT length must be positive, not {n}")
    m = n
    while True:
        rest = m
        for p in (2, 3, 5):
            while rest % p == 0:
                rest //= p
        if rest == 1:
            return m
        m += 1


@dataclass(frozen=True)
class PixelSpectra:
    """Per-pixel power spectra of a flow buffer.

    Attributes
    ----------
    frequencies_hz : ndarray of float64, shape (F,)
    power : ndarray of float32, shape (F, P)
        |U|² + |V|² per frequency and pixel (P = h * w on the flow grid).
    fps : float
    n : int
        Transform length (flow samples, zero-padded to a fast length).
    """

    frequencies_hz: NDArray[np.float64]
    power: NDArray[np.float32]
    fps: float
    n: int

    @property
    def bin_hz(self) -> float:
        return self.fps / self.n

    def band_median(self, band_hz: tuple[float, float]) -> NDArray[np.float32]:
        """Each pixel's median power over the bins of ``band_hz`` (its own noise level), computed once.

        Returns
        -------
        ndarray of float32, shape (P,)
        """
        return self.band_summary(band_hz).median

    def band_summary(self, band_hz: tuple[float, float]) -> BandSummary:
        """Each pixel's median and maximum power over the bins of ``band_hz`` (see :func:`median_bins`),
        computed once (along with the transforms when :func:`pixel_spectra` was given the band)."""
        cache: dict[tuple[float, float], BandSummary] = self.__dict__.setdefault("_summaries", {})
        if band_hz not in cache:
            bins = median_bins(self.frequencies_hz, band_hz)
            summary = BandSummary.empty(bins, self.power.shape[1])
            summary.fill(np.ascontiguousarray(self.power[bins].T), 0)
            cache[band_hz] = summary
        return cache[band_hz]


@dataclass(frozen=True)
class BandSummary:
    """Per-pixel summaries of the power in a band's bins, filled block by block by :meth:`RfftPlans.power`.

    Attributes
    ----------
    bins : slice
        The band's bins.
    median, peak : ndarray of float32, shape (P,)
        Median and maximum power over the bins.
    argmax : ndarray of int64, shape (P,)
        Position of the maximum, counted from ``bins.start``.
    """

    bins: slice
    median: NDArray[np.float32]
    peak: NDArray[np.float32]
    argmax: NDArray[np.int64]

    @classmethod
    def empty(cls, bins: slice, pixels: int) -> BandSummary:
        return cls(
            bins=bins,
            median=np.empty(pixels, np.float32),
            peak=np.empty(pixels, np.float32),
            argmax=np.empty(pixels, np.int64),
        )

    def fill(self, rows: NDArray[np.float32], first: int) -> None:
        """Summarise ``rows`` (pixels ``first, first + 1, ...``; the band's bins along axis 1)."""
        end = first + len(rows)
        self.median[first:end] = median_rows(rows)
        k = np.argmax(rows, axis=1)
        self.argmax[first:end] = k
        self.peak[first:end] = np.take_along_axis(rows, k[:, None], axis=1)[:, 0]


def median_bins(frequencies_hz: NDArray[np.float64], band_hz: tuple[float, float]) -> slice:
    """The bins a pixel's noise level is the median of: those of ``band_hz``, or every bin above zero
    when the band holds fewer than three."""
    inside = np.flatnonzero((frequencies_hz >= band_hz[0]) & (frequencies_hz <= band_hz[1]))
    if len(inside) < 3:
        return slice(1, len(frequencies_hz)) if frequencies_hz[0] <= 0 else slice(0, len(frequencies_hz))
    return slice(int(inside[0]), int(inside[-1]) + 1)


def median_rows(rows: NDArray[np.float32]) -> NDArray[np.float32]:
    """``np.median(rows, axis=1)``, about four times faster: one partition along the contiguous axis
    (numpy's median partitions for both middle elements), the lower middle taken as the maximum below it.

    Parameters
    ----------
    rows : ndarray of float32, shape (P, B), C-contiguous, B >= 1

    Returns
    -------
    ndarray of float32, shape (P,)
    """
    b = rows.shape[1]
    k = b // 2
    parted = np.partition(rows, k, axis=1)
    upper = parted[:, k]
    if b % 2:
        return np.asarray(upper, np.float32)
    lower = parted[:, :k].max(axis=1)
    return np.asarray((lower.astype(np.float64) + upper) / 2, np.float32)


def pixel_spectra(
    flow: NDArray[np.float32],
    *,
    fps: float,
    plans: RfftPlans | None = None,
    band_hz: tuple[float, float] | None = None,
) -> PixelSpectra:
    """Per-pixel power spectra of signed flow, mean removed.

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
        Flow maps in time order.
    fps : float
        Sampling rate of the flow maps, Hz.
    plans : RfftPlans, optional
        FFT plan cache; the process-wide one by default.
    band_hz : (float, float), optional
        The analysis band: each pixel's median power in it (:meth:`PixelSpectra.band_median`) is then
        computed along with the transforms, at a fraction of the cost of a later pass.

    Returns
    -------
    PixelSpectra
    """
    n = flow.shape[0]
    flat = flow.reshape(n, -1)
    nfft = fast_length(n)
    freqs = np.fft.rfftfreq(nfft, d=1.0 / fps).astype(np.float64)
    summary = None
    if band_hz is not None:
        summary = BandSummary.empty(median_bins(freqs, band_hz), flat.shape[1] // 2)
    power = (plans or shared_plans()).power(flat, nfft=nfft, pairs=2, summary=summary)
    spectra = PixelSpectra(frequencies_hz=freqs, power=power, fps=fps, n=nfft)
    if band_hz is not None and summary is not None:
        spectra.__dict__.setdefault("_summaries", {})[band_hz] = summary
    return spectra


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


def find_peaks(
    frequencies_hz: NDArray[np.float64],
    power: NDArray[np.floating[Any]],
    *,
    band_hz: tuple[float, float],
    noise: NDArray[np.floating[Any]] | None = None,
    min_prominence_db: float = 6.0,
    min_snr_db: float = 10.0,
    max_peaks: int = 8,
    harmonic_tolerance: float = 0.04,
) -> list[Peak]:
    """Peaks of a summed spectrum inside ``band_hz``, strongest first, harmonics folded in.

    A peak must stand ``min_prominence_db`` above its key saddle inside the band (topographic
    prominence: a broad, heavily damped peak on a sloping background still counts, a wiggle on a
    plateau does not) and ``min_snr_db`` above the ``noise`` spectrum when one is given (the spectrum
    a frame of static background would sum to). A peak at an integer multiple (2, 3, ...) of a stronger
    peak, within ``harmonic_tolerance`` relative error (or one bin), is recorded as that peak's harmonic
    instead of a peak of its own.

    Parameters
    ----------
    frequencies_hz : ndarray of float64, shape (F,)
    power : ndarray, shape (F,)
    band_hz : (low, high)
    noise : ndarray, shape (F,), optional
    min_prominence_db, min_snr_db : float
    max_peaks : int
    harmonic_tolerance : float

    Returns
    -------
    list of Peak
    """
    values: NDArray[np.float64] = np.asarray(power, np.float64)
    power = values
    bin_hz = float(frequencies_hz[1] - frequencies_hz[0]) if len(frequencies_hz) > 1 else 1.0
    lo, hi = band_hz
    band = np.flatnonzero((frequencies_hz >= lo) & (frequencies_hz <= hi))
    if band.size < 3:
        return []
    sub = power[band]
    padded = np.concatenate(([-np.inf], sub, [-np.inf]))
    local = np.flatnonzero((padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:]))
    candidates: list[Peak] = []
    for j in local:
        k = int(band[j])
        prom = 10 * math.log10(topographic_prominence(np.asarray(sub, np.float64), int(j)))
        if prom < min_prominence_db:
            continue
        snr = float("inf")
        if noise is not None:
            snr = 10 * math.log10(power[k] / max(float(noise[k]), 1e-30))
            if snr < min_snr_db:
                continue
        fk = interpolate_peak(power, k) * bin_hz
        candidates.append(
            Peak(
                frequency_hz=fk,
                bin=k,
                power=float(power[k]),
                prominence_db=prom,
                snr_db=snr,
                width_bins=_half_width(values, k),
            )
        )
    candidates.sort(key=lambda p: -p.power)
    return fold_harmonics(
        candidates, bin_hz=bin_hz, max_peaks=max_peaks, harmonic_tolerance=harmonic_tolerance
    )


def fold_harmonics(
    candidates: list[Peak], *, bin_hz: float, max_peaks: int = 8, harmonic_tolerance: float = 0.04
) -> list[Peak]:
    """Keep peaks in the given order (strongest first), folding integer multiples of a kept peak into
    its ``harmonics_hz`` and dropping repeats of a kept peak (within its width or a bin and a half).

    Parameters
    ----------
    candidates : list of Peak
    bin_hz : float
    max_peaks : int
    harmonic_tolerance : float

    Returns
    -------
    list of Peak
    """
    kept: list[Peak] = []
    for peak in candidates:
        if any(
            abs(peak.frequency_hz - base.frequency_hz) <= max(1.5, base.width_bins) * bin_hz for base in kept
        ):
            continue
        parent = None
        for base in kept:
            ratio = peak.frequency_hz / base.frequency_hz
            order = round(ratio)
            if order >= 2 and abs(peak.frequency_hz - order * base.frequency_hz) <= max(
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


@dataclass(frozen=True)
class RingdownFit:
    """A damped oscillation fitted to a velocity signal.

    The displacement model is x(t) = C + A exp(-σ t) cos(ω_d t + φ) for t >= 0 (t from the first sample of
    the fit), and the signal is its per-frame difference v_k = x_{k+1} - x_k, as optical flow measures.

    Attributes
    ----------
    frequency_hz : float
        Damped frequency f_d = ω_d / 2π.
    natural_frequency_hz : float
        Undamped f_n = sqrt(ω_d² + σ²) / 2π.
    damping_ratio : float
        ζ = σ / ω_n.
    amplitude : float
        A, in the signal's units integrated (pixels for flow in pixels/frame).
    phase_rad : float
        φ at the first sample.
    decay_per_s : float
        σ.
    start_index : int
        First sample of the fitted window.
    frequency_sd_hz, damping_sd, amplitude_sd : float
        Standard uncertainties from the fit's Jacobian and residual variance.
    residual_rms : float
    snr_db : float
        Signal power over residual power, dB.
    """

    frequency_hz: float
    natural_frequency_hz: float
    damping_ratio: float
    amplitude: float
    phase_rad: float
    decay_per_s: float
    start_index: int
    frequency_sd_hz: float
    damping_sd: float
    amplitude_sd: float
    residual_rms: float
    snr_db: float

    def displacement(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Model displacement (without the constant offset) at times ``t_s`` from the fit start."""
        w = 2 * math.pi * self.frequency_hz
        return np.asarray(self.amplitude * np.exp(-self.decay_per_s * t_s) * np.cos(w * t_s + self.phase_rad))


def _basis(omega: float, sigma: float, k: NDArray[np.float64]) -> NDArray[np.float64]:
    """Columns: per-interval differences of e^{-σk}cos(ωk) and e^{-σk}sin(ωk) at frame positions k
    (N + 1 values, in periods of the nominal rate from the fit start), and a constant drift per period."""
    env = np.exp(-sigma * k)
    c = env * np.cos(omega * k)
    s = env * np.sin(omega * k)
    return np.stack([np.diff(c), np.diff(s), np.diff(k)], axis=1)


def _profile(
    params: NDArray[np.float64], v: NDArray[np.float64], k: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    omega, sigma = float(params[0]), float(params[1])
    basis = _basis(omega, sigma, k)
    coef, *_ = np.linalg.lstsq(basis, v, rcond=None)
    return v - basis @ coef, np.asarray(coef, np.float64)


def _spectral_guess(v: NDArray[np.float64], f_guess_cycles: float | None) -> float:
    """Angular frequency (rad/sample) of the strongest peak, zero-padded x16, parabolic refinement."""
    n = len(v)
    nfft = 1 << math.ceil(math.log2(max(16 * n, 64)))
    spec = np.abs(np.fft.rfft(v - v.mean(), n=nfft)) ** 2
    if f_guess_cycles is not None:
        centre = f_guess_cycles * nfft
        lo = max(1, int(centre - 1.5 * nfft / n))
        hi = min(len(spec) - 1, int(centre + 1.5 * nfft / n) + 1)
    else:
        lo, hi = max(1, nfft // n), len(spec) - 1
    k = lo + int(np.argmax(spec[lo:hi]))
    return 2 * math.pi * interpolate_peak(spec, k) / nfft


@dataclass(frozen=True)
class _Solution:
    x: NDArray[np.float64]
    cost: float  # half the sum of squared residuals
    jac: NDArray[np.float64]  # (M, n) at x


def _jacobian(
    fun: Any, x: NDArray[np.float64], r: NDArray[np.float64], upper: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Forward differences, stepping away from the upper bound."""
    jac = np.empty((len(r), len(x)))
    for i in range(len(x)):
        h = math.sqrt(np.finfo(np.float64).eps) * max(1.0, abs(float(x[i])))
        if x[i] + h > upper[i]:
            h = -h
        step = x.copy()
        step[i] += h
        jac[:, i] = (fun(step) - r) / h
    return jac


def _least_squares(
    fun: Any,
    x0: NDArray[np.float64],
    *,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    max_iterations: int = 200,
    tolerance: float = 1e-10,
) -> _Solution:
    """Levenberg-Marquardt for a few bounded parameters (steps are clipped into the box).

    A small problem does not need scipy.optimize, whose import costs a third of a second of every run.
    The damping is scaled by the diagonal of JᵀJ, so parameters of different size need no scaling.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> residuals``, ndarray of float64, shape (M,).
    x0 : ndarray of float64, shape (n,)

    Returns
    -------
    _Solution
        Minimiser, its cost (half the squared residual norm) and the Jacobian there.
    """
    x = np.clip(np.asarray(x0, np.float64), lower, upper)
    r = fun(x)
    cost = 0.5 * float(r @ r)
    jac = _jacobian(fun, x, r, upper)
    damping = 1e-3
    for _ in range(max_iterations):
        gradient = jac.T @ r
        normal = jac.T @ jac
        scale = np.maximum(np.diag(normal), 1e-30)
        improved = False
        while damping < 1e12:
            try:
                delta = np.linalg.solve(normal + damping * np.diag(scale), -gradient)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            x_new = np.clip(x + delta, lower, upper)
            r_new = fun(x_new)
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                improved = True
                break
            damping *= 10
        if not improved:
            break
        moved = np.abs(x_new - x)
        reduction = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        jac = _jacobian(fun, x, r, upper)
        damping = max(damping / 10, 1e-12)
        if reduction <= tolerance * cost or np.all(moved <= tolerance * (np.abs(x) + tolerance)):
            break
    return _Solution(x=x, cost=cost, jac=jac)


def fit_ringdown(
    velocity: NDArray[np.floating[Any]],
    *,
    fps: float,
    frequency_guess_hz: float | None = None,
    start_index: int = 0,
    frame_times_s: NDArray[np.float64] | None = None,
) -> RingdownFit:
    """Fit a damped oscillation to a per-frame velocity signal.

    Variable projection: the two nonlinear parameters (ω, σ) are optimised by least squares while the
    amplitude, phase and a constant velocity offset are solved linearly at each step.

    Parameters
    ----------
    velocity : ndarray, shape (N,)
        Per-frame displacement differences (e.g. the flow of the object projected on its motion axis).
    fps : float
    frequency_guess_hz : float, optional
        Start value (e.g. the summed spectrum's peak); found from the signal's own spectrum otherwise.
    start_index : int
        Samples before this are ignored (still frames before release).
    frame_times_s : ndarray of float64, shape (N + 1,), optional
        Capture times of the frames that bound the samples (sample k spans frames k and k + 1). With
        dropped frames or jitter the model is evaluated at these true times, so gaps do not bias the fit;
        uniform at ``fps`` when omitted.

    Returns
    -------
    RingdownFit
    """
    v = np.asarray(velocity, np.float64)[start_index:]
    n = len(v)
    if frame_times_s is None:
        k_pos = np.arange(n + 1, dtype=np.float64)
    else:
        times = np.asarray(frame_times_s, np.float64)
        k_pos = (times[start_index : start_index + n + 1] - times[start_index]) * fps
    if n < 6:
        from workers.pipeline.errors import AnalysisError

        raise AnalysisError(f"only {n} moving frames after release; record at least 16 frames of motion")
    guess = None if frequency_guess_hz is None else frequency_guess_hz / fps
    omega0 = _spectral_guess(v, guess)
    # Decay start value: from the envelope of the signal's two halves.
    half = n // 2
    e1 = np.sqrt(np.mean(v[:half] ** 2)) + 1e-12
    e2 = np.sqrt(np.mean(v[half:] ** 2)) + 1e-12
    sigma0 = max(1e-4, math.log(e1 / e2) / max(half, 1)) if e1 > e2 else 1e-3

    def residual(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return _profile(p, v, k_pos)[0]

    best = None
    for s0 in (sigma0, sigma0 * 0.3, sigma0 * 3):
        sol = _least_squares(
            residual,
            np.array([omega0, min(max(s0, 1e-5), 0.5)]),
            lower=np.array([1e-4, 0.0]),
            upper=np.array([math.pi, 1.0]),
        )
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    omega, sigma = float(best.x[0]), float(best.x[1])
    res, coef = _profile(best.x, v, k_pos)
    a_c, a_s = float(coef[0]), float(coef[1])
    amplitude = math.hypot(a_c, a_s)
    phase = math.atan2(-a_s, a_c)
    dof = max(n - 5, 1)
    # Residuals of real flow are not white: neighbouring samples share errors. Inflate the variance by
    # the effective-sample-size factor (1 + ρ) / (1 - ρ) of the lag-1 autocorrelation ρ.
    rho = float(res[1:] @ res[:-1]) / max(float(res @ res), 1e-30) if n > 2 else 0.0
    rho = min(max(rho, 0.0), 0.9)
    s2 = float(res @ res) / dof * (1 + rho) / (1 - rho)
    jac = best.jac
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2
        omega_sd, sigma_sd = (math.sqrt(max(float(x), 0.0)) for x in np.diag(cov))
    except np.linalg.LinAlgError:
        omega_sd, sigma_sd = float("nan"), float("nan")
    basis = _basis(omega, sigma, k_pos)
    try:
        cov_lin = np.linalg.inv(basis.T @ basis) * s2
        amp_sd = math.sqrt(max(float(cov_lin[0, 0] + cov_lin[1, 1]) / 2, 0.0))
    except np.linalg.LinAlgError:
        amp_sd = float("nan")
    wn = math.hypot(omega, sigma)
    zeta = sigma / wn
    zeta_sd = sigma_sd / wn
    signal_power = float(np.mean((v - res - coef[2] * np.diff(k_pos)) ** 2))
    snr_db = 10 * math.log10(max(signal_power, 1e-30) / max(s2, 1e-30))
    return RingdownFit(
        frequency_hz=omega * fps / (2 * math.pi),
        natural_frequency_hz=wn * fps / (2 * math.pi),
        damping_ratio=zeta,
        amplitude=amplitude,
        phase_rad=phase,
        decay_per_s=sigma * fps,
        start_index=start_index,
        frequency_sd_hz=omega_sd * fps / (2 * math.pi),
        damping_sd=zeta_sd,
        amplitude_sd=amp_sd,
        residual_rms=math.sqrt(s2),
        snr_db=snr_db,
    )


@dataclass(frozen=True)
class Ringdown:
    """How an object's oscillation evolves over the clip, from sliding windows.

    Attributes
    ----------
    times_s : ndarray of float64, shape (W,)
        Window centres, seconds from the analysed window's first frame.
    amplitude : ndarray of float64, shape (W,)
        Displacement amplitude at the object's frequency in each window (signal units integrated).
    frequency_hz : ndarray of float64, shape (W,)
        Strongest frequency in each window (zero-padded, interpolated).
    spectrogram_hz : ndarray of float64, shape (F,)
    spectrogram_power : ndarray of float64, shape (W, F)
        Power of the velocity in each window.
    """

    times_s: NDArray[np.float64]
    amplitude: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]
    spectrogram_hz: NDArray[np.float64]
    spectrogram_power: NDArray[np.float64]


def sliding_ringdown(
    velocity: NDArray[np.floating[Any]],
    *,
    fps: float,
    frequency_hz: float,
    window: int | None = None,
) -> Ringdown:
    """Ring-down analysis over sliding windows (a short-time spectrum of the object's motion).

    Parameters
    ----------
    velocity : ndarray, shape (N,)
        Per-frame displacement of the object.
    fps : float
    frequency_hz : float
        The object's frequency; each window's amplitude is measured there.
    window : int, optional
        Window length in samples; default: four periods, at least 8 and at most N / 2.

    Returns
    -------
    Ringdown
    """
    v = np.asarray(velocity, np.float64)
    n = len(v)
    period = fps / max(frequency_hz, 1e-9)
    length = window or round(4 * period)
    length = int(min(max(length, 8), max(n // 2, 8), n))
    hop = max(1, length // 4)
    starts = np.arange(0, n - length + 1, hop)
    taper = np.hanning(length + 2)[1:-1]
    nfft = max(64, 1 << math.ceil(math.log2(4 * length)))
    freqs = np.fft.rfftfreq(nfft, d=1.0 / fps)
    omega = 2 * math.pi * frequency_hz / fps
    k = np.arange(length)
    probe = np.exp(-1j * omega * k) * taper
    gain = 2 * math.sin(omega / 2)  # per-frame difference of a unit sine
    norm = float(taper.sum()) / 2
    power = np.empty((len(starts), len(freqs)))
    amp = np.empty(len(starts))
    freq = np.empty(len(starts))
    for i, s in enumerate(starts):
        seg = v[s : s + length] - v[s : s + length].mean()
        spec = np.abs(np.fft.rfft(seg * taper, n=nfft)) ** 2
        power[i] = spec
        kk = int(np.argmax(spec[1:])) + 1
        freq[i] = interpolate_peak(spec, kk) * fps / nfft
        amp[i] = abs(complex(seg @ probe)) / norm / max(gain, 1e-9)
    times = (starts + length / 2) / fps
    return Ringdown(
        times_s=times.astype(np.float64),
        amplitude=amp,
        frequency_hz=freq,
        spectrogram_hz=freqs.astype(np.float64),
        spectrogram_power=power,
    )
