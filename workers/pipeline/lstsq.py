"""A small bounded least-squares solver (Levenberg-Marquardt) for fits of a few parameters.

scipy.optimize would do, but its import costs a third of a second of every analysis; the ring-down fit
has two nonlinear parameters. Tested against ``scipy.optimize.least_squares``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Solution:
    """A minimiser, its cost (half the squared residual norm) and the Jacobian there."""

    x: NDArray[np.float64]
    cost: float  # half the sum of squared residuals
    jac: NDArray[np.float64]  # (M, n) at x


def _jacobian(
    fun: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    x: NDArray[np.float64],
    r: NDArray[np.float64],
    upper: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Forward differences, stepping away from the upper bound."""
    jac = np.empty((len(r), len(x)))
    for i in range(len(x)):
        h = math.sqrt(np.finfo(np.float64).eps) * max(1.0, abs(float(x[i])))
        if x[i] + h > upper[i]:
            h = -h
        step = x.copy()
        step[i] += h
        jac[:, i] = (fun(step) - r) / h
    return jac


def least_squares(
    fun: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    x0: NDArray[np.float64],
    *,
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    max_iterations: int = 200,
    tolerance: float = 1e-10,
) -> Solution:
    """Levenberg-Marquardt for a few bounded parameters (steps are clipped into the box).

    A small problem does not need scipy.optimize, whose import costs a third of a second of every run.
    The damping is scaled by the diagonal of JᵀJ, so parameters of different size need no scaling.

    Parameters
    ----------
    fun : callable
        ``fun(x) -> residuals``, ndarray of float64, shape (M,).
    x0 : ndarray of float64, shape (n,)

    Returns
    -------
    Solution
        Minimiser, its cost (half the squared residual norm) and the Jacobian there.
    """
    x = np.clip(np.asarray(x0, np.float64), lower, upper)
    r = fun(x)
    cost = 0.5 * float(r @ r)
    jac = _jacobian(fun, x, r, upper)
    damping = 1e-3
    for _ in range(max_iterations):
        gradient = jac.T @ r
        normal = jac.T @ jac
        scale = np.maximum(np.diag(normal), 1e-30)
        improved = False
        while damping < 1e12:
            try:
                delta = np.linalg.solve(normal + damping * np.diag(scale), -gradient)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            x_new = np.clip(x + delta, lower, upper)
            r_new = fun(x_new)
            cost_new = 0.5 * float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new < cost:
                improved = True
                break
            damping *= 10
        if not improved:
            break
        moved = np.abs(x_new - x)
        reduction = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        jac = _jacobian(fun, x, r, upper)
        damping = max(damping / 10, 1e-12)
        if reduction <= tolerance * cost or np.all(moved <= tolerance * (np.abs(x) + tolerance)):
            break
    return Solution(x=x, cost=cost, jac=jac)


__all__ = ["Solution", "least_squares"]


def effective_count(residual: NDArray[np.float64]) -> float:
    """Independent samples among correlated ones: n (1 - ρ) / (1 + ρ), ρ the lag-1 autocorrelation of
    ``residual`` (N,) (clipped to [0, 0.95]); what a fit's residual variance is divided by."""
    n = residual.size
    centred = residual - residual.mean()
    power = float(centred @ centred)
    if n < 3 or power <= 0:
        return float(max(n, 1))
    rho = min(max(float(centred[1:] @ centred[:-1]) / power, 0.0), 0.95)
    return n * (1.0 - rho) / (1.0 + rho)
