"""Which spectral peaks are objects, and why the others are not.

A peak of the motion spectra becomes an object when a region of the picture moves at it; it is dropped
when it is a property of the whole picture (lighting flicker, codec keyframes, camera shake) or when the
region's motion does not ring down coherently. Every drop is reported with its reason.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.model import Excitation, ObjectMeasurement, QualityNote, RejectedPeak
from workers.pipeline.peaks import Peak, find_peaks, fold_harmonics, noise_floor
from workers.pipeline.segmentation import Segmentation, band_mask
from workers.pipeline.spectra import PixelSpectra, background_spectrum, whitened_spectrum

#: A region whose motion fits a damped oscillation this poorly (dB) is not an object.
MIN_RINGDOWN_SNR_DB = 3.0


def candidate_peaks(
    spectra: PixelSpectra, *, band_hz: tuple[float, float], max_peaks: int
) -> tuple[list[Peak], NDArray[np.float64], NDArray[np.float64]]:
    """Peaks of the window's spectra that may be objects, strongest first, harmonics folded in.

    Two detectors: the summed spectrum against static background finds strong motion, however damped;
    the whitened spectrum finds weak, sub-pixel vibration spread over many pixels.

    Returns
    -------
    peaks : list of Peak
    summed : ndarray of float64, shape (F,)
        The spectrum summed over pixels.
    noise : ndarray of float64, shape (F,)
        What the summed spectrum would be over static background.
    """
    summed = spectra.power.sum(axis=1, dtype=np.float64)
    noise = background_spectrum(spectra)
    strong = find_peaks(spectra.frequencies_hz, summed, band_hz=band_hz, noise=noise, max_peaks=max_peaks)
    whitened, _ = whitened_spectrum(spectra, band_hz=band_hz)
    weak = find_peaks(
        spectra.frequencies_hz,
        whitened,
        band_hz=band_hz,
        noise=noise_floor(whitened, width=max(15, len(whitened) // 6)),
        min_snr_db=3.0,
        max_peaks=max_peaks,
    )
    peaks = fold_harmonics(
        [*strong, *(Peak(**{**vars(p), "harmonics_hz": []}) for p in weak)],
        bin_hz=spectra.bin_hz,
        max_peaks=max_peaks,
    )
    return peaks, summed, noise


def reject_artefacts(
    seg: Segmentation,
    spectra: PixelSpectra,
    *,
    band_hz: tuple[float, float],
    background_snr: float = 2.5,
    relative_snr: float = 0.05,
    max_area_fraction: float = 0.5,
) -> tuple[Segmentation, list[RejectedPeak]]:
    """Drop peaks that are a property of the whole picture rather than of an object.

    Lighting flicker, codec keyframes and residual camera shake move (or seem to move) the static
    background too: a peak whose band stands ``background_snr`` above the pixels' own noise over the
    median background pixel, and there at least ``relative_snr`` of its strength over its own region
    (an object's motion leaks faintly into the background through flow smoothing; an artefact is as
    strong there as anywhere), or whose region covers more than ``max_area_fraction`` of the frame, is
    reported and removed; the remaining objects are relabelled 1, 2, ...

    Returns
    -------
    Segmentation
    list of RejectedPeak
    """
    if not seg.peaks:
        return seg, []
    freqs = spectra.frequencies_hz
    pixel_noise = spectra.band_median(band_hz) + np.float32(1e-20)
    background = (seg.labels == 0).ravel()
    h, w = seg.labels.shape
    keep: list[int] = []
    rejected: list[RejectedPeak] = []
    for i, peak in enumerate(seg.peaks):
        sel = band_mask(freqs, peak, bin_hz=spectra.bin_hz, band_bins=max(1.5, peak.width_bins))
        bins = max(int(sel.sum()), 1)
        area = float((seg.labels == i + 1).sum()) / (h * w)
        snr_bg = snr_obj = float("nan")
        region = (seg.labels == i + 1).ravel()
        if background.sum() >= 16 and region.any():
            bp = seg.band_power[i].ravel()
            snr = bp / (pixel_noise * bins)
            snr_bg = float(np.median(snr[background]))
            snr_obj = float(np.median(snr[region]))
        if area > max_area_fraction:
            rejected.append(
                RejectedPeak(
                    peak.frequency_hz,
                    f"{peak.frequency_hz:.4g} Hz moves {area * 100:.0f} % of the picture: camera motion or "
                    "a global effect, not an object",
                )
            )
        elif snr_bg > background_snr and snr_bg > relative_snr * snr_obj:
            rejected.append(
                RejectedPeak(
                    peak.frequency_hz,
                    f"{peak.frequency_hz:.4g} Hz is present over the static background as well "
                    f"({10 * np.log10(snr_bg):.1f} dB above its noise): lighting flicker, codec keyframes "
                    "or camera shake, not an object",
                )
            )
        else:
            keep.append(i)
    if len(keep) == len(seg.peaks):
        return seg, rejected
    labels = np.zeros_like(seg.labels)
    for new, old in enumerate(keep, start=1):
        labels[seg.labels == old + 1] = new
    return (
        Segmentation(
            labels=labels,
            peaks=[seg.peaks[i] for i in keep],
            band_power=seg.band_power[keep],
            noise_power=seg.noise_power[keep],
        ),
        rejected,
    )


def drop_incoherent(
    objects: list[ObjectMeasurement],
    labels: NDArray[np.uint16],
    quality: list[QualityNote],
    excited: dict[int, Excitation],
) -> tuple[list[ObjectMeasurement], NDArray[np.uint16], list[ObjectMeasurement]]:
    """Remove regions whose motion does not ring down coherently (fit SNR below ``MIN_RINGDOWN_SNR_DB``)
    unless the user named them in an excitation; renumber the rest 1, 2, ... in objects and labels.
    Returns the kept objects, their labels and the removed objects."""
    kept = [o for o in objects if (o.snr_db or 0.0) >= MIN_RINGDOWN_SNR_DB or o.id in excited]
    dropped = [o for o in objects if o not in kept]
    for o in dropped:
        quality.append(
            QualityNote(
                "artefact_peak",
                f"{o.eigenfrequency_hz:.4g} Hz: the region's motion does not ring down coherently "
                f"({(o.snr_db or 0.0):.1f} dB); not reported as an object",
                "info",
            )
        )
    if not dropped:
        return objects, labels, dropped
    relabelled = np.zeros_like(labels)
    for new_id, o in enumerate(kept, start=1):
        relabelled[labels == o.id] = new_id
        o.id = new_id
    return kept, relabelled, dropped


__all__ = ["MIN_RINGDOWN_SNR_DB", "RejectedPeak", "candidate_peaks", "drop_incoherent", "reject_artefacts"]
