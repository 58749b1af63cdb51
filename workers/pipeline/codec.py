"""A codec's traces in a window of frames, found from the picture's change and the flow's noise.

Nearly every real clip went through a lossy codec with periodic keyframes. At a keyframe the codec redraws
the picture, so the change between consecutive frames pulses every K frames (:func:`keyframe_period` for
the whole picture, :func:`region_keyframe_period` for one region, where a codec at a low bit rate redraws
only part of it); its cycle of frame types makes the flow's noise follow a pattern of m frames
(:func:`flow_level`, :func:`frame_pattern_period`); and the flow maps that span a keyframe hold a jump of
every edge, which :func:`keyframe_maps` finds and :func:`repair_keyframe_maps` mends.
:mod:`workers.pipeline.artefacts` turns these into the ``codec_keyframes`` verdict.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.flow import pixel_columns

#: Keyframe evidence: pulses every K frames stand this many robust deviations above the typical change
#: of the whole picture ...
KEYFRAME_Z = 8.0
#: ... and (at half that) in this fraction of its blocks.
KEYFRAME_BLOCKS = 0.6
#: A region's own change (:func:`region_keyframe_period`) is scaled by at least this fraction of
#: its mean: a codec that re-uses still blocks makes most frames' change exactly zero, and a deviation of
#: zero would make any few changes sharing a phase a pulse of any height.
KEYFRAME_MIN_SCALE = 0.1
#: Fewest frame-to-frame changes in which pulses are sought (a period up to a third of them).
MIN_PULSE_FRAMES = 24
#: A codec's cycle of frame types: patterns of up to this many frames, significant at this probability and
#: differing by this ratio between their phases (:func:`frame_pattern_period`).
MAX_PATTERN_FRAMES = 8
PATTERN_P = 1e-6
PATTERN_RATIO = 1.3


def keyframe_period(frame_change: NDArray[np.floating] | None) -> int | None:
    """The period K (frames) of pulses in the frame-to-frame change of the whole picture, or None.

    A codec's keyframes (and some cameras' exposure steps) change the whole picture every K frames: the
    change between consecutive frames then stands out at one phase modulo K, in most blocks of the
    picture at once (a fast vibration makes the change pulse too, but only where it moves).

    Parameters
    ----------
    frame_change : ndarray, shape (N, B, B), or None
        Mean absolute grey-level change of each block between consecutive frames.
    """
    if frame_change is None or len(frame_change) < MIN_PULSE_FRAMES:
        return None
    series = np.asarray(frame_change, np.float64).reshape(len(frame_change), -1)
    whole = series.mean(axis=1)
    scores = _pulse_scores(whole, _robust_centre(whole))
    if not scores:
        return None
    # Every multiple of the period folds the pulses as well: the period is the shortest that does nearly
    # as well as the best.
    best = max(scores.values())
    k = min(k for k, z in scores.items() if z >= 0.8 * best)
    everywhere = np.mean(
        [_pulse_score(series[:, j], k, z_min=KEYFRAME_Z / 2) > 0 for j in range(series.shape[1])]
    )
    return k if everywhere >= KEYFRAME_BLOCKS else None


def region_keyframe_period(frame_change: NDArray[np.floating], coverage: NDArray[np.float64]) -> int | None:
    """The period K (frames) of pulses in the change of one region of the picture, or None.

    The region's change is the ``coverage``-weighted mean of its blocks' change in each frame; its pulses
    are found as :func:`keyframe_period` finds the whole picture's, with the deviation scaled by at least
    :data:`KEYFRAME_MIN_SCALE` of the mean change (a codec re-using still blocks makes most frames'
    change exactly zero).

    Parameters
    ----------
    frame_change : ndarray, shape (N, B, B)
        Mean absolute grey-level change of each block between consecutive frames.
    coverage : ndarray of float64, shape (B, B)
        Fraction of each block the region covers (:func:`workers.pipeline.artefacts.block_coverage`).
    """
    total = float(coverage.sum())
    if len(frame_change) < MIN_PULSE_FRAMES or total <= 0:
        return None
    series = np.asarray(frame_change, np.float64).reshape(len(frame_change), -1) @ coverage.ravel() / total
    median, mad = _robust_centre(series)
    scores = _pulse_scores(series, (median, max(mad, KEYFRAME_MIN_SCALE * float(series.mean()))))
    # Every multiple of the period folds the pulses too, and one of them, holding fewer pulses, may score
    # higher by chance (a rate control's keyframes differ in size): the period is the shortest of which
    # nearly every period that scores is a multiple.
    return next((k for k in sorted(scores) if sum(j % k == 0 for j in scores) >= 0.8 * len(scores)), None)


def flow_level(
    flow: NDArray[np.float32], textured: NDArray[np.bool_], *, pixels: int = 4096
) -> NDArray[np.float32]:
    """Mean absolute flow (u and v) of a sample of the textured pixels in each map (N,): the level of the
    picture's flow noise, where a codec's cycle of frame types shows (:func:`frame_pattern_period`).

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
    textured : ndarray of bool, shape (h, w)
    """
    idx = np.flatnonzero(textured.ravel())
    if idx.size == 0:
        return np.zeros(len(flow), np.float32)
    idx = idx[:: max(1, idx.size // pixels)]
    sample = pixel_columns(flow, idx)
    return np.asarray(np.abs(sample).mean(axis=1), np.float32)


def frame_pattern_period(level: NDArray[np.floating] | None) -> int | None:
    """The shortest period m (2 to :data:`MAX_PATTERN_FRAMES` frames) over which the level of the picture's
    flow noise (:func:`flow_level`) follows a pattern, or None.

    Codecs cycle through frame types (intra, predicted, bidirectional) quantised differently, so the flow's
    noise differs by the frame's place in the cycle, and its spectrum holds lines at multiples of fps / m.
    The pattern is a one-way analysis of variance of the level by phase modulo m: significant at
    :data:`PATTERN_P` and differing by :data:`PATTERN_RATIO` between its phases.
    """
    from scipy.special import fdtrc  # the F law's survival function (scipy.stats's import costs 0.6 s)

    if level is None:
        return None
    series = np.asarray(level, np.float64)
    for m in range(2, MAX_PATTERN_FRAMES + 1):
        usable = len(series) - len(series) % m
        if usable < 6 * m:
            break
        folded = series[:usable].reshape(-1, m)
        means = folded.mean(axis=0)
        within = float(((folded - means) ** 2).sum()) / (usable - m)
        between = float(((means - folded.mean()) ** 2).sum()) * (usable // m) / (m - 1)
        if within <= 0 or means.min() <= 0:
            continue
        p = float(fdtrc(m - 1, usable - m, between / within))
        if p <= PATTERN_P and float(means.max()) >= PATTERN_RATIO * float(means.min()):
            return m
    return None


def keyframe_maps(frame_change: NDArray[np.floating] | None) -> NDArray[np.intp]:
    """The flow maps that span a codec's keyframe (map i spans frames i and i + 1): every K-th, at the
    phase where the whole picture's change pulses (:func:`keyframe_period`); none without pulses.

    Returns
    -------
    ndarray of intp, shape (M,)
    """
    period = keyframe_period(frame_change)
    if period is None or frame_change is None:
        return np.zeros(0, np.intp)
    change = np.asarray(frame_change, np.float64).reshape(len(frame_change), -1).mean(axis=1)
    usable = len(change) - len(change) % period
    phase = int(np.argmax(change[:usable].reshape(-1, period).mean(axis=0)))
    return np.arange(phase, len(change), period, dtype=np.intp)


def repair_keyframe_maps(flow: NDArray[np.float32], maps: NDArray[np.intp]) -> None:
    """Replace, in place, each flow map that spans a keyframe by the median of it and its two neighbours,
    per pixel and component.

    At a keyframe the codec redraws the picture: the flow between the last frame before it and the
    keyframe holds a jump of every edge that is no motion (the drift the predicted frames accumulated,
    and the new frame's own quantisation), every K frames, over the whole picture: a comb of lines at
    multiples of fps / K in every pixel's spectrum. The median of three keeps a motion that is monotone
    over the three samples as it is and clips the jump to its neighbours' range.

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
    maps : ndarray of intp, shape (M,)
        Indices into ``flow`` (:func:`keyframe_maps`).
    """
    n = len(flow)
    for i in maps:
        if not 0 < i < n - 1:
            continue
        lo = np.minimum(flow[i - 1], flow[i + 1])
        hi = np.maximum(flow[i - 1], flow[i + 1])
        np.clip(flow[i], lo, hi, out=flow[i])


def _robust_centre(change: NDArray[np.float64]) -> tuple[float, float]:
    """The median of ``change`` and its median absolute deviation scaled to a standard deviation."""
    median = float(np.median(change))
    return median, 1.4826 * float(np.median(np.abs(change - median))) + 1e-9


def _pulse_scores(change: NDArray[np.float64], centre: tuple[float, float]) -> dict[int, float]:
    """Each period from 2 to a third of ``change``'s length whose pulses stand out, with its score
    (:func:`_pulse_score`; ``centre`` is the same for every period tried)."""
    periods = range(2, len(change) // 3 + 1)
    return {k: z for k in periods if (z := _pulse_score(change, k, centre=centre)) > 0}


def _pulse_score(
    change: NDArray[np.float64],
    period: int,
    *,
    z_min: float = KEYFRAME_Z,
    centre: tuple[float, float] | None = None,
) -> float:
    """How far the pulses of ``change`` every ``period`` samples stand out (robust deviations above its
    median), or 0 when they do not all stand out (a few large changes sharing a phase by chance).
    ``centre``: :func:`_robust_centre` of ``change``, when already known."""
    median, mad = centre if centre is not None else _robust_centre(change)
    usable = len(change) - len(change) % period
    folded = change[:usable].reshape(-1, period)
    pulses = folded[:, int(np.argmax(folded.mean(axis=0)))]
    z = (float(np.median(pulses)) - median) / mad
    if z >= z_min and float(np.mean(pulses > median + 3 * mad)) >= 0.8:
        return z
    return 0.0


__all__ = [
    "KEYFRAME_BLOCKS",
    "KEYFRAME_MIN_SCALE",
    "KEYFRAME_Z",
    "MAX_PATTERN_FRAMES",
    "MIN_PULSE_FRAMES",
    "PATTERN_P",
    "PATTERN_RATIO",
    "flow_level",
    "frame_pattern_period",
    "keyframe_maps",
    "keyframe_period",
    "region_keyframe_period",
    "repair_keyframe_maps",
]
