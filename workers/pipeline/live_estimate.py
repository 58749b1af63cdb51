"""A live estimate: the record of the main object's figures from the frames so far, its JSON form, and how
few samples widen its frequency's interval (:mod:`workers.pipeline.live` makes the estimates and judges
their convergence)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

#: Two-sided 97.5 % quantiles of Student's t for 1..30 degrees of freedom (beyond: the normal's 1.96).
_T975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
    2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
    2.045, 2.042,
)  # fmt: skip
#: Relative frequency floor of a live estimate: the live signal is the mean flow of the moving region
#: (no registration), whose residual errors correlate with the motion more than the full analysis's.
LIVE_FREQUENCY_REL_FLOOR = 1e-3


def few_samples_factor(samples: int) -> float:
    """How much wider a 95 % interval is from ``samples`` fitted samples than from many: the fit's standard
    error assumes many, an early estimate has few degrees of freedom (five parameters fitted), Student's
    t over the normal's 1.96."""
    dof = max(samples - 5, 1)
    return (_T975[dof - 1] if dof <= len(_T975) else 1.959964) / 1.959964


@dataclass(frozen=True, kw_only=True)
class LiveEstimate:
    """The main object's figures from the frames so far. Frequencies in Hz, lengths in metres unless
    ``_px``; every ``*_uncertainty*`` is a standard uncertainty; None where not measurable.

    Attributes
    ----------
    frames_received : int
        Frames pushed so far.
    frames_used : (first, last)
        Frame indices [first, last) whose flow the estimate used.
    samples_after_release : int
        Flow samples fitted (from the release on).
    release_time_s : float
        Capture time of the release (the first moving sample), seconds from the first frame.
    periods : float
        Periods of motion fitted.
    relative_uncertainty : float
        ``eigenfrequency_uncertainty_hz / eigenfrequency_hz``.
    converged : bool
        Whether the convergence rule holds (see the module docstring).
    """

    frames_received: int
    frames_used: tuple[int, int]
    samples_after_release: int
    release_time_s: float
    periods: float
    eigenfrequency_hz: float
    eigenfrequency_uncertainty_hz: float
    natural_frequency_hz: float
    damping_ratio: float
    damping_ratio_uncertainty: float
    amplitude_px: float
    amplitude_m: float | None
    amplitude_uncertainty_m: float | None
    depth_m: float | None
    stiffness_n_per_m: float | None
    stiffness_uncertainty_n_per_m: float | None
    mass_kg: float | None
    mass_uncertainty_kg: float | None
    snr_db: float
    relative_uncertainty: float
    converged: bool
    null_reasons: tuple[str, ...] = ()

    def interval_hz(self, level: float = 0.95) -> tuple[float, float]:
        """The frequency's ``level`` interval (normal), Hz; only 0.95 and 0.68 are tabulated."""
        z = {0.95: 1.959964, 0.68: 0.994458}[level]
        return (
            self.eigenfrequency_hz - z * self.eigenfrequency_uncertainty_hz,
            self.eigenfrequency_hz + z * self.eigenfrequency_uncertainty_hz,
        )


def estimate_dict(est: LiveEstimate) -> dict[str, Any]:
    """A :class:`LiveEstimate` as JSON-ready data (NaN and infinity become None)."""
    out: dict[str, Any] = {}
    for key, value in est.__dict__.items():
        if isinstance(value, float) and not math.isfinite(value):
            value = None
        elif isinstance(value, tuple):
            value = list(value)
        out[key] = value
    return out


__all__ = ["LIVE_FREQUENCY_REL_FLOOR", "LiveEstimate", "estimate_dict", "few_samples_factor"]
