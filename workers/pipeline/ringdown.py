"""The ring-down model: a damped oscillation fitted to an object's motion (frequency and damping far
below one FFT bin), and its evolution over sliding windows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.lstsq import Solution, least_squares
from workers.pipeline.peaks import interpolate_peak


@dataclass(frozen=True)
class RingdownFit:
    """A damped oscillation fitted to a velocity signal.

    The displacement model is x(t) = C + A exp(-σ t) cos(ω_d t + φ) for t >= 0 (t from the first sample of
    the fit), and the signal is its per-frame difference v_k = x_{k+1} - x_k, as optical flow measures.

    Attributes
    ----------
    frequency_hz : float
        Damped frequency f_d = ω_d / 2π.
    natural_frequency_hz : float
        Undamped f_n = sqrt(ω_d² + σ²) / 2π.
    damping_ratio : float
        ζ = σ / ω_n.
    amplitude : float
        A, in the signal's units integrated (pixels for flow in pixels/frame).
    phase_rad : float
        φ at the first sample.
    decay_per_s : float
        σ.
    start_index : int
        First sample of the fitted window.
    frequency_sd_hz, damping_sd, amplitude_sd : float
        Standard uncertainties from the fit's Jacobian and residual variance.
    residual_rms : float
    snr_db : float
        Signal power over residual power per sample, dB.
    samples : int
        Samples fitted (from ``start_index``).
    duration_s : float
        Time they span, seconds.
    concentration : float
        Fraction of the motion's energy near the fitted frequency (within a few lines of it) that the
        model explains: near 1 for one coherent oscillation, low for narrow-band noise, a wandering
        frequency or two unresolved oscillations.
    """

    frequency_hz: float
    natural_frequency_hz: float
    damping_ratio: float
    amplitude: float
    phase_rad: float
    decay_per_s: float
    start_index: int
    frequency_sd_hz: float
    damping_sd: float
    amplitude_sd: float
    residual_rms: float
    snr_db: float
    samples: int = 0
    concentration: float = 1.0

    @property
    def detection_db(self) -> float:
        """The oscillation's energy over the residual's variance, dB: the per-sample SNR summed over the
        fitted samples (a weak but steady vibration is clearly detected over many periods)."""
        return self.snr_db + 10 * math.log10(max(self.samples, 1))

    duration_s: float = 0.0

    @property
    def decay(self) -> float:
        """How far the envelope decays over the fitted span, nepers (σ times its duration)."""
        return self.decay_per_s * self.duration_s

    def displacement(self, t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Model displacement (without the constant offset) at times ``t_s`` from the fit start."""
        w = 2 * math.pi * self.frequency_hz
        return np.asarray(self.amplitude * np.exp(-self.decay_per_s * t_s) * np.cos(w * t_s + self.phase_rad))


def _basis(omega: float, sigma: float, k: NDArray[np.float64]) -> NDArray[np.float64]:
    """Columns: per-interval differences of e^{-σk}cos(ωk) and e^{-σk}sin(ωk) at frame positions k
    (N + 1 values, in periods of the nominal rate from the fit start), and a constant drift per period."""
    env = np.exp(-sigma * k)
    c = env * np.cos(omega * k)
    s = env * np.sin(omega * k)
    return np.stack([np.diff(c), np.diff(s), np.diff(k)], axis=1)


def _profile(
    params: NDArray[np.float64], v: NDArray[np.float64], k: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    omega, sigma = float(params[0]), float(params[1])
    basis = _basis(omega, sigma, k)
    coef, *_ = np.linalg.lstsq(basis, v, rcond=None)
    return v - basis @ coef, np.asarray(coef, np.float64)


def _spectral_guess(v: NDArray[np.float64], f_guess_cycles: float | None) -> float:
    """Angular frequency (rad/sample) of the strongest peak, zero-padded x16, parabolic refinement."""
    n = len(v)
    nfft = 1 << math.ceil(math.log2(max(16 * n, 64)))
    spec = np.abs(np.fft.rfft(v - v.mean(), n=nfft)) ** 2
    if f_guess_cycles is not None:
        centre = f_guess_cycles * nfft
        lo = max(1, int(centre - 1.5 * nfft / n))
        hi = min(len(spec) - 1, int(centre + 1.5 * nfft / n) + 1)
    else:
        lo, hi = max(1, nfft // n), len(spec) - 1
    k = lo + int(np.argmax(spec[lo:hi]))
    return 2 * math.pi * interpolate_peak(spec, k) / nfft


def fit_ringdown(
    velocity: NDArray[np.floating[Any]],
    *,
    sample_rate_hz: float,
    frequency_guess_hz: float | None = None,
    start_index: int = 0,
    frame_times_s: NDArray[np.float64] | None = None,
    band_hz: tuple[float, float] | None = None,
) -> RingdownFit:
    """Fit a damped oscillation to a per-frame velocity signal.

    Variable projection: the two nonlinear parameters (ω, σ) are optimised by least squares while the
    amplitude, phase and a constant velocity offset are solved linearly at each step.

    Parameters
    ----------
    velocity : ndarray, shape (N,)
        Per-frame displacement differences (e.g. the flow of the object projected on its motion axis).
    sample_rate_hz : float
    frequency_guess_hz : float, optional
        Start value (e.g. the summed spectrum's peak); found from the signal's own spectrum otherwise.
    start_index : int
        Samples before this are ignored (still frames before release).
    frame_times_s : ndarray of float64, shape (N + 1,), optional
        Capture times of the frames that bound the samples (sample k spans frames k and k + 1). With
        dropped frames or jitter the model is evaluated at these true times, so gaps do not bias the fit;
        uniform at ``fps`` when omitted.
    band_hz : (low, high), optional
        The frequency is sought inside this band (the analysis band); anywhere below the Nyquist rate
        when omitted.

    Returns
    -------
    RingdownFit
    """
    v, k_pos = _fitted_samples(
        velocity, sample_rate_hz=sample_rate_hz, start_index=start_index, frame_times_s=frame_times_s
    )
    n = len(v)
    if n < 6:
        from workers.pipeline.errors import AnalysisError

        raise AnalysisError(f"only {n} moving frames after release; record at least 16 frames of motion")
    guess = None if frequency_guess_hz is None else frequency_guess_hz / sample_rate_hz
    omega0 = _spectral_guess(v, guess)
    sigma0 = _decay_guess(v)
    w_lo, w_hi = _angular_bounds(sample_rate_hz, band_hz)
    best = _best_solution(v, k_pos, omega0=min(max(omega0, w_lo), w_hi), sigma0=sigma0, bounds=(w_lo, w_hi))
    omega, sigma = float(best.x[0]), float(best.x[1])
    res, coef = _profile(best.x, v, k_pos)
    a_c, a_s = float(coef[0]), float(coef[1])
    spread = _spread(res, best.jac, _basis(omega, sigma, k_pos))
    wn = math.hypot(omega, sigma)
    model = v - res - coef[2] * np.diff(k_pos)
    signal_power = float(np.mean(model**2))
    return RingdownFit(
        frequency_hz=omega * sample_rate_hz / (2 * math.pi),
        natural_frequency_hz=wn * sample_rate_hz / (2 * math.pi),
        damping_ratio=sigma / wn,
        amplitude=math.hypot(a_c, a_s),
        phase_rad=math.atan2(-a_s, a_c),
        decay_per_s=sigma * sample_rate_hz,
        start_index=start_index,
        frequency_sd_hz=spread.omega_sd * sample_rate_hz / (2 * math.pi),
        damping_sd=spread.sigma_sd / wn,
        amplitude_sd=spread.amplitude_sd,
        residual_rms=math.sqrt(spread.variance),
        snr_db=10 * math.log10(max(signal_power, 1e-30) / max(spread.variance, 1e-30)),
        samples=n,
        duration_s=float(k_pos[-1] - k_pos[0]) / sample_rate_hz,
        concentration=_concentration(v, model, omega=omega, sigma=sigma),
    )


def _fitted_samples(
    velocity: NDArray[np.floating[Any]],
    *,
    sample_rate_hz: float,
    start_index: int,
    frame_times_s: NDArray[np.float64] | None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The samples fitted and the positions of the frames that bound them.

    Returns
    -------
    v : ndarray of float64, shape (n,)
        ``velocity`` from ``start_index``.
    k_pos : ndarray of float64, shape (n + 1,)
        Frame positions in periods of ``fps`` from the fit start (uniform without ``frame_times_s``).
    """
    v = np.asarray(velocity, np.float64)[start_index:]
    n = len(v)
    if frame_times_s is None:
        return v, np.arange(n + 1, dtype=np.float64)
    times = np.asarray(frame_times_s, np.float64)
    return v, (times[start_index : start_index + n + 1] - times[start_index]) * sample_rate_hz


def _decay_guess(v: NDArray[np.float64]) -> float:
    """Decay start value (per sample), from the envelope of the signal's two halves."""
    n = len(v)
    half = n // 2
    e1 = np.sqrt(np.mean(v[:half] ** 2)) + 1e-12
    e2 = np.sqrt(np.mean(v[half:] ** 2)) + 1e-12
    return max(1e-4, math.log(e1 / e2) / max(half, 1)) if e1 > e2 else 1e-3


def _angular_bounds(sample_rate_hz: float, band_hz: tuple[float, float] | None) -> tuple[float, float]:
    """The range (rad/sample) the frequency is sought in: below the Nyquist rate, inside ``band_hz``.

    Raises
    ------
    ValueError
        When the band holds no frequency at ``fps``.
    """
    w_lo, w_hi = 1e-4, math.pi
    if band_hz is not None:
        w_lo = max(w_lo, 2 * math.pi * band_hz[0] / sample_rate_hz)
        w_hi = min(w_hi, 2 * math.pi * band_hz[1] / sample_rate_hz)
        if w_lo >= w_hi:
            raise ValueError(f"fit_ringdown: band {band_hz} Hz holds no frequency at {sample_rate_hz:g} fps")
    return w_lo, w_hi


def _best_solution(
    v: NDArray[np.float64],
    k_pos: NDArray[np.float64],
    *,
    omega0: float,
    sigma0: float,
    bounds: tuple[float, float],
) -> Solution:
    """The least-squares solution of (ω, σ) with the lowest cost, from three decay start values
    (``sigma0`` and 0.3 and 3 times it); ω within ``bounds`` (rad/sample), σ within [0, 1]."""

    def residual(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return _profile(p, v, k_pos)[0]

    best = None
    for s0 in (sigma0, sigma0 * 0.3, sigma0 * 3):
        sol = least_squares(
            residual,
            np.array([omega0, min(max(s0, 1e-5), 0.5)]),
            lower=np.array([bounds[0], 0.0]),
            upper=np.array([bounds[1], 1.0]),
        )
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    return best


@dataclass(frozen=True)
class _Spread:
    """The fit's residual variance and the standard uncertainties of its parameters.

    Attributes
    ----------
    variance : float
        Residual variance per sample, inflated for correlated residuals.
    omega_sd, sigma_sd : float
        Of ω and σ, per sample (NaN when the Jacobian is singular).
    amplitude_sd : float
        Of the amplitude (NaN when the basis is singular).
    """

    variance: float
    omega_sd: float
    sigma_sd: float
    amplitude_sd: float


def _spread(res: NDArray[np.float64], jac: NDArray[np.float64], basis: NDArray[np.float64]) -> _Spread:
    """Uncertainties from the residuals ``res`` (n,), the Jacobian ``jac`` (n, 2) of (ω, σ) and the
    linear ``basis`` (n, 3) at the solution."""
    n = len(res)
    dof = max(n - 5, 1)
    # Residuals of real flow are not white: neighbouring samples share errors. Inflate the variance by
    # the effective-sample-size factor (1 + ρ) / (1 - ρ) of the lag-1 autocorrelation ρ.
    rho = float(res[1:] @ res[:-1]) / max(float(res @ res), 1e-30) if n > 2 else 0.0
    rho = min(max(rho, 0.0), 0.9)
    s2 = float(res @ res) / dof * (1 + rho) / (1 - rho)
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2
        omega_sd, sigma_sd = (math.sqrt(max(float(x), 0.0)) for x in np.diag(cov))
    except np.linalg.LinAlgError:
        omega_sd, sigma_sd = float("nan"), float("nan")
    try:
        cov_lin = np.linalg.inv(basis.T @ basis) * s2
        amp_sd = math.sqrt(max(float(cov_lin[0, 0] + cov_lin[1, 1]) / 2, 0.0))
    except np.linalg.LinAlgError:
        amp_sd = float("nan")
    return _Spread(variance=s2, omega_sd=omega_sd, sigma_sd=sigma_sd, amplitude_sd=amp_sd)


def _concentration(
    v: NDArray[np.float64], model: NDArray[np.float64], *, omega: float, sigma: float
) -> float:
    """Fraction of the energy of ``v`` within a few lines of ω that ``model`` explains (see
    :class:`RingdownFit`): lines are the window's resolution (1 / n cycles per sample) or the model's own
    half-power width (σ / π), whichever is wider."""
    n = len(v)
    nfft = 1 << math.ceil(math.log2(max(4 * n, 64)))
    freqs = np.fft.rfftfreq(nfft)
    half_width = max(3.0 / n, 3.0 * sigma / math.pi)
    near = np.abs(freqs - omega / (2 * math.pi)) <= half_width
    data = np.fft.rfft(v - v.mean(), n=nfft)[near]
    left = np.fft.rfft(v - v.mean() - (model - model.mean()), n=nfft)[near]
    energy = float(np.sum(np.abs(data) ** 2))
    if energy <= 0:
        return 0.0
    return max(0.0, 1.0 - float(np.sum(np.abs(left) ** 2)) / energy)


@dataclass(frozen=True)
class Ringdown:
    """How an object's oscillation evolves over the clip, from sliding windows.

    Attributes
    ----------
    times_s : ndarray of float64, shape (W,)
        Window centres, seconds from the analysed window's first frame.
    amplitude : ndarray of float64, shape (W,)
        Displacement amplitude at the object's frequency in each window (signal units integrated).
    frequency_hz : ndarray of float64, shape (W,)
        Strongest frequency in each window (zero-padded, interpolated).
    spectrogram_hz : ndarray of float64, shape (F,)
    spectrogram_power : ndarray of float64, shape (W, F)
        Power of the velocity in each window.
    """

    times_s: NDArray[np.float64]
    amplitude: NDArray[np.float64]
    frequency_hz: NDArray[np.float64]
    spectrogram_hz: NDArray[np.float64]
    spectrogram_power: NDArray[np.float64]


def sliding_ringdown(
    velocity: NDArray[np.floating[Any]],
    *,
    sample_rate_hz: float,
    frequency_hz: float,
    window: int | None = None,
) -> Ringdown:
    """Ring-down analysis over sliding windows (a short-time spectrum of the object's motion).

    Parameters
    ----------
    velocity : ndarray, shape (N,)
        Per-frame displacement of the object.
    sample_rate_hz : float
    frequency_hz : float
        The object's frequency; each window's amplitude is measured there.
    window : int, optional
        Window length in samples; default: four periods, at least 8 and at most N / 2.

    Returns
    -------
    Ringdown
    """
    v = np.asarray(velocity, np.float64)
    n = len(v)
    period = sample_rate_hz / max(frequency_hz, 1e-9)
    length = window or round(4 * period)
    length = int(min(max(length, 8), max(n // 2, 8), n))
    hop = max(1, length // 4)
    starts = np.arange(0, n - length + 1, hop)
    taper = np.hanning(length + 2)[1:-1]
    nfft = max(64, 1 << math.ceil(math.log2(4 * length)))
    freqs = np.fft.rfftfreq(nfft, d=1.0 / sample_rate_hz)
    omega = 2 * math.pi * frequency_hz / sample_rate_hz
    k = np.arange(length)
    probe = np.exp(-1j * omega * k) * taper
    gain = 2 * math.sin(omega / 2)  # per-frame difference of a unit sine
    norm = float(taper.sum()) / 2
    power = np.empty((len(starts), len(freqs)))
    amp = np.empty(len(starts))
    freq = np.empty(len(starts))
    for i, s in enumerate(starts):
        seg = v[s : s + length] - v[s : s + length].mean()
        spec = np.abs(np.fft.rfft(seg * taper, n=nfft)) ** 2
        power[i] = spec
        kk = int(np.argmax(spec[1:])) + 1
        freq[i] = interpolate_peak(spec, kk) * sample_rate_hz / nfft
        amp[i] = abs(complex(seg @ probe)) / norm / max(gain, 1e-9)
    times = (starts + length / 2) / sample_rate_hz
    return Ringdown(
        times_s=times.astype(np.float64),
        amplitude=amp,
        frequency_hz=freq,
        spectrogram_hz=freqs.astype(np.float64),
        spectrogram_power=power,
    )


# Uncertainties and regime of a fitted ring-down -------------------------------------------------------

#: Systematic floors on the ring-down fit's statistical uncertainties (model mismatch: projection
#: nonlinearity, registration errors correlated with the motion), measured on randomised ground truth.
FREQUENCY_REL_FLOOR = 3e-4
#: ... and, for a strongly damped object, this fraction of its resonance's half-power width (2 zeta f):
#: model mismatch shifts a broad resonance further (a clear 8-10 Hz object at zeta 0.09 is 8e-4 off).
FREQUENCY_LINEWIDTH_FLOOR = 0.005
DAMPING_REL_FLOOR = 0.015
DAMPING_ABS_FLOOR = 3e-4


def frequency_sd_hz(
    fit: RingdownFit, *, rel_floor: float = FREQUENCY_REL_FLOOR, t_factor: float = 1.0
) -> float:
    """The frequency's standard uncertainty: the fit's own, times ``t_factor`` (an early live estimate's
    few degrees of freedom), with the systematic floors added (``rel_floor`` of the frequency, or a
    fraction of the resonance's width). A fit that could not state its own counts as 100 %."""
    f_floor = max(rel_floor, FREQUENCY_LINEWIDTH_FLOOR * 2 * abs(fit.damping_ratio))
    stat = fit.frequency_sd_hz if math.isfinite(fit.frequency_sd_hz) else fit.frequency_hz
    return math.hypot(stat * t_factor, f_floor * fit.frequency_hz)


def damping_sd(fit: RingdownFit, *, t_factor: float = 1.0) -> float:
    """The damping ratio's standard uncertainty: the fit's own, times ``t_factor``, with the systematic
    floors added. A fit that could not state its own counts as 1."""
    stat = fit.damping_sd if math.isfinite(fit.damping_sd) else 1.0
    return math.sqrt(
        (stat * t_factor) ** 2 + (DAMPING_REL_FLOOR * fit.damping_ratio) ** 2 + DAMPING_ABS_FLOOR**2
    )


#: A decay over the fitted span of at least this (nepers: 5 % of the amplitude), three standard
#: uncertainties clear of zero, makes a ring-down; less is steady.
MIN_DECAY = 0.05
#: An envelope that grows by this factor over the window, clearly, is ``growing``.
MIN_GROWTH = 1.25


def regime_of(ring: Ringdown | None, *, decay: float, decay_sd: float) -> str:
    """``ring_down``, ``steady`` or ``growing``: how an object's oscillation evolved over the window.

    Parameters
    ----------
    ring : Ringdown or None
        The object's sliding-window amplitude, when it has one (for growth).
    decay, decay_sd : float
        The fitted envelope's decay over the fitted span and its standard uncertainty, nepers.
    """
    if decay >= MIN_DECAY and decay >= 3 * decay_sd:
        return "ring_down"
    if ring is not None and len(ring.amplitude) >= 4:
        amp = np.asarray(ring.amplitude, np.float64)
        ok = amp > 0
        if ok.sum() >= 4:
            t = np.asarray(ring.times_s, np.float64)[ok]
            slope, _ = np.polyfit(t, np.log(amp[ok]), 1)
            span = float(t[-1] - t[0])
            if slope * span >= math.log(MIN_GROWTH) and float(amp[ok][-1]) > float(amp[ok][0]):
                return "growing"
    return "steady"


def regime_of_fit(fit: RingdownFit, ring: Ringdown | None = None) -> str:
    """:func:`regime_of` a fit, its decay judged on the fit's own (statistical) uncertainty, before the
    systematic floors."""
    decay_sd = fit.damping_sd * 2 * math.pi * fit.natural_frequency_hz * fit.duration_s
    return regime_of(ring, decay=fit.decay, decay_sd=decay_sd)


__all__ = [
    "DAMPING_ABS_FLOOR",
    "DAMPING_REL_FLOOR",
    "FREQUENCY_LINEWIDTH_FLOOR",
    "FREQUENCY_REL_FLOOR",
    "MIN_DECAY",
    "MIN_GROWTH",
    "Ringdown",
    "RingdownFit",
    "damping_sd",
    "fit_ringdown",
    "frequency_sd_hz",
    "regime_of",
    "regime_of_fit",
    "sliding_ringdown",
]
