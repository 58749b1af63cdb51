"""An object's ring-down fitted from its release: where its motion starts, and a fit that stays on the line
the object was found at.

:class:`ReleaseFitter` fits :func:`~workers.pipeline.ringdown.fit_ringdown` to a tracked motion from the first
sample in which it moves (:func:`~workers.pipeline.mechanics.detect_release`), or from the end of a release a
force sensor recorded (:class:`FitHints`); :mod:`workers.pipeline.tracking` calls it on each motion it
measures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.mechanics import detect_release
from workers.pipeline.ringdown import RingdownFit, fit_ringdown

#: Fewest flow samples a ring-down fit keeps after the end of a recorded release (a release that ends near
#: the window's end is fitted over its last samples).
MIN_FIT_SAMPLES = 16
#: A fit is on its object's line when within this many bins of the window's transform of it ...
LINE_BINS = 2.0
#: ... or within this many of a harmonic relation of it (n times, or one n-th), up to this order (a fit
#: that converges on a harmonic relation lands within a fraction of a bin of it).
RELATION_BINS = 1.0
MAX_RELATION = 5
#: A fit off its line is made again from these many periods of the line later (the first on it is kept) ...
LATER_STARTS = (1.0, 2.0, 4.0)
#: ... when the line is resolved: the fit's samples span this many of its periods. (A few periods, a live
#: stream stopped early, make the scan's line broad and its peak a poor guess, 2.3 Hz for a 4.5 Hz ring-down
#: over 40 frames at 30 fps; the first fit is the better estimate there.)
RESOLVED_PERIODS = 10.0


@dataclass(frozen=True)
class FitHints:
    """What an object's ring-down fit starts from.

    Attributes
    ----------
    frequency_guess_hz : float
        The object's frequency as its spectrum shows it.
    band_hz : (low, high) or None
        The band searched.
    free_from_s : float or None
        Window clock (the frame times' origin): from when the object moves freely, when a force sensor
        recorded the end of the release or the strike; None: from when it is first seen moving.
    """

    frequency_guess_hz: float
    band_hz: tuple[float, float] | None = None
    free_from_s: float | None = None


@dataclass(frozen=True)
class ReleaseFitter:
    """Fits the ring-down of a motion from its release (:func:`fit_ringdown` with the window's settings).

    Attributes
    ----------
    sample_rate_hz : float
        Rate of the flow samples, Hz.
    hints : FitHints
    times_s : ndarray of float64, shape (N + 1,)
        The window's frame times.
    """

    sample_rate_hz: float
    hints: FitHints
    times_s: NDArray[np.float64]

    def __call__(self, signal: NDArray[np.float64]) -> tuple[int, RingdownFit]:
        """The release (first sample of the motion) of ``signal`` (N,) and the ring-down fitted from it:
        from the first sample in which it moves, or, when a force sensor saw the release end later (a
        release that takes time drives the object on the way), from there.

        A fit off the object's line (neither at it within :data:`LINE_BINS` bins nor a harmonic relation
        of it) was taken by something else at the start: a codec's start-up, whose rate control draws a
        thin bar only after a few frames, makes a jump there that the fit follows (17 Hz fitted to a bar
        steady at 41 Hz through H.264). When the line is resolved (:data:`RESOLVED_PERIODS`), the fit is
        then made again from :data:`LATER_STARTS` periods of the line later, and the first one on the line
        is kept; none on it, the first fit stands."""
        start = detect_release(signal)
        if self.hints.free_from_s is not None:
            free = int(np.searchsorted(self.times_s, self.hints.free_from_s))
            start = max(start, min(free, len(signal) - MIN_FIT_SAMPLES))
        fit = self._fit(signal, start)
        period = self.sample_rate_hz / self.hints.frequency_guess_hz
        if (len(signal) - start) < RESOLVED_PERIODS * period or self._on_line(fit.frequency_hz, len(signal)):
            return start, fit
        for periods in LATER_STARTS:
            later = start + round(periods * period)
            if later > len(signal) - MIN_FIT_SAMPLES:
                break
            refit = self._fit(signal, later)
            if self._on_line(refit.frequency_hz, len(signal)):
                return later, refit
        return start, fit

    def _fit(self, signal: NDArray[np.float64], start: int) -> RingdownFit:
        return fit_ringdown(
            signal,
            sample_rate_hz=self.sample_rate_hz,
            frequency_guess_hz=self.hints.frequency_guess_hz,
            start_index=start,
            frame_times_s=self.times_s,
            band_hz=self.hints.band_hz,
        )

    def _on_line(self, frequency_hz: float, samples: int) -> bool:
        """Whether ``frequency_hz`` is the line the object was found at, or a harmonic relation of it
        (its rate beside its marks' passing, a second harmonic fitted for the first)."""
        guess = self.hints.frequency_guess_hz
        bin_hz = self.sample_rate_hz / max(samples, 1)
        if abs(frequency_hz - guess) <= LINE_BINS * bin_hz:
            return True
        orders = range(2, MAX_RELATION + 1)
        return any(
            abs(frequency_hz - guess * r) <= RELATION_BINS * bin_hz for n in orders for r in (n, 1 / n)
        )


__all__ = [
    "LATER_STARTS",
    "LINE_BINS",
    "MAX_RELATION",
    "MIN_FIT_SAMPLES",
    "RELATION_BINS",
    "RESOLVED_PERIODS",
    "FitHints",
    "ReleaseFitter",
]
