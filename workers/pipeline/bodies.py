"""One body, several modes: regions of the segmentation that are parts of one object ringing at once in
several modes are joined into that object.

Segmentation labels each pixel by the frequency that dominates its motion. A body ringing in several
modes (a struck cantilever: 1 : 6.3 : 17.5) is then cut where its modes trade places: the tip moves
most in the first mode, the middle in the second, the root in the third, and each part becomes an
object of its own. Yet every part carries every mode: the modes are the body's, not the part's.
Two regions are parts of one body when

- they touch (within :data:`TOUCH_PX` grid pixels), and
- each one's pixels, summed, show the other's frequency as a line of their own: a local maximum standing
  :data:`SHARED_LINE_DB` above the summed spectrum's running median and :data:`SHARED_PROMINENCE` above
  the saddle to any stronger line (the flank of its own line, or a neighbour's motion leaking a few
  pixels across the border, is no line over the whole region), at a frequency resolved from its own.

Two objects that merely touch do not share their lines; two bodies that do not touch are never joined.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.peaks import noise_floor, topographic_prominence
from workers.pipeline.segmentation import Segmentation

#: Regions closer than this (grid pixels, after dilation) touch.
TOUCH_PX = 2
#: A shared line stands this far above the region's summed spectrum's running median, dB ...
SHARED_LINE_DB = 10.0
#: ... and this far (power ratio) above its key saddle.
SHARED_PROMINENCE = 2.0
#: The two frequencies are at least this many bins apart (closer ones are one line's flanks).
MIN_SEPARATION_BINS = 3.0
#: Running-median width of the floor, bins.
FLOOR_WIDTH_BINS = 31


def join_bodies(
    seg: Segmentation,
    power: NDArray[np.float32],
    *,
    frequencies_hz: NDArray[np.float64],
) -> Segmentation:
    """Join the regions of ``seg`` that are parts of one body (see the module docstring).

    Parameters
    ----------
    seg : Segmentation
        Labels (h, w) 1..K for ``seg.peaks``, strongest first.
    power : ndarray of float32, shape (F, h * w)
        Per-pixel power spectra on the same grid.
    frequencies_hz : ndarray of float64, shape (F,)

    Returns
    -------
    Segmentation
        ``seg`` itself when nothing joins; else the joined labels renumbered 1..K' in the order of their
        strongest part, each keeping that part's peak, band power and noise.
    """
    k = len(seg.peaks)
    if k < 2:
        return seg
    bin_hz = float(frequencies_hz[1] - frequencies_hz[0])
    masks = [seg.labels == i + 1 for i in range(k)]
    spectra = [power[:, m.ravel()].sum(axis=1, dtype=np.float64) for m in masks]
    floors = [noise_floor(spectrum, width=FLOOR_WIDTH_BINS) for spectrum in spectra]
    near = [_grown(m) for m in masks]
    parent = list(range(k))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for a in range(k):
        for b in range(a + 1, k):
            fa, fb = seg.peaks[a].frequency_hz, seg.peaks[b].frequency_hz
            if abs(fa - fb) < MIN_SEPARATION_BINS * bin_hz or not (near[a] & masks[b]).any():
                continue
            if _has_line(spectra[a], floors[a], frequencies_hz, fb) and _has_line(
                spectra[b], floors[b], frequencies_hz, fa
            ):
                parent[root(b)] = root(a)
    groups = sorted({root(i) for i in range(k)})
    if len(groups) == k:
        return seg
    labels = np.zeros_like(seg.labels)
    for i in range(k):
        labels[masks[i]] = groups.index(root(i)) + 1
    return Segmentation(
        labels=labels,
        peaks=[seg.peaks[g] for g in groups],
        band_power=seg.band_power[groups],
        noise_power=seg.noise_power[groups],
    )


def _grown(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    kernel = np.ones((2 * TOUCH_PX + 1, 2 * TOUCH_PX + 1), np.uint8)
    return np.asarray(cv2.dilate(mask.astype(np.uint8), kernel), bool)


def _has_line(
    spectrum: NDArray[np.float64],
    floor: NDArray[np.float64],
    frequencies_hz: NDArray[np.float64],
    frequency_hz: float,
) -> bool:
    """Whether ``spectrum`` (over its running-median ``floor``) has a line of its own at ``frequency_hz``
    (within a bin)."""
    k = int(np.argmin(np.abs(frequencies_hz - frequency_hz)))
    lo, hi = max(k - 1, 1), min(k + 2, len(spectrum) - 1)
    if hi <= lo:
        return False
    k = lo + int(np.argmax(spectrum[lo:hi]))
    if not (spectrum[k] >= spectrum[k - 1] and spectrum[k] >= spectrum[k + 1]):
        return False  # a flank, not a maximum
    stands = spectrum[k] >= 10 ** (SHARED_LINE_DB / 10) * max(float(floor[k]), 1e-30)
    return bool(stands and topographic_prominence(spectrum, k) >= SHARED_PROMINENCE)


__all__ = ["join_bodies"]
