"""Stiffness, mass and damping of a forced vibration: the frequency response between the force a sensor
recorded and the motion the camera saw, identified as one degree of freedom.

A robot (or a shaker) that keeps pushing gives no release and no strike; but the force it applied is
recorded, and the object's motion follows it through its frequency response

    H(ω) = X(ω) / F(ω) = 1 / (k - m ω² + i c ω).

:func:`fit_response` identifies k, m and c from the two records. It fits the response in the time domain
(the output-error form of the same transfer function): the recorded force drives m x'' + c x' + k x = F,
simulated on the force's own samples, and the simulated motion, read at the frames' instants, is fitted to
the measured one. Compared with a spectral estimate of H from averaged segments (H1), this uses every
sample, needs no segments long enough to resolve the resonance, and is not biased by the leakage of a
window shorter than the decay. The motion's own start (the object at rest, or already moving when the
frames begin) is a free response, fitted with the rest, and so is the slow drift of a displacement
integrated from flow.

What the data must show, else a :class:`~workers.pipeline.errors.ForceError` says why and what to do:

- the force and the motion overlap for at least :data:`MIN_PERIODS` periods;
- the force explains at least :data:`MIN_EXPLAINED` of the motion's variance;
- k and m come out within :data:`MAX_REL_SD` relative standard uncertainty each. A force at one steady
  frequency, with no transient in the window, shows one point of H(ω): two numbers for three unknowns,
  and the fit says so through these uncertainties.

Conventions: seconds on the clip's clock, newtons, metres; uncertainties standard (1 σ).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, signal

from workers.pipeline.errors import ForceError
from workers.pipeline.lstsq import effective_count

FloatArray = NDArray[np.float64]

#: Fewest periods (at the object's frequency) in which both the force and the motion were recorded.
MIN_PERIODS = 4.0
#: Least share of the motion's variance (about its fitted drift) that the force must explain.
MIN_EXPLAINED = 0.5
#: Largest relative standard uncertainty of k and of m for the fit to be reported.
MAX_REL_SD = 0.2
#: Least noise assumed per frame, as a share of the motion's RMS: the camera's displacement and the force
#: sensor's samples (a force known only at its samples, interpolated between them) are not a better model
#: than this, whatever the residuals say; below it, the model's own small errors would pose as
#: information (a single steady tone would seem to determine k and m).
MOTION_FLOOR = 0.01
#: The profile test (:func:`_profile_holds`): a stiffness MAX_REL_SD away must fit worse by this many noise
#: units (Δχ² of two standard deviations): the free response fitting the noise makes a flat valley look
#: curved by about one unit.
PROFILE_CHI2 = 4.0
#: The coarse search's grid: natural frequencies as ratios of the object's measured one, damping ratios.
_FREQUENCY_RATIOS = np.geomspace(0.7, 1.4, 15)
_DAMPING_RATIOS = (0.003, 0.01, 0.03, 0.1, 0.3)


@dataclass(frozen=True)
class ResponseFit:
    """One degree of freedom identified from a force and a motion.

    Attributes
    ----------
    stiffness_n_per_m, stiffness_uncertainty_n_per_m : float
    mass_kg, mass_uncertainty_kg : float
    damping_n_s_per_m, damping_uncertainty_n_s_per_m : float
        The viscous damping coefficient c.
    natural_frequency_hz, natural_frequency_uncertainty_hz : float
        √(k/m) / 2π.
    damping_ratio, damping_ratio_uncertainty : float
        c / (2 √(k m)).
    explained : float
        Share of the motion's variance (about its drift and free response) that the force explains.
    frames : int
        Frames fitted.
    """

    stiffness_n_per_m: float
    stiffness_uncertainty_n_per_m: float
    mass_kg: float
    mass_uncertainty_kg: float
    damping_n_s_per_m: float
    damping_uncertainty_n_s_per_m: float
    natural_frequency_hz: float
    natural_frequency_uncertainty_hz: float
    damping_ratio: float
    damping_ratio_uncertainty: float
    explained: float
    frames: int


def fit_response(
    force_times_s: FloatArray,
    force_n: FloatArray,
    frame_times_s: FloatArray,
    displacement_m: FloatArray,
    *,
    frequency_hz: float,
) -> ResponseFit:
    """Fit m x'' + c x' + k x = F to a recorded force and the measured motion.

    Parameters
    ----------
    force_times_s : ndarray, shape (M,), float64
        The force's sample times, strictly increasing, clip clock (seconds).
    force_n : ndarray, shape (M,), float64
        The force along the object's motion, newtons (its sign and offset do not matter).
    frame_times_s : ndarray, shape (N,), float64
        Instants of the displacement samples, clip clock.
    displacement_m : ndarray, shape (N,), float64
        The object's displacement along its motion, metres (offset and slow drift do not matter).
    frequency_hz : float
        The object's frequency as the motion shows it: where the search starts.

    Returns
    -------
    ResponseFit

    Raises
    ------
    ForceError
        When the records overlap too little, the force does not explain the motion, or k and m are not
        determined (see the module's docstring); the message gives the figures and the fix.
    """
    t_f = np.asarray(force_times_s, np.float64)
    f = np.asarray(force_n, np.float64)
    t_x = np.asarray(frame_times_s, np.float64)
    x = np.asarray(displacement_m, np.float64)
    inside = (t_x >= t_f[0]) & (t_x <= t_f[-1]) & np.isfinite(x)
    t_x, x = t_x[inside], x[inside]
    periods = (t_x[-1] - t_x[0]) * frequency_hz if t_x.size >= 2 else 0.0
    if periods < MIN_PERIODS or t_x.size < 8:
        raise ForceError(
            f"the force and the motion overlap for {periods:.1f} periods of the object's {frequency_hz:.3g} "
            f"Hz; a forced vibration needs at least {MIN_PERIODS:.0f}: record the force over the frames"
        )
    problem = _Problem.build(t_f, f, t_x, x)
    best = _search(problem, frequency_hz)
    return _result(problem, best, frequency_hz)


@dataclass(frozen=True)
class _Problem:
    """The force on a uniform grid from just before the first frame, and the motion to fit."""

    grid_s: FloatArray
    force: FloatArray
    t_x: FloatArray
    x: FloatArray

    @classmethod
    def build(cls, t_f: FloatArray, f: FloatArray, t_x: FloatArray, x: FloatArray) -> _Problem:
        dt = float(np.median(np.diff(t_f)))
        grid = np.arange(t_f[0], t_f[-1] + dt / 2, dt)
        force = np.interp(grid, t_f, f)
        return cls(grid, force - float(np.median(force)), t_x, x)

    def columns(self, omega: float, zeta: float) -> FloatArray:
        """Regressors (N, 5): the unit-stiffness forced response (x k), the two free responses from the
        first frame on, an offset and a drift.

        The free responses are the same discrete recursion's, started from unit states at the first frame:
        a motion already under way, or a response the record's start cut short, is cancelled exactly.
        """
        dt = float(self.grid_s[1] - self.grid_s[0])
        num, den, _ = signal.cont2discrete(([omega**2], [1.0, 2 * zeta * omega, omega**2]), dt, method="foh")
        num = np.ravel(num)
        driven = np.interp(self.t_x, self.grid_s, signal.lfilter(num, den, self.force))
        start = int(np.searchsorted(self.grid_s, self.t_x[0], side="right")) - 1
        quiet = np.zeros(self.grid_s.size - start)
        free = [
            np.interp(self.t_x, self.grid_s[start:], signal.lfilter(num, den, quiet, zi=state)[0])
            for state in np.eye(2)
        ]
        tau = self.t_x - self.t_x[0]
        return np.stack([driven, *free, np.ones_like(tau), tau], axis=1)

    def solve(self, omega: float, zeta: float, *, gain: float | None = None) -> tuple[FloatArray, FloatArray]:
        """Linear coefficients (5,) and residuals (N,) at (ω, ζ); with ``gain`` the first (1 / k) is held."""
        design = self.columns(omega, zeta)
        target = self.x if gain is None else self.x - gain * design[:, 0]
        free = design if gain is None else design[:, 1:]
        scale = np.maximum(np.linalg.norm(free, axis=0), 1e-300)
        coef = np.linalg.lstsq(free / scale, target, rcond=None)[0] / scale
        if gain is not None:
            coef = np.concatenate([[gain], coef])
        return coef, self.x - design @ coef


def _search(problem: _Problem, frequency_hz: float) -> tuple[float, float]:
    """(ω, ζ) minimising the residual, the linear coefficients projected out: the best point of a coarse
    grid around the measured frequency, refined by least squares."""

    def residual(p: FloatArray) -> FloatArray:
        return problem.solve(math.exp(p[0]), p[1])[1]

    omega0 = 2 * math.pi * frequency_hz
    grid = [(omega0 * r, z) for r in _FREQUENCY_RATIOS for z in _DAMPING_RATIOS]
    costs = [float(np.sum(problem.solve(w, z)[1] ** 2)) for w, z in grid]
    omega, zeta = grid[int(np.argmin(costs))]
    found = _refine(residual, np.array([math.log(omega), zeta]))
    return math.exp(float(found.x[0])), float(found.x[1])


def _refine(residual: Callable[[FloatArray], FloatArray], start: FloatArray) -> Any:
    """Least squares over (log ω, ζ) from ``start``, ζ kept in [1e-4, 0.95]."""
    bounds = ([-np.inf, 1e-4], [np.inf, 0.95])
    return optimize.least_squares(residual, start, bounds=bounds, x_scale=[0.01, 0.01])


def _result(problem: _Problem, found: tuple[float, float], frequency_hz: float) -> ResponseFit:
    omega, zeta = found
    coef, res = problem.solve(omega, zeta)
    design = problem.columns(omega, zeta)
    gain = float(coef[0])  # metres per newton: 1 / k
    nuisance = design[:, 1:] @ coef[1:]
    motion = problem.x - nuisance
    explained = 1.0 - float(res @ res) / max(float(motion @ motion), 1e-300)
    if explained < MIN_EXPLAINED or gain == 0.0:
        raise ForceError(
            f"the recorded force explains {max(explained, 0.0) * 100:.0f} % of the object's motion (at least "
            f"{MIN_EXPLAINED * 100:.0f} % needed): the force was not what moved it, or it was recorded "
            "along another direction or clock; record the force at the object, or give --force-n / "
            "--impulse-ns"
        )
    cov = _covariance(problem, omega, zeta, coef, res)
    k = 1.0 / abs(gain)
    m = k / omega**2
    c = 2.0 * zeta * omega * m
    # Gradients of log k, log m, log c and of ω, ζ with respect to (ω, ζ, gain).
    d_logk = np.array([0.0, 0.0, -1.0 / gain])
    d_logm = np.array([-2.0 / omega, 0.0, -1.0 / gain])
    d_logc = np.array([-1.0 / omega, 1.0 / zeta, -1.0 / gain])
    rel_k, rel_m, rel_c = (_spread(g, cov) for g in (d_logk, d_logm, d_logc))
    determined = rel_k <= MAX_REL_SD and rel_m <= MAX_REL_SD
    if not (determined and _profile_holds(problem, (omega, zeta), coef, res)):
        why = (
            f"relative uncertainty {rel_k:.0%} and {rel_m:.0%}, at most {MAX_REL_SD:.0%} needed"
            if not determined
            else f"a stiffness {MAX_REL_SD:.0%} away explains the motion as well"
        )
        raise ForceError(
            f"the force and the motion do not determine stiffness and mass ({why}): a force at one steady "
            "frequency shows one point of the frequency response; drive the object across its resonance (a "
            "sweep or a random force), record the start of the forcing, or push, hold and release it"
        )
    return ResponseFit(
        stiffness_n_per_m=k,
        stiffness_uncertainty_n_per_m=k * rel_k,
        mass_kg=m,
        mass_uncertainty_kg=m * rel_m,
        damping_n_s_per_m=c,
        damping_uncertainty_n_s_per_m=c * rel_c,
        natural_frequency_hz=omega / (2 * math.pi),
        natural_frequency_uncertainty_hz=_spread(np.array([1.0, 0.0, 0.0]), cov) / (2 * math.pi),
        damping_ratio=zeta,
        damping_ratio_uncertainty=_spread(np.array([0.0, 1.0, 0.0]), cov),
        explained=explained,
        frames=int(problem.x.size),
    )


def _profile_holds(problem: _Problem, found: tuple[float, float], coef: FloatArray, res: FloatArray) -> bool:
    """Whether the data rule out a stiffness :data:`MAX_REL_SD` away on either side: the residual with
    1 / k held there, (ω, ζ) refitted, exceeds the best by at least :data:`PROFILE_CHI2` noise units (the
    noise per independent sample). The local uncertainties can miss a valley of the cost that bends (a
    force at one frequency), or find a false curvature in it where the free response fits the noise; this
    cannot."""
    ssr = float(res @ res)
    unit = _noise_variance(problem, res)
    start = np.array([math.log(found[0]), found[1]])
    for factor in (1.0 + MAX_REL_SD, 1.0 / (1.0 + MAX_REL_SD)):
        gain = float(coef[0]) / factor

        def residual(p: FloatArray, gain: float = gain) -> FloatArray:
            return problem.solve(math.exp(p[0]), p[1], gain=gain)[1]

        held = _refine(residual, start)
        if 2.0 * float(held.cost) - ssr < PROFILE_CHI2 * unit:
            return False
    return True


def _noise_variance(problem: _Problem, res: FloatArray) -> float:
    """Variance per sample of the motion's noise, scaled up for the residuals' correlation (n / n_eff),
    at least :data:`MOTION_FLOOR` of the motion's RMS (its drift and mean removed)."""
    n = problem.x.size
    variance = float(res @ res) / max(n - 7, 1) * n / effective_count(res)
    tau = problem.t_x - problem.t_x[0]
    trend = np.polyval(np.polyfit(tau, problem.x, 1), tau)
    floor = MOTION_FLOOR**2 * float(np.mean((problem.x - trend) ** 2))
    return max(variance, floor)


def _spread(gradient: FloatArray, cov: FloatArray) -> float:
    """Standard uncertainty of a function with this gradient; inf where the covariance is."""
    if not np.all(np.isfinite(cov)):
        return math.inf
    return math.sqrt(max(float(gradient @ cov @ gradient), 0.0))


def _covariance(
    problem: _Problem, omega: float, zeta: float, coef: FloatArray, res: FloatArray
) -> FloatArray:
    """Covariance (3, 3) of (ω, ζ, gain) from the Jacobian of all seven parameters, the residuals' variance
    scaled up for their correlation (n / n_eff)."""

    def model(p: FloatArray) -> FloatArray:
        return problem.columns(p[0], p[1]) @ p[2:]

    params = np.concatenate([[omega, zeta], coef])
    steps = np.maximum(np.abs(params) * 1e-6, 1e-12)
    jac = np.empty((problem.x.size, params.size))
    for j in range(params.size):
        up, down = params.copy(), params.copy()
        up[j] += steps[j]
        down[j] -= steps[j]
        jac[:, j] = (model(up) - model(down)) / (2 * steps[j])
    variance = _noise_variance(problem, res)
    scale = np.maximum(np.linalg.norm(jac, axis=0), 1e-300)
    normal = (jac / scale).T @ (jac / scale)
    if np.linalg.cond(normal) > 1e12:  # a direction the data do not constrain at all
        return np.full((3, 3), np.inf)
    full = np.linalg.inv(normal) * variance / np.outer(scale, scale)
    return np.asarray(full[:3, :3], dtype=np.float64)
