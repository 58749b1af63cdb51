"""The force sensor's baseline, noise and the force's dominant direction (:mod:`workers.pipeline.force`).

The *baseline* is what the sensor reads when nothing pushes: the level the record ends at (after a release
or a strike the object rings freely), fitted as a robust straight line over every quiet part of the
record, so that a sensor's offset and slow linear drift are removed. The noise is the MAD of the quiet
parts about it. Times in seconds, forces in newtons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.lstsq import effective_count

FloatArray = NDArray[np.float64]

#: Scale from a median absolute deviation to the standard deviation of normal noise.
MAD_TO_SD = 1.4826
#: Fewest samples a force record needs.
MIN_SAMPLES = 8
#: A sample further than this many noise SDs from the baseline is not quiet.
QUIET_SIGMAS = 6.0


@dataclass(frozen=True)
class Line:
    """A robust straight line y = intercept + slope (t - t_mean) and its standard error."""

    t_mean: float
    intercept: float
    slope: float
    sigma: float
    n: int
    n_eff: float
    sxx: float

    def at(self, t: FloatArray) -> FloatArray:
        return self.intercept + self.slope * (t - self.t_mean)

    def se(self, t: float) -> float:
        """Standard error of the line at ``t`` (noise over the effective count; the slope's share)."""
        slope_share = (t - self.t_mean) ** 2 / (self.sxx * self.n_eff / max(self.n, 1))
        return float(self.sigma * math.sqrt(1.0 / self.n_eff + slope_share))


@dataclass(frozen=True)
class Baseline:
    """The baseline at every sample (N,), the quiet samples' mask (N,) and their noise SD."""

    level: FloatArray
    quiet: NDArray[np.bool_]
    sigma: float
    line: Line


def signed_force(t: FloatArray, force: FloatArray) -> tuple[FloatArray | None, FloatArray, bool]:
    """Unit direction (3,) or None, the projected force (N,), and whether a 1-D force's sign was flipped:
    ``force`` (N, 3) or (N, 1) at times ``t`` (N,)."""
    if force.shape[1] == 1:
        values = force[:, 0]
        base = baseline(t, values)
        above = values - base.level
        flipped = bool(np.sum(above[np.abs(above) > QUIET_SIGMAS * base.sigma]) < 0)
        return None, -values if flipped else values.copy(), flipped
    axis = principal_axis(force - np.median(force, axis=0))
    base = baseline(t, force @ axis)
    quiet = base.quiet
    lines = [robust_line(t[quiet], force[quiet, k]) for k in range(3)] if quiet.sum() >= 2 else []
    rest = np.stack([line.at(t) for line in lines], axis=1) if lines else np.median(force, axis=0)
    change = force - rest
    active = np.abs(change @ axis) > QUIET_SIGMAS * base.sigma
    if active.sum() >= 2:
        axis = principal_axis(change[active])
    if np.sum(change[active] @ axis) < 0:
        axis = -axis
    return axis, force @ axis, False


def principal_axis(samples: FloatArray) -> FloatArray:
    """First right singular vector of (M, 3) samples: the direction of most of their energy."""
    _, _, vt = np.linalg.svd(samples, full_matrices=False)
    return np.asarray(vt[0], dtype=np.float64)


def noise_floor(values: FloatArray) -> float:
    """Smallest noise SD worth believing: the quantisation step's, or a tiny fraction of the values."""
    steps = np.abs(np.diff(values))
    steps = steps[steps > 0]
    quantum = float(steps.min()) / math.sqrt(12.0) if steps.size else 0.0
    return max(quantum, 1e-12 * max(1.0, float(np.max(np.abs(values)))))


def difference_noise(values: FloatArray) -> float:
    """Noise SD from the MAD of second differences: blind to slow changes, steps and short pulses."""
    second = np.diff(values, 2)
    return max(MAD_TO_SD * float(np.median(np.abs(second))) / math.sqrt(6.0), noise_floor(values))


def baseline(t: FloatArray, values: FloatArray) -> Baseline:
    """The quiet samples and the robust line through them, starting from the level the record ends at.

    A sample is quiet when it lies within :data:`QUIET_SIGMAS` noise SDs of the line and outside the
    feet of any excursion beyond them (:func:`_excursions`); the noise is the MAD of the quiet samples
    about the line. Three rounds.
    """
    n = values.size
    sigma = difference_noise(values)
    rest, count = _resting_level(t, values, sigma)
    line = Line(float(np.mean(t)), rest, 0.0, sigma, count, float(count), math.inf)
    quiet = np.ones(n, dtype=bool)
    dt = float(np.median(np.diff(t)))
    for _ in range(3):
        candidate = ~_excursions(values - line.at(t), sigma=sigma, dt=dt)
        if candidate.sum() < MIN_SAMPLES:
            break
        quiet = candidate
        line = robust_line(t[quiet], values[quiet])
        sigma = max(line.sigma, noise_floor(values))
    return Baseline(level=line.at(t), quiet=quiet, sigma=sigma, line=line)


def _excursions(residual: FloatArray, *, sigma: float, dt: float) -> NDArray[np.bool_]:
    """Samples (N,) in an excursion from the baseline: beyond :data:`QUIET_SIGMAS` noise SDs, widened to
    where its 10-ms running mean falls within 3 of that mean's SDs of the baseline, and by 5 ms more."""
    active = np.abs(residual) > QUIET_SIGMAS * sigma
    width = max(5, round(0.01 / dt) | 1)
    smooth = np.convolve(residual, np.ones(width) / width, mode="same")
    hits = np.concatenate([[0], np.cumsum(active)])
    wide = np.zeros_like(active)
    for first, last in runs(active | (np.abs(smooth) > 3 * sigma / math.sqrt(width)), gap=0):
        wide[first : last + 1] = hits[last + 1] > hits[first]
    pad = max(2, round(0.005 / dt))
    return np.convolve(wide, np.ones(2 * pad + 1), mode="same") > 0


def _resting_level(t: FloatArray, values: FloatArray, sigma: float) -> tuple[float, int]:
    """Median of the last flat stretch of about 50 ms (the force after the release or the strike), and
    its sample count. Flat: its MAD-SD within twice the smallest such SD (or the noise) of the record."""
    n = values.size
    size = min(n, max(MIN_SAMPLES, round(0.05 / float(np.median(np.diff(t))))))
    blocks = values[n % size :].reshape(-1, size)
    centre = np.median(blocks, axis=1)
    spread = MAD_TO_SD * np.median(np.abs(blocks - centre[:, None]), axis=1)
    flat = np.flatnonzero(spread <= 2 * max(float(spread.min()), sigma))
    return float(centre[flat[-1]]), size


def robust_line(t: FloatArray, y: FloatArray) -> Line:
    """Straight line through (t, y) by Huber-weighted least squares; the noise is the residuals' MAD."""
    t_mean = float(np.mean(t))
    x = t - t_mean
    weights = np.ones_like(y)
    intercept, slope = float(np.median(y)), 0.0
    for _ in range(8):
        total = float(weights.sum())
        xm, ym = float(weights @ x) / total, float(weights @ y) / total
        sxx = float(weights @ (x - xm) ** 2)
        slope = float(weights @ ((x - xm) * (y - ym))) / sxx if sxx > 0 else 0.0
        intercept = ym - slope * xm
        residual = y - intercept - slope * x
        scale = MAD_TO_SD * float(np.median(np.abs(residual)))
        if scale <= 0:
            break
        weights = np.minimum(1.0, 1.345 * scale / np.maximum(np.abs(residual), 1e-300))
    residual = y - intercept - slope * x
    sigma = MAD_TO_SD * float(np.median(np.abs(residual - np.median(residual))))
    sxx_plain = float(np.sum(x**2))
    return Line(t_mean, intercept, slope, sigma, y.size, effective_count(residual), sxx_plain or math.inf)


def runs(mask: NDArray[np.bool_], *, gap: int = 2) -> list[tuple[int, int]]:
    """First and last index of each run of True, runs closer than ``gap`` samples joined."""
    index = np.flatnonzero(mask)
    if index.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(index) > gap + 1)
    starts = np.concatenate([[index[0]], index[breaks + 1]])
    ends = np.concatenate([index[breaks], [index[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]
