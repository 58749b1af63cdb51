"""The law of the detection statistic under "nothing moves here", fitted on the clip's own frequencies
(:mod:`workers.pipeline.significance` computes the statistic T).

log T over the band's frequencies (the surrogates) first loses its slow course (:func:`_trend`); the
rest is fitted by a Gumbel law, robustly: frequencies near known artefacts and those that stand out are
left out, in rounds. The fit gives each frequency's standardised height ``z`` and its false-alarm
probability; the probability *per clip* allows for every frequency searched. How far the stated rate is
from the measured one: ``bench/calibration.py`` (simulated noise) and ``bench/null_corpus.py`` (still
footage through the codecs).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.peaks import noise_floor

#: The fitted scale of log T is never below this: the largest of even a million independent noise values
#: varies by about a tenth of its logarithm (a fit on few frequencies can say less; it would overstate
#: every peak's significance).
MIN_SCALE = 0.1
#: Below this many frequencies fitted, the calibration allows for its own uncertainty (see
#: :func:`fit_calibration`).
MIN_SURROGATES = 48
#: Frequencies standing this many standardised units above the fit are left out of the next fit.
FIT_OUTLIER_Z = 3.0
#: Frequencies within this many bins of a known artefact frequency are left out of the fit.
ARTEFACT_BINS = 1.6
#: The calibration follows log T's slow course over the band with a running median this wide (bins), or a
#: third of the band when that is wider; on a band narrower than twice this, with a parabola ...
TREND_WIDTH_BINS = 15
#: ... down to a band of this many bins (a 64-frame window at 30 fps holds 29): below it the law is
#: fitted to log T as it is (and when fewer than :data:`MIN_TREND_SURROGATES` frequencies are left to fit
#: the law beside a parabola).
MIN_TREND_BINS = 24
MIN_TREND_SURROGATES = 20


@dataclass(frozen=True)
class Calibration:
    """The Gumbel law of log T fitted over the band's frequencies.

    Attributes
    ----------
    location, scale : float
        Of log T over its trend: ``z = (log T - trend - location) / scale``.
    bins_fitted : int
        Frequencies the fit used.
    bins_searched : int
        Frequencies of the band (the per-clip probability allows for each).
    trend : ndarray of float64, shape (B,), or None
        The slow course of log T over the band (a running median over :data:`TREND_WIDTH_BINS`): the
        noise's level drifts over frequency (more flow noise at low frequencies, a codec's at high ones);
        a line stands out of its neighbourhood, not of the band's average.
    """

    location: float
    scale: float
    bins_fitted: int
    bins_searched: int
    trend: NDArray[np.float64] | None = None

    def z(self, statistic: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Standardised heights of T over the band's bins (an array of the band's length when there is a
        trend)."""
        log_t = np.log(np.maximum(np.asarray(statistic, np.float64), 1e-30))
        if self.trend is not None:
            log_t = log_t - self.trend
        return np.asarray((log_t - self.location) / self.scale, np.float64)

    def p_frequency(self, z: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Probability that noise reaches ``z`` at one frequency (the Gumbel survival function)."""
        zz = np.clip(np.asarray(z, np.float64), -50.0, 700.0)
        return np.asarray(-np.expm1(-np.exp(-zz)), np.float64)

    def p_clip(self, z: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Probability that noise reaches ``z`` at any of the band's frequencies."""
        p = self.p_frequency(z)
        m = self.bins_searched
        whole = -np.expm1(m * np.log1p(-np.minimum(p, 1 - 1e-16)))
        return np.asarray(np.where(p < 1e-9, np.minimum(m * p, 1.0), whole), np.float64)


def _kept_bins(frequencies_hz: NDArray[np.float64], exclude_hz: Sequence[float]) -> NDArray[np.bool_]:
    """The bins the fit may use: those away from the known artefacts (all, when they would be too few)."""
    bins = len(frequencies_hz)
    bin_hz = float(frequencies_hz[1] - frequencies_hz[0]) if bins > 1 else 1.0
    keep = np.ones(bins, bool)
    for f in exclude_hz:
        keep &= np.abs(frequencies_hz - f) > ARTEFACT_BINS * bin_hz
    return keep if keep.sum() >= max(8, bins // 4) else np.ones(bins, bool)


def fit_calibration(
    statistic: NDArray[np.float64],
    *,
    frequencies_hz: NDArray[np.float64],
    exclude_hz: Sequence[float] = (),
    rounds: int = 3,
    tiles: NDArray[np.float64] | None = None,
) -> Calibration:
    """Fit the Gumbel law of log T over the band's frequencies (the clip's own surrogates).

    log T first loses its slow course over the band (:func:`_trend`). The location and scale come from
    the quantiles of what is left: the interquartile range (1.5725 scales of a Gumbel law), or the 10 %
    to 50 % range (1.2007 scales) when that says less (an object lifting many frequencies lifts the upper
    quartile, never the lower). Left out of the fit: frequencies near ``exclude_hz``; in each of
    ``rounds`` rounds those standing :data:`FIT_OUTLIER_Z` above the last fit, with two neighbours each
    side (a peak's skirt); below :data:`MIN_SURROGATES` frequencies fitted, the law allows for its own
    uncertainty. On Gumbel noise independent from bin to bin the per-clip rate so stated is optimistic
    (the trimmed fit narrows its own tail: at a stated 10⁻³, about 10⁻² are measured on 29 to 125 bins);
    the rate measured on still footage (``bench/null_corpus.py``) is what holds it to account: on 77
    still clips through H.264 and MPEG-4 and still crops of real footage, no line but the codecs' keyframe
    combs (set aside as artefacts) and a real fork's reaching into a crop came below 10⁻², and at stated
    rates of 0.05 to 0.5 the measured ones were 0.026 to 0.195 (``bench/README.md``). And,
    given ``tiles`` (the statistic of each of K tiles of the picture, (K, B)), the tiles where something
    stands out at any frequency, while at least two (or an eighth) remain: a strong object's broad skirt
    lifts the picture's T over many frequencies, but only in its own tiles. T is then the largest of the
    other tiles', and its law's location moves up by ``scale * log(K / K_other)`` (the law of the largest
    of K).

    Parameters
    ----------
    statistic : ndarray of float64, shape (B,)
    frequencies_hz : ndarray of float64, shape (B,)
    exclude_hz : sequence of float
    rounds : int
    tiles : ndarray of float64, shape (K, B), optional

    Returns
    -------
    Calibration
    """
    keep = _kept_bins(frequencies_hz, exclude_hz)
    series, shift = np.asarray(statistic, np.float64), 0.0
    if tiles is not None and len(tiles) >= 4:
        quiet = _quiet_tiles(tiles, keep)
        if len(tiles) > quiet.sum() >= max(2, len(tiles) // 8):
            series, shift = tiles[quiet].max(axis=0), math.log(len(tiles) / quiet.sum())
    log_t = np.log(np.maximum(series, 1e-30))
    trend = _trend(log_t, keep)
    location, scale, use = _fit_law(log_t if trend is None else log_t - trend, keep, rounds)
    if trend is not None and len(log_t) < 2 * TREND_WIDTH_BINS and use.sum() < MIN_TREND_SURROGATES:
        # Too few surrogates left to tell a parabola's course from the noise's own spread.
        trend = None
        location, scale, use = _fit_law(log_t, keep, rounds)
    fitted = max(int(use.sum()), 1)
    if fitted < MIN_SURROGATES:
        # A law fitted on few surrogates (a short window) is itself uncertain (its median to about 1.25
        # scales / sqrt(n), its quartiles' spread to about a relative 1 / sqrt(n)): take the upper end of
        # both.
        location += 1.25 * scale / math.sqrt(fitted)
        scale *= 1 + 1 / math.sqrt(fitted)
    return Calibration(
        location=location + scale * shift,
        scale=scale,
        bins_fitted=int(use.sum()),
        bins_searched=len(frequencies_hz),
        trend=trend,
    )


def _fit_law(
    log_t: NDArray[np.float64], keep: NDArray[np.bool_], rounds: int
) -> tuple[float, float, NDArray[np.bool_]]:
    """The Gumbel law's location and scale from the quantiles of ``log_t`` (see :func:`fit_calibration`),
    and the frequencies fitted."""
    use = keep.copy()
    least = max(8, int(keep.sum()) // 4)
    location, scale = 0.0, 1.0
    for _ in range(rounds):
        q10, q25, q50, q75 = np.percentile(log_t[use], [10, 25, 50, 75])
        # The interquartile range, unless the lower half says less (an object lifting many frequencies
        # lifts the upper quartile, never the lower): a Gumbel law's 10 % to 50 % quantiles span 1.2007
        # scales, its quartiles 1.5725.
        scale = max(min(float(q75 - q25) / 1.5725, float(q50 - q10) / 1.2007), MIN_SCALE)
        location = float(q50) + scale * math.log(math.log(2))  # a Gumbel law's median: location + 0.37 scale
        high = (log_t - location) / scale > FIT_OUTLIER_Z
        skirt = np.convolve(high.astype(np.float64), np.ones(5), mode="same") > 0
        nxt = keep & ~skirt
        if nxt.sum() < least:
            break
        use = nxt
    return location, scale, use


def _trend(log_t: NDArray[np.float64], keep: NDArray[np.bool_]) -> NDArray[np.float64] | None:
    """log T's slow course over the band, centred on 0: a running median over :data:`TREND_WIDTH_BINS`
    (or a third of the band); on a band of :data:`MIN_TREND_BINS` to twice that width, a parabola fitted
    robustly (what stands out above it left out, in rounds): a running median as wide as half the band
    would follow the noise itself and understate its spread, where three parameters hardly do. None on a
    narrower band."""
    bins = len(log_t)
    if bins >= 2 * TREND_WIDTH_BINS:
        slow = np.asarray(noise_floor(log_t, width=max(TREND_WIDTH_BINS, bins // 3)), np.float64)
        return slow - float(np.median(slow))
    if bins < MIN_TREND_BINS:
        return None
    x = np.linspace(-1.0, 1.0, bins)
    # First through the lower half of the band's values (what an object lifts is its upper half), then
    # through every frequency that does not stand out above that.
    use = keep & (log_t <= np.median(log_t[keep]))
    coef = np.polyfit(x[use], log_t[use], 2)
    for _ in range(3):
        residual = log_t - np.polyval(coef, x)
        centre = float(np.median(residual[use]))
        spread = 1.4826 * float(np.median(np.abs(residual[use] - centre))) + 1e-9
        nxt = keep & (residual <= centre + FIT_OUTLIER_Z * spread)
        if nxt.sum() < MIN_TREND_BINS // 2:
            break
        use = nxt
        coef = np.polyfit(x[use], log_t[use], 2)
    fitted = np.asarray(np.polyval(coef, x), np.float64)
    return fitted - float(np.median(fitted))


def _quiet_tiles(tiles: NDArray[np.float64], keep: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """The tiles where nothing stands out: at no frequency does a tile rise above the median tile there
    by more than :data:`FIT_OUTLIER_Z` + log(B) robust units (interquartile ranges over 1.5725) of how
    tiles differ (the largest of B such differences stands about log(B) above their median)."""
    log_t = np.log(np.maximum(tiles[:, keep], 1e-30))
    above = log_t - np.median(log_t, axis=0)[None, :]
    q25, q50, q75 = np.percentile(above, [25, 50, 75])
    spread = max(float(q75 - q25) / 1.5725, 1e-3)
    z = (above - q50) / spread
    return np.asarray(z.max(axis=1) <= FIT_OUTLIER_Z + math.log(max(log_t.shape[1], 1)), bool)


__all__ = ["Calibration", "fit_calibration"]
