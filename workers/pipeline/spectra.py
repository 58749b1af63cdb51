"""Per-pixel power spectra of signed flow, and the spectra summed over pixels that peaks are found in.

Signed flow is transformed, never its magnitude: |v| of an oscillation rings at twice its frequency.
Per-pixel power is |U|² + |V|² (both flow components), so parts moving in anti-phase add up instead of
cancelling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.fft import BandSummary, RfftPlans, fast_length, shared_plans


@dataclass(frozen=True)
class PixelSpectra:
    """Per-pixel power spectra of a flow buffer.

    Attributes
    ----------
    frequencies_hz : ndarray of float64, shape (F,)
    power : ndarray of float32, shape (F, P)
        |U|² + |V|² per frequency and pixel (P = h * w on the flow grid).
    sample_rate_hz : float
    n : int
        Transform length (flow samples, zero-padded to a fast length).
    """

    frequencies_hz: NDArray[np.float64]
    power: NDArray[np.float32]
    sample_rate_hz: float
    n: int

    @property
    def bin_hz(self) -> float:
        return self.sample_rate_hz / self.n

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


def median_bins(frequencies_hz: NDArray[np.float64], band_hz: tuple[float, float]) -> slice:
    """The bins a pixel's noise level is the median of: those of ``band_hz``, or every bin above zero
    when the band holds fewer than three."""
    inside = np.flatnonzero((frequencies_hz >= band_hz[0]) & (frequencies_hz <= band_hz[1]))
    if len(inside) < 3:
        return slice(1, len(frequencies_hz)) if frequencies_hz[0] <= 0 else slice(0, len(frequencies_hz))
    return slice(int(inside[0]), int(inside[-1]) + 1)


def pixel_spectra(
    flow: NDArray[np.float32],
    *,
    sample_rate_hz: float,
    plans: RfftPlans | None = None,
    band_hz: tuple[float, float] | None = None,
    mix: tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]] | None = None,
) -> PixelSpectra:
    """Per-pixel power spectra of signed flow, mean removed.

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
        Flow maps in time order.
    sample_rate_hz : float
        Sampling rate of the flow maps, Hz.
    plans : RfftPlans, optional
        FFT plan cache; the process-wide one by default.
    band_hz : (float, float), optional
        The analysis band: each pixel's median power in it (:meth:`PixelSpectra.band_median`) is then
        computed along with the transforms, at a fraction of the cost of a later pass.
    mix : (a, b, c), each ndarray of float32, shape (h, w), optional
        Spectra of each pixel's flow (u, v) turned into (a u + b v, b u + c v) first, as the transforms
        go (for instance J^(1/2) u, :func:`workers.pipeline.confidence.tensor_sqrt`): no mixed copy of
        the flow is made.

    Returns
    -------
    PixelSpectra
    """
    n = flow.shape[0]
    flat = flow.reshape(n, -1)
    nfft = fast_length(n)
    freqs = np.fft.rfftfreq(nfft, d=1.0 / sample_rate_hz).astype(np.float64)
    summary = None
    if band_hz is not None:
        summary = BandSummary.empty(median_bins(freqs, band_hz), flat.shape[1] // 2)
    per_pixel = None
    if mix is not None:
        a, b, c = (np.asarray(m, np.float32).ravel() for m in mix)
        per_pixel = (a, b, c)
    power = (plans or shared_plans()).power(flat, nfft=nfft, pairs=2, summary=summary, mix=per_pixel)
    spectra = PixelSpectra(frequencies_hz=freqs, power=power, sample_rate_hz=sample_rate_hz, n=nfft)
    if band_hz is not None and summary is not None:
        spectra.__dict__.setdefault("_summaries", {})[band_hz] = summary
    return spectra


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


__all__ = [
    "PixelSpectra",
    "background_spectrum",
    "median_bins",
    "pixel_spectra",
    "whitened_spectrum",
]
