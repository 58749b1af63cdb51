"""Segmentation by spectral signature: pixels whose motion rings at an object's frequency, well above the
noise floor, grouped into cleaned connected regions and labelled one object per fundamental frequency.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from workers.pipeline.spectrum import Peak, PixelSpectra


@dataclass(frozen=True, kw_only=True)
class SegmentationConfig:
    """Thresholds of the segmentation; the defaults work without tuning.

    Attributes
    ----------
    noise_factor : float
        A pixel's band power must exceed this multiple of the background's (the median pixel's).
    relative_level : float
        ... and this fraction of the object's typical (median) band power.
    purity : float
        ... and this fraction of the pixel's power in the whole analysis band.
    band_bins : float
        Half-width, in bins, of the band around each peak and harmonic.
    min_area_fraction : float
        Regions smaller than this fraction of the frame are dropped.
    pool_px : int
        Neighbourhood (grid pixels) over which per-pixel signal-to-noise is pooled for weak motion.
    pooled_snr : float
        Pooled band power over the pixels' own noise in that band that marks weak motion.
    """

    noise_factor: float = 8.0
    relative_level: float = 0.2
    purity: float = 0.25
    band_bins: float = 1.5
    min_area_fraction: float = 0.0015
    pool_px: int = 5
    pooled_snr: float = 4.0


@dataclass(frozen=True)
class Segmentation:
    """Labels on the flow grid.

    Attributes
    ----------
    labels : ndarray of int32, shape (h, w)
        0 background, i + 1 for ``peaks[i]``.
    peaks : list of Peak
        The fundamentals, in label order; peaks that gave no region are dropped.
    band_power : ndarray of float32, shape (len(peaks), h, w)
        Power in each object's band (fundamental + harmonics).
    noise_power : ndarray of float64, shape (len(peaks),)
        Band power of the background (median pixel).
    """

    labels: NDArray[np.int32]
    peaks: list[Peak]
    band_power: NDArray[np.float32]
    noise_power: NDArray[np.float64]


def band_mask(
    frequencies_hz: NDArray[np.float64], peak: Peak, *, bin_hz: float, band_bins: float
) -> NDArray[np.bool_]:
    """Bins within ``band_bins`` of the peak or any of its harmonics."""
    sel = np.zeros(len(frequencies_hz), bool)
    for f in (peak.frequency_hz, *peak.harmonics_hz):
        sel |= np.abs(frequencies_hz - f) <= band_bins * bin_hz
    return sel


def _clean(mask: NDArray[np.bool_], min_area: int) -> NDArray[np.bool_]:
    m = mask.astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, kernel)
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, kernel)
    filled = ndimage.binary_fill_holes(m.astype(bool))
    count, comp, stats, _ = cv2.connectedComponentsWithStats(filled.astype(np.uint8), connectivity=8)
    keep = np.zeros(count, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return np.asarray(keep[comp])


def segment(
    spectra: PixelSpectra,
    peaks: list[Peak],
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    config: SegmentationConfig | None = None,
) -> Segmentation:
    """Label the pixels of each peak's object.

    Parameters
    ----------
    spectra : PixelSpectra
        Per-pixel power, shape (F, h * w).
    peaks : list of Peak
        Fundamental peaks of the summed spectrum, strongest first.
    grid_shape : (h, w)
    band_hz : (low, high)
        Analysis band.
    config : SegmentationConfig, optional

    Returns
    -------
    Segmentation
    """
    cfg = config or SegmentationConfig()
    h, w = grid_shape
    freqs = spectra.frequencies_hz
    in_band = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    total = spectra.power[in_band].sum(axis=0) + np.float32(1e-20)
    if not peaks:
        return Segmentation(
            labels=np.zeros(grid_shape, np.int32),
            peaks=[],
            band_power=np.zeros((0, h, w), np.float32),
            noise_power=np.zeros(0),
        )
    band_power = np.empty((len(peaks), h * w), np.float32)
    band_bins = np.empty(len(peaks))
    for i, peak in enumerate(peaks):
        # A heavily damped peak is wider than a few bins: take its measured half-power width.
        width = max(cfg.band_bins, peak.width_bins)
        sel = band_mask(freqs, peak, bin_hz=spectra.bin_hz, band_bins=width)
        band_power[i] = spectra.power[sel].sum(axis=0)
        band_bins[i] = max(int(sel.sum()), 1)
    # Each pixel's own noise level (median power per bin in the band), for weak, sub-pixel motion.
    pixel_noise = spectra.band_median(band_hz) + np.float32(1e-20)
    noise = np.median(band_power, axis=1).astype(np.float64) + 1e-20
    owner = np.argmax(band_power, axis=0)
    min_area = max(4, int(cfg.min_area_fraction * h * w))
    labels = np.zeros(h * w, np.int32)
    kept: list[Peak] = []
    kept_rows: list[int] = []
    for i, peak in enumerate(peaks):
        bp = band_power[i]
        candidate = (bp > cfg.noise_factor * noise[i]) & (owner == i) & (bp > cfg.purity * total)
        region = np.zeros(h * w, bool)
        if candidate.any():
            # The object's typical level: occlusion edges carry erratic, strong flow, so a high
            # percentile would be set by them rather than by the object's interior.
            level = float(np.median(bp[candidate]))
            candidate &= bp >= cfg.relative_level * level
            region = _clean(candidate.reshape(h, w), min_area).ravel() & (labels == 0)
        if not region.any():
            # Weak (sub-pixel) motion: each pixel is only a few dB above its own noise. Pool the
            # per-pixel signal-to-noise ratio over small neighbourhoods, which move together (parts
            # in anti-phase are pooled as power, so they do not cancel), and keep what stands out.
            snr = (bp / (pixel_noise * band_bins[i])).reshape(h, w).astype(np.float32)
            pooled = cv2.blur(snr, (cfg.pool_px, cfg.pool_px))
            mine = (owner == i).reshape(h, w)
            mostly_mine = cv2.blur(mine.astype(np.float32), (cfg.pool_px, cfg.pool_px)) > 0.5
            weak = (pooled > cfg.pooled_snr) & mostly_mine
            region = _clean(weak, min_area).ravel() & (labels == 0)
        if not region.any():
            continue
        kept.append(peak)
        kept_rows.append(i)
        labels[region] = len(kept)
    return Segmentation(
        labels=labels.reshape(h, w),
        peaks=kept,
        band_power=band_power[kept_rows].reshape(len(kept_rows), h, w),
        noise_power=noise[kept_rows],
    )


def frequency_map(
    spectra: PixelSpectra,
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    noise_factor: float = 8.0,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Per-pixel dominant frequency inside the band.

    Returns
    -------
    freq : ndarray of float32, shape (h, w)
        Dominant frequency, Hz.
    valid : ndarray of bool, shape (h, w)
        Pixels whose peak stands ``noise_factor`` above the background (median pixel) at that frequency.
    """
    freqs = spectra.frequencies_hz
    idx = np.flatnonzero((freqs >= band_hz[0]) & (freqs <= band_hz[1]))
    if len(idx) == 0:
        z = np.zeros(grid_shape, np.float32)
        return z, np.zeros(grid_shape, bool)
    sub = spectra.power[idx]
    k = np.argmax(sub, axis=0)
    peak_power = np.take_along_axis(sub, k[None, :], axis=0)[0]
    background = np.median(sub[:, :: max(1, sub.shape[1] // 20_000)], axis=1)
    valid = peak_power > noise_factor * background[k]
    freq = freqs[idx][k].astype(np.float32)
    return freq.reshape(grid_shape), valid.reshape(grid_shape)


def upsample_labels(labels: NDArray[np.integer[Any]], shape: tuple[int, int]) -> NDArray[np.uint16]:
    """Nearest-neighbour resize of a label map to the input frame size.

    Parameters
    ----------
    labels : ndarray of int, shape (h, w)
    shape : (H, W)

    Returns
    -------
    ndarray of uint16, shape (H, W)
    """
    lab = labels.astype(np.uint16)
    if lab.shape == shape:
        return lab
    return np.asarray(cv2.resize(lab, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST), np.uint16)


@dataclass(frozen=True)
class Exclusion:
    """Pixels removed from an object's mask, and why."""

    label: int
    pixels: int
    reason: str


def exclude_background_surfaces(
    labels: NDArray[np.int32],
    depth: NDArray[np.float32],
    *,
    min_separation_m: float = 0.05,
    min_area: int = 16,
    max_frames: int = 24,
) -> tuple[NDArray[np.int32], list[Exclusion]]:
    """Remove from each object the pixels that lie on the background's surface.

    A shadow or a reflection cast on a static wall moves at the object's frequency, so its spectrum looks
    like the object's; its depth does not: it is at the wall's distance, the object is in front of it.
    Pixels of a label whose (time-median) depth is nearer the background's than the object's are
    removed, provided the two surfaces are at least ``min_separation_m`` apart.

    Parameters
    ----------
    labels : ndarray of int32, shape (h, w)
        Object labels on the flow grid (0 = background).
    depth : ndarray of float32, shape (T, h, w)
        Depth in metres on the flow grid, NaN where invalid.
    min_separation_m : float
    min_area : int
        Objects left with fewer pixels keep their original mask (nothing is excluded).
    max_frames : int
        Frames (evenly spaced) used for the per-pixel median.

    Returns
    -------
    labels : ndarray of int32, shape (h, w)
    exclusions : list of Exclusion
    """
    import warnings

    step = max(1, depth.shape[0] // max_frames)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels
        median = np.nanmedian(depth[::step], axis=0)
    out = labels.copy()
    exclusions: list[Exclusion] = []
    background = median[(labels == 0) & np.isfinite(median)]
    if background.size < 16:
        return out, exclusions
    bg_depth = float(np.median(background))
    for label in range(1, int(labels.max()) + 1):
        region = labels == label
        values = median[region & np.isfinite(median)]
        if values.size < min_area:
            continue
        obj_depth = float(np.percentile(values, 25))
        if bg_depth - obj_depth < min_separation_m:
            continue
        split = (obj_depth + bg_depth) / 2
        far = region & np.isfinite(median) & (median > split)
        if not far.any():
            continue
        kept = region & ~far
        kept = _clean(kept, min_area)
        if kept.sum() < min_area:
            continue
        removed = int(region.sum() - kept.sum())
        out[region & ~kept] = 0
        exclusions.append(
            Exclusion(
                label=label,
                pixels=removed,
                reason=(
                    f"{removed} grid pixels moved at the object's frequency but lie on the background "
                    f"surface ({bg_depth:.2f} m, object at {obj_depth:.2f} m): a shadow, reflection or "
                    "swept background, excluded"
                ),
            )
        )
    return out, exclusions


@dataclass(frozen=True)
class RejectedPeak:
    """A spectral peak that is not an object."""

    frequency_hz: float
    reason: str


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
