"""Where each candidate moves in a window: its region on the window's grid and over the whole frame.

The front (:mod:`workers.pipeline.front`) found the candidates on the whole picture's coarse grid; this
module labels their pixels on the window's own grid (:func:`~workers.pipeline.segmentation.segment`), on the
plain flow or, where the plain flow's region misses where the scan found the line, on the constrained flow
(what the image can show of each pixel's motion), joins the parts of one body ringing in several modes
(:func:`~workers.pipeline.bodies.join_bodies`) and cuts away the background surface (with depth).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.bodies import join_bodies
from workers.pipeline.detection import Candidate
from workers.pipeline.front import Front, coarse_share
from workers.pipeline.peaks import Peak
from workers.pipeline.roi import Roi
from workers.pipeline.segmentation import (
    Exclusion,
    Segmentation,
    SegmentationConfig,
    exclude_background_surfaces,
    segment,
)
from workers.pipeline.spectra import PixelSpectra


@dataclass(frozen=True)
class Regions:
    """The segmented objects: labels on the window's grid and over the whole frame, their candidates."""

    seg: Segmentation
    labels_grid: NDArray[np.int32]
    labels_full: NDArray[np.uint16]
    exclusions: list[Exclusion]
    candidates: list[Candidate]


def segment_candidates(
    plain: PixelSpectra,
    constrained: Callable[[], PixelSpectra],
    *,
    front: Front,
    box: Roi,
    depth: NDArray[np.float32] | None,
    config: SegmentationConfig,
) -> Regions:
    """Label the front's candidates' pixels on the window's grid (the look already scanned the whole
    picture for weak local motion, so the segmentation does not): on the plain flow, and for the
    candidates that gave no region there or a region off where the scan found them (:func:`_held_in`: a
    thin, plain object moving a fraction of a pixel, whose flat inside, and the flat wall beside its ends,
    carry flow the image does not constrain), on the constrained flow.

    Parameters
    ----------
    plain : PixelSpectra
        Spectra of the window's flow, pixels of ``box``'s grid.
    constrained : callable
        Returns the spectra of the constrained flow (J^(1/2) u) on the same grid; called only when needed.
    front : Front
        The whole picture's scan and its candidates.
    box : Roi
        The box the window's grid covers.
    depth : ndarray of float32, shape (N + 1, h, w), or None
        Depth on the grid (regions on the background surface are cut away).
    config : SegmentationConfig

    Returns
    -------
    Regions
    """
    cfg = replace(config, local_snr=None)
    peaks = front.candidates.peaks
    seg = segment(plain, peaks, grid_shape=box.grid_shape, band_hz=front.band_hz, config=cfg)
    own = [_held_in(seg, p, front, box) for p in seg.peaks]
    off = [
        i
        for i, share in enumerate(own)
        if share < ON_TARGET_SHARE and not _held_elsewhere(seg, i, front, box)
    ]
    missing = [p for p in peaks if _index_in(seg.peaks, p) is None]
    if missing or off:
        second = segment(
            constrained(),
            missing + [seg.peaks[i] for i in off],
            grid_shape=box.grid_shape,
            band_hz=front.band_hz,
            config=cfg,
        )
        better = [
            i
            for i in off
            if _held_in(second, seg.peaks[i], front, box) >= min(ON_TARGET_SHARE, RETARGET_GAIN * own[i])
        ]
        wanted = missing + [seg.peaks[i] for i in better]
        unwanted = [j for j, q in enumerate(second.peaks) if _index_in(wanted, q) is None]
        seg = _merged(seg, second, order=peaks, drop=(better, unwanted))
    # Parts of one body ringing in several modes are one object (its modes are sought on it later).
    seg = join_bodies(seg, plain.power, frequencies_hz=plain.frequencies_hz)
    # The segmentation may hand back copies of the peaks (with folded harmonics): match by frequency.
    candidates = [candidate_of(p, front.candidates.found) for p in seg.peaks]
    labels_grid = seg.labels
    exclusions: list[Exclusion] = []
    if depth is not None and seg.peaks:
        labels_grid, exclusions = exclude_background_surfaces(labels_grid, depth)
    labels_full = np.asarray(box.to_frame(labels_grid.astype(np.uint16)), np.uint16)
    return Regions(seg, labels_grid, labels_full, exclusions, candidates)


#: A region holding less than this share of where the scan found its line (its candidate's region, on the
#: scan's grid) is off target ...
ON_TARGET_SHARE = 0.3
#: The constrained flow's region replaces it when it holds that share, or this many times the plain one's
#: (on a thin bar of low contrast, 0.045 of where the scan found it by the plain flow's region at its ends,
#: 0.245 by the constrained flow's along it; a flickering light's apparent motion holds about as little
#: of the picture either way).
RETARGET_GAIN = 2.0
#: ... unless other objects' regions hold this share of it: a line found on a stronger object's pixels and
#: measured elsewhere is that object's (:func:`~workers.pipeline.verdicts.held_verdict` says so).
HELD_ELSEWHERE = 0.3


def _held_share(region: NDArray[np.bool_], found: NDArray[np.bool_], front: Front, box: Roi) -> float:
    """The share of ``found`` (on the scan's grid) that ``region`` (on the window's grid) holds."""
    frame = np.asarray(box.to_frame(region.astype(np.uint8)), bool)
    return float(coarse_share(front, frame)[found].mean())


def _held_elsewhere(seg: Segmentation, index: int, front: Front, box: Roi) -> bool:
    """Whether the regions of ``seg``'s other peaks hold :data:`HELD_ELSEWHERE` of where the scan found
    ``seg.peaks[index]``."""
    found = candidate_of(seg.peaks[index], front.candidates.found).region
    others = (seg.labels > 0) & (seg.labels != index + 1)
    return bool(found.any()) and _held_share(others, found, front, box) >= HELD_ELSEWHERE


def _held_in(seg: Segmentation, peak: Peak, front: Front, box: Roi) -> float:
    """The share of where the scan found ``peak`` that its region in ``seg`` holds (0 without one; 1 when
    the scan's region is empty: nothing to miss)."""
    found = candidate_of(peak, front.candidates.found).region
    if not found.any():
        return 1.0
    j = _index_in(seg.peaks, peak)
    return 0.0 if j is None else _held_share(seg.labels == j + 1, found, front, box)


def _index_in(peaks: list[Peak], peak: Peak) -> int | None:
    """The index of ``peak`` among ``peaks`` (the same frequency), or None."""
    return next((i for i, q in enumerate(peaks) if abs(q.frequency_hz - peak.frequency_hz) <= 1e-9), None)


def candidate_of(peak: Peak, found: list[Candidate]) -> Candidate:
    """The candidate whose peak ``peak`` is (the nearest in frequency)."""
    return min(found, key=lambda c: abs(c.peak.frequency_hz - peak.frequency_hz))


def _merged(
    first: Segmentation,
    second: Segmentation,
    *,
    order: list[Peak],
    drop: tuple[list[int], list[int]] = ([], []),
) -> Segmentation:
    """Two segmentations of different peaks as one, labelled in ``order`` (the second's regions only
    where the first has none), without the regions of the peaks ``drop`` names (indices into each)."""
    sources = [
        (p, seg, i)
        for seg, dropped in zip((first, second), drop, strict=True)
        for i, p in enumerate(seg.peaks)
        if i not in dropped
    ]

    def rank(peak: Peak) -> int:
        return min(range(len(order)), key=lambda k: abs(order[k].frequency_hz - peak.frequency_hz))

    sources.sort(key=lambda item: rank(item[0]))
    labels = np.zeros_like(first.labels)
    placed: list[tuple[Peak, Segmentation, int]] = []
    for peak, seg, i in sources:
        region = (seg.labels == i + 1) & (labels == 0)
        if region.any():
            placed.append((peak, seg, i))
            labels[region] = len(placed)
    sources = placed
    if not sources:  # neither gave a region
        return Segmentation(
            labels=labels,
            peaks=[],
            band_power=np.zeros((0, *labels.shape), np.float32),
            noise_power=np.zeros(0),
        )
    return Segmentation(
        labels=labels,
        peaks=[p for p, _, _ in sources],
        band_power=np.stack([seg.band_power[i] for _, seg, i in sources]),
        noise_power=np.array([seg.noise_power[i] for _, seg, i in sources]),
    )


__all__ = [
    "HELD_ELSEWHERE",
    "ON_TARGET_SHARE",
    "RETARGET_GAIN",
    "Regions",
    "candidate_of",
    "segment_candidates",
]
