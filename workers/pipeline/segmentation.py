"""Segmentation by spectral signature: pixels whose motion rings at an object's frequency, well above the
noise floor, grouped into cleaned connected regions and labelled one object per fundamental frequency.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.peaks import (
    Peak,
    explained,
    fold_aliased_harmonics,
    interpolate_peak,
    nanmedian_over_time,
    noise_floor,
    topographic_prominence,
)
from workers.pipeline.spectra import PixelSpectra


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
    pooled_grow : float
        Weak regions grow into connected neighbours whose pooled ratio exceeds this fraction of
        ``pooled_snr`` (hysteresis).
    weak_snr : float
        A region whose median pixel stands less than this far above its own noise (band power over the
        pixel's median power, per bin) may be weak motion: the purity test keeps only its strongest
        pixels, so the pooled ratio adds the pixels moving as strongly (``relative_level`` of the
        region's median band power) that it missed.
    edge_level : float or None
        A pixel of a strongly moving region is kept only where its band power is at least this fraction
        of the strongest within ``edge_radius_px``: dense flow spreads motion a patch beyond the object,
        and a smoothed edge has half the amplitude (a quarter of the power) where the object ends. This
        keeps a thin object (a string, a wire) from growing a fringe wider than itself. None: off.
    edge_radius_px : int
        Radius (grid pixels) of that neighbourhood: about the flow's smoothing scale.
    local_snr : float or None
        Weak motion confined to part of the picture (a small object moving a twentieth of a pixel) is
        diluted in any whole-picture spectrum. :func:`local_peaks` scans the per-pixel signal-to-noise
        ratio pooled over square neighbourhoods of ``local_scales_px``; a frequency at which some
        neighbourhood stands this many times above its usual maximum (over frequency) becomes an object
        candidate of its own. None: off.
    local_scales_px : tuple of int
        Side lengths (grid pixels) of the pooled neighbourhoods.
    """

    noise_factor: float = 8.0
    relative_level: float = 0.2
    purity: float = 0.25
    band_bins: float = 1.5
    min_area_fraction: float = 0.0015
    pool_px: int = 5
    pooled_snr: float = 4.0
    edge_level: float | None = 0.25
    edge_radius_px: int = 8
    local_snr: float | None = 3.0
    pooled_grow: float = 0.5
    weak_snr: float = 30.0
    local_scales_px: tuple[int, ...] = (7, 15, 31)


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


def _fill_holes(mask: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Set the background pixels that no 4-connected path joins to the image border (as
    ``scipy.ndimage.binary_fill_holes``, without importing scipy.ndimage)."""
    h, w = mask.shape
    outside = np.zeros((h + 2, w + 2), np.uint8)
    outside[1:-1, 1:-1] = mask > 0
    cv2.floodFill(outside, np.zeros((h + 4, w + 4), np.uint8), (0, 0), 2, flags=4)
    return np.asarray(outside[1:-1, 1:-1] != 2, np.uint8)


def _clean(mask: NDArray[np.bool_], min_area: int) -> NDArray[np.bool_]:
    m = mask.astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, kernel)
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, kernel)
    filled = _fill_holes(m)
    count, comp, stats, _ = cv2.connectedComponentsWithStats(filled, connectivity=8)
    keep = np.zeros(count, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return np.asarray(keep[comp])


def _within_edge(
    band_power: NDArray[np.float32], candidate: NDArray[np.bool_], cfg: SegmentationConfig
) -> NDArray[np.bool_]:
    """Pixels whose band power reaches ``cfg.edge_level`` of the strongest candidate within
    ``cfg.edge_radius_px`` (see :class:`SegmentationConfig`).

    Parameters
    ----------
    band_power : ndarray of float32, shape (h, w)
    candidate : ndarray of bool, shape (h, w)

    Returns
    -------
    ndarray of bool, shape (h, w)
    """
    assert cfg.edge_level is not None
    r = max(1, cfg.edge_radius_px)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    local_max = cv2.dilate(np.where(candidate, band_power, 0).astype(np.float32), kernel)
    return np.asarray(band_power >= np.float32(cfg.edge_level) * local_max)


def segment(
    spectra: PixelSpectra,
    peaks: list[Peak],
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    config: SegmentationConfig | None = None,
) -> Segmentation:
    """Label the pixels of each peak's object.

    A peak at an overtone of a stronger peak folded back below the Nyquist rate (a string's 3rd
    harmonic at 600 fps) is counted as that peak's harmonic (see :func:`fold_aliased_harmonics`). After
    the given peaks are labelled, the rest of the picture is scanned for weak motion that only a
    region shows (:func:`local_peaks`, unless ``config.local_snr`` is None); the peaks it finds are
    labelled after the given ones (and appear in the result's ``peaks`` when they give a region).

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
    peaks = fold_aliased_harmonics(peaks, sample_rate_hz=spectra.sample_rate_hz, bin_hz=spectra.bin_hz)
    seg = _label(spectra, peaks, grid_shape=grid_shape, band_hz=band_hz, cfg=cfg)
    if cfg.local_snr is None:
        return seg
    extra = local_peaks(
        spectra,
        grid_shape=grid_shape,
        band_hz=band_hz,
        exclude=seg.labels > 0,
        known=peaks,
        scan=LocalScan(min_ratio=cfg.local_snr, scales_px=cfg.local_scales_px),
    )
    if not extra:
        return seg
    return _label(spectra, [*peaks, *extra], grid_shape=grid_shape, band_hz=band_hz, cfg=cfg)


@dataclass(frozen=True, kw_only=True)
class LocalScan:
    """How :func:`local_peaks` scans neighbourhoods for weak motion.

    Attributes
    ----------
    min_ratio : float
        Height of a peak over the chance level.
    scales_px : tuple of int
        Neighbourhood sides, grid pixels (clipped to half the grid's smaller side).
    max_peaks : int
        Peaks reported at most.
    harmonic_tolerance : float
        Relative tolerance of a multiple of a known peak.
    """

    min_ratio: float = 3.0
    scales_px: tuple[int, ...] = (7, 15, 31)
    max_peaks: int = 3
    harmonic_tolerance: float = 0.04


def local_peaks(
    spectra: PixelSpectra,
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    exclude: NDArray[np.bool_] | None = None,
    known: list[Peak] | None = None,
    scan: LocalScan = LocalScan(),
) -> list[Peak]:
    """Frequencies at which some region of the picture moves, too weakly for any whole-picture spectrum.

    Each pixel's power is divided by its own noise (its median power in the band), so every pixel
    votes with its signal-to-noise ratio, and these ratios are averaged over square neighbourhoods of
    each size in ``scan.scales_px``. Averaging power, not signed flow, keeps parts moving in anti-phase
    from cancelling; averaging over a neighbourhood rather than the whole picture keeps the static
    background from diluting a small object's motion. At each frequency the best neighbourhood's value is
    compared with its running median over frequency (what the best neighbourhood reaches by chance); a
    peak ``scan.min_ratio`` times above it, with 6 dB of topographic prominence, is reported.

    Parameters
    ----------
    spectra : PixelSpectra
        Per-pixel power, shape (F, h * w).
    grid_shape : (h, w)
    band_hz : (low, high)
    exclude : ndarray of bool, shape (h, w), optional
        Pixels already explained (labelled objects); they do not vote.
    known : list of Peak, optional
        Peaks already found: their frequencies, harmonics and integer multiples (also when folded back
        below the Nyquist rate) are not reported again.
    scan : LocalScan
        Neighbourhood sizes and thresholds.

    Returns
    -------
    list of Peak
        Strongest first; ``power`` and ``snr_db`` are the height over the chance level (ratio and dB).

    Raises
    ------
    ValueError
        When ``grid_shape`` does not match the spectra's pixel count.
    """
    h, w = grid_shape
    if spectra.power.shape[1] != h * w:
        raise ValueError(
            f"local_peaks: grid {h}x{w} has {h * w} pixels but the spectra hold {spectra.power.shape[1]}"
        )
    freqs = spectra.frequencies_hz
    idx = np.flatnonzero((freqs >= band_hz[0]) & (freqs <= band_hz[1]))
    if len(idx) < 8:
        return []
    ratio = _neighbourhood_ratio(
        spectra, idx, grid_shape=grid_shape, band_hz=band_hz, exclude=exclude, scales_px=scan.scales_px
    )
    padded = np.concatenate(([-np.inf], ratio, [-np.inf]))
    local = np.flatnonzero((padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:]))
    found: list[Peak] = []
    for j in sorted(local.tolist(), key=lambda j: -ratio[j]):
        if ratio[j] < scan.min_ratio or len(found) >= scan.max_peaks:
            break
        peak = _local_peak(ratio, j, first_bin=int(idx[0]), peak_bin=int(idx[j]), bin_hz=spectra.bin_hz)
        if peak is None or explained(
            peak.frequency_hz,
            [*(known or []), *found],
            bin_hz=spectra.bin_hz,
            tolerance=scan.harmonic_tolerance,
            sample_rate_hz=spectra.sample_rate_hz,
        ):
            continue
        found.append(peak)
    return found


def _neighbourhood_ratio(
    spectra: PixelSpectra,
    idx: NDArray[np.intp],
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    exclude: NDArray[np.bool_] | None,
    scales_px: tuple[int, ...],
) -> NDArray[np.float64]:
    """The best neighbourhood's pooled signal-to-noise ratio at each bin of ``idx`` over its running
    median over frequency, the highest over the neighbourhood sizes (see :func:`local_peaks`).

    Parameters
    ----------
    spectra : PixelSpectra
        Per-pixel power, shape (F, h * w).
    idx : ndarray of intp, shape (B,)
        The band's bins.
    grid_shape : (h, w)
    band_hz : (low, high)
        The band of ``idx``: each pixel's noise is its median power in it.
    exclude : ndarray of bool, shape (h, w), optional
        Pixels that do not vote.
    scales_px : tuple of int
        Neighbourhood sides, grid pixels.

    Returns
    -------
    ndarray of float64, shape (B,)
    """
    h, w = grid_shape
    limit = max(3, min(h, w) // 2)
    scales = sorted({min(s, limit) | 1 for s in scales_px if s >= 1})
    noise = spectra.band_median(band_hz) + np.float32(1e-20)
    weight = (1.0 / noise).astype(np.float32)
    if exclude is not None:
        weight[exclude.ravel()] = 0.0
    best = np.zeros((len(scales), len(idx)))
    for j, k in enumerate(idx):
        snr = (spectra.power[k] * weight).reshape(h, w)
        for i, side in enumerate(scales):
            best[i, j] = float(cv2.blur(snr, (side, side)).max())
    width = max(15, len(idx) // 6)
    ratios = np.stack([row / np.maximum(noise_floor(row, width=width), 1e-30) for row in best])
    return np.asarray(ratios.max(axis=0), np.float64)


def _local_peak(
    ratio: NDArray[np.float64], j: int, *, first_bin: int, peak_bin: int, bin_hz: float
) -> Peak | None:
    """The peak at the local maximum ``j`` of ``ratio`` (B,) over the band starting at ``first_bin``, or
    None when it stands less than 6 dB above its key saddle."""
    prominence = topographic_prominence(ratio, j)
    if 10 * np.log10(prominence) < 6.0:
        return None
    return Peak(
        frequency_hz=(first_bin + interpolate_peak(ratio, j)) * bin_hz,
        bin=peak_bin,
        power=float(ratio[j]),
        prominence_db=float(10 * np.log10(prominence)),
        snr_db=float(10 * np.log10(ratio[j])),
    )


def _label(
    spectra: PixelSpectra,
    peaks: list[Peak],
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    cfg: SegmentationConfig,
) -> Segmentation:
    """Label the pixels of each of ``peaks`` (see :func:`segment`)."""
    h, w = grid_shape
    if not peaks:
        return Segmentation(
            labels=np.zeros(grid_shape, np.int32),
            peaks=[],
            band_power=np.zeros((0, h, w), np.float32),
            noise_power=np.zeros(0),
        )
    bands = _bands(spectra, peaks, grid_shape=grid_shape, band_hz=band_hz, cfg=cfg)
    min_area = max(4, int(cfg.min_area_fraction * h * w))
    labels = np.zeros(h * w, np.int32)
    kept: list[Peak] = []
    kept_rows: list[int] = []
    for i, peak in enumerate(peaks):
        region = _object_region(bands, i, labels=labels, grid_shape=grid_shape, min_area=min_area, cfg=cfg)
        if not region.any():
            continue
        kept.append(peak)
        kept_rows.append(i)
        labels[region] = len(kept)
    return Segmentation(
        labels=labels.reshape(h, w),
        peaks=kept,
        band_power=bands.power[kept_rows].reshape(len(kept_rows), h, w),
        noise_power=bands.noise[kept_rows],
    )


@dataclass(frozen=True)
class _Bands:
    """Each peak's band power at every pixel, and what it is judged against.

    Attributes
    ----------
    power : ndarray of float32, shape (K, h * w)
        Power in each peak's band (fundamental and harmonics).
    bins : ndarray of float64, shape (K,)
        Bins in each band (at least 1).
    total : ndarray of float32, shape (h * w,)
        Each pixel's power in the whole analysis band.
    pixel_noise : ndarray of float32, shape (h * w,)
        Each pixel's own noise level (median power per bin in the analysis band).
    noise : ndarray of float64, shape (K,)
        Band power of the background (median pixel).
    owner : ndarray of intp, shape (h * w,)
        The peak whose band is strongest at each pixel.
    """

    power: NDArray[np.float32]
    bins: NDArray[np.float64]
    total: NDArray[np.float32]
    pixel_noise: NDArray[np.float32]
    noise: NDArray[np.float64]
    owner: NDArray[np.intp]


def _bands(
    spectra: PixelSpectra,
    peaks: list[Peak],
    *,
    grid_shape: tuple[int, int],
    band_hz: tuple[float, float],
    cfg: SegmentationConfig,
) -> _Bands:
    """The band powers of ``peaks`` (not empty) over the ``grid_shape`` pixels of ``spectra`` (see
    :class:`_Bands`)."""
    h, w = grid_shape
    freqs = spectra.frequencies_hz
    in_band = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    total = spectra.power[in_band].sum(axis=0) + np.float32(1e-20)
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
    return _Bands(
        power=band_power, bins=band_bins, total=total, pixel_noise=pixel_noise, noise=noise, owner=owner
    )


def _object_region(
    bands: _Bands,
    i: int,
    *,
    labels: NDArray[np.int32],
    grid_shape: tuple[int, int],
    min_area: int,
    cfg: SegmentationConfig,
) -> NDArray[np.bool_]:
    """The pixels of peak ``i``'s object not yet labelled: those the purity test keeps, or pooled weak
    motion, then bridged over its gaps (see :func:`_bridged`).

    Parameters
    ----------
    bands : _Bands
    i : int
        The peak's row of ``bands``.
    labels : ndarray of int32, shape (h * w,)
        The labels so far (0: free).
    grid_shape : (h, w)
    min_area : int
        Smallest connected part kept, grid pixels.
    cfg : SegmentationConfig

    Returns
    -------
    ndarray of bool, shape (h * w,)
    """
    h, w = grid_shape
    bp = bands.power[i]
    snr = bp / (bands.pixel_noise * bands.bins[i])
    candidate = (
        (bp > cfg.noise_factor * bands.noise[i]) & (bands.owner == i) & (bp > cfg.purity * bands.total)
    )
    moving = candidate.copy()
    region = np.zeros(h * w, bool)
    if candidate.any():
        # The object's typical level: occlusion edges carry erratic, strong flow, so a high
        # percentile would be set by them rather than by the object's interior.
        level = float(np.median(bp[candidate]))
        candidate &= bp >= cfg.relative_level * level
        if cfg.edge_level is not None:
            candidate &= _within_edge(bp.reshape(h, w), candidate.reshape(h, w), cfg).ravel()
        region = _clean(candidate.reshape(h, w), min_area).ravel() & (labels == 0)
    if not region.any() or float(np.median(snr[region])) < cfg.weak_snr:
        weak = _weak_motion(snr.reshape(h, w), (bands.owner == i).reshape(h, w), cfg)
        if region.any():
            # ... as strong as the pixels the purity test kept: strong motion on noisy flow also
            # lights up the swept, leaking background around it, far weaker than the object.
            weak &= (bp >= cfg.relative_level * float(np.median(bp[region]))).reshape(h, w)
        region |= _clean(weak, min_area).ravel() & (labels == 0)
    if not region.any():
        return region
    core = region & (bp >= float(np.median(bp[region])))
    region |= _bridged(region.reshape(h, w), moving.reshape(h, w), cfg, core=core.reshape(h, w)).ravel()
    region &= labels == 0
    return region


def _weak_motion(
    snr: NDArray[np.floating[Any]], mine: NDArray[np.bool_], cfg: SegmentationConfig
) -> NDArray[np.bool_]:
    """Weak (sub-pixel) motion: each pixel is only a few dB above its own noise, too little for the
    purity test. The per-pixel signal-to-noise ratio is pooled over small neighbourhoods, which move
    together (parts in anti-phase are pooled as power, so they do not cancel); what stands out is kept
    and grown into neighbours that stand out less (hysteresis).

    Parameters
    ----------
    snr : ndarray of float, shape (h, w)
        Each pixel's band power over its own noise (per bin) in the band.
    mine : ndarray of bool, shape (h, w)
        Pixels whose strongest band is the object's.
    cfg : SegmentationConfig

    Returns
    -------
    ndarray of bool, shape (h, w)
    """
    pooled = cv2.blur(snr.astype(np.float32), (cfg.pool_px, cfg.pool_px))
    mostly_mine = cv2.blur(mine.astype(np.float32), (cfg.pool_px, cfg.pool_px)) > 0.5
    weak = (pooled > cfg.pooled_snr) & mostly_mine
    if weak.any():
        low = (pooled > cfg.pooled_grow * cfg.pooled_snr) & mostly_mine
        count, comp = cv2.connectedComponents(low.astype(np.uint8), connectivity=8)
        seeded = np.zeros(count, bool)
        seeded[np.unique(comp[weak])] = True
        seeded[0] = False
        weak = seeded[comp]
    return np.asarray(weak, bool)


def _bridged(
    region: NDArray[np.bool_],
    moving: NDArray[np.bool_],
    cfg: SegmentationConfig,
    *,
    core: NDArray[np.bool_],
) -> NDArray[np.bool_]:
    """The pixels of ``moving`` (above the noise at the object's frequency, mostly its own) in the gaps of
    ``region`` no wider than the edge neighbourhood; and for a long, thin region (a string, a wire, a
    bar: :data:`THIN_ASPECT`), along its length up to :data:`BRIDGE_SHARE` of it, in its gaps and beyond
    its ends. A thin object's nodes, and the stretches of it that show little contrast against the
    background, move far less in the flow than the rest (the relative and edge tests drop them) and
    still lie inside the object; a closing fills gaps and dents only, and growth along a thin object's
    length does not widen it: it starts from the region's ``core`` (its pixels moving at least as
    strongly as its median one), not from the fringe that flow spreads around it."""
    side = 2 * cfg.edge_radius_px + 1
    closed = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((side, side), np.uint8)) > 0
    along = _length_kernel(region, min_px=side)
    if along is not None:
        closed |= cv2.dilate(core.astype(np.uint8), along) > 0
    return np.asarray(closed & moving & ~region, bool)


#: :func:`_bridged` grows a region along its length up to this share of its length ...
BRIDGE_SHARE = 0.15
#: ... when it is at least this many times longer than wide.
THIN_ASPECT = 4.0


def _length_kernel(region: NDArray[np.bool_], *, min_px: int) -> NDArray[np.uint8] | None:
    """A line along a thin region's longer principal axis, :data:`BRIDGE_SHARE` of its length long (None
    when the region is not thin, or the line would be no longer than ``min_px``)."""
    ys, xs = np.nonzero(region)
    if xs.size < 2:
        return None
    coords = np.stack([xs - xs.mean(), ys - ys.mean()]).astype(np.float64)
    values, vectors = np.linalg.eigh(coords @ coords.T)
    if values[1] < THIN_ASPECT**2 * max(float(values[0]), 1e-9):
        return None
    axis = vectors[:, 1]
    along = axis @ coords
    length = int(BRIDGE_SHARE * float(along.max() - along.min()))
    if length <= min_px:
        return None
    reach = length // 2
    kernel = np.zeros((2 * reach + 1, 2 * reach + 1), np.uint8)
    dx, dy = axis[0] * reach, axis[1] * reach
    cv2.line(kernel, (round(reach - dx), round(reach - dy)), (round(reach + dx), round(reach + dy)), 1, 1)
    return kernel


def at_rest(
    mask: NDArray[np.bool_], *, axis_px: tuple[float, float], amplitude_px: float
) -> NDArray[np.bool_]:
    """Where an object is at rest, from the region its motion swept: the region eroded by its amplitude
    along its motion's axis on either side (a body moving by A along an axis covers its resting outline
    widened by A each way). Unchanged when that would leave less than :data:`REST_MIN_SHARE` of it (the
    region did not hold the whole sweep). The erosion is by the amplitude's whole pixels: a sweep of less
    than a pixel each way is not resolved by a region on the pixel grid.

    Parameters
    ----------
    mask : ndarray of bool, shape (H, W)
    axis_px : (ux, uy)
        Unit vector of the motion in the image.
    amplitude_px : float
        The motion's amplitude, pixels.
    """
    reach = math.floor(amplitude_px)
    if reach < 1:
        return mask
    side = 2 * reach + 1
    kernel = np.zeros((side, side), np.uint8)
    dx, dy = axis_px[0] * reach, axis_px[1] * reach
    cv2.line(kernel, (round(reach - dx), round(reach - dy)), (round(reach + dx), round(reach + dy)), 1, 1)
    rest = cv2.erode(mask.astype(np.uint8), kernel) > 0
    return rest if rest.sum() >= REST_MIN_SHARE * mask.sum() else mask


#: :func:`at_rest` keeps at least this share of a region.
REST_MIN_SHARE = 0.3


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
    summary = spectra.band_summary(band_hz)
    if summary.bins == slice(int(idx[0]), int(idx[-1]) + 1):  # the band itself (not a short band's stand-in)
        k, peak_power = summary.argmax, summary.peak
    else:
        sub_all = spectra.power[idx]
        k = np.argmax(sub_all, axis=0)
        peak_power = np.take_along_axis(sub_all, k[None, :], axis=0)[0]
    sub = spectra.power[idx[0] : idx[-1] + 1]
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
    step = max(1, depth.shape[0] // max_frames)
    median = nanmedian_over_time(depth[::step])
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
