"""The excitation read from a force sensor: a held force and the instant it is let go, or a strike's
impulse, each with its standard uncertainty.

A wrist force/torque sensor (a ROS ``geometry_msgs/WrenchStamped`` topic) or a force log beside a clip
records the force the robot applied, at hundreds of hertz. This module finds the excitation in it:

- :class:`ForceSeries` -- the samples on the clip's clock (read from a CSV or JSON log by
  :func:`workers.pipeline.clipio.force_log.read_force_log`, from a bag's force topic by
  :func:`workers.pipeline.clipio.force_topics.read_force`);
- :func:`dominant_direction` -- the force as one signed number: its component along the direction in
  which it changes, signed so that the push or the strike is positive;
- :func:`find_excitation` -- a push held then let go (``step_release``), a strike (``impulse``), or a
  force that keeps oscillating (``forced``), as a :class:`ForceExcitation`;
- :func:`excitation_of` -- the :class:`~workers.pipeline.model.Excitation` the mechanics take.

Conventions: times in seconds on the clip's clock (0 = the clip's first frame; a force record may start
before it), forces in newtons, impulses in newton-seconds, uncertainties standard (1 σ). The *baseline*
is what the sensor reads when nothing pushes: the level the record ends at (after a release or a strike
the object rings freely), fitted as a robust straight line over every quiet part of the record, so that
a sensor's offset and slow linear drift are removed. The noise is the MAD of the quiet parts about it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.errors import ForceError
from workers.pipeline.model import Excitation

#: Scale from a median absolute deviation to the standard deviation of normal noise.
MAD_TO_SD = 1.4826
#: Fewest samples a force record needs.
MIN_SAMPLES = 8
#: A sample further than this many noise SDs from the baseline is not quiet.
QUIET_SIGMAS = 6.0
#: An event's peak rises at least this many noise SDs above the baseline ...
EVENT_SIGMAS = 8.0
#: ... and it spans the samples more than this many noise SDs above it.
EDGE_SIGMAS = 3.0
#: An event above the baseline for at most this long is a strike; a longer one is a push.
PULSE_MAX_S = 0.1
#: A hold is the stretch before the release within max(4 SD, this fraction) of the held force ...
HOLD_BAND = 0.05
#: ... and it has at least this many samples.
MIN_HOLD_SAMPLES = 8
#: A forced vibration swings across the baseline at least this many times (3 cycles), to the end.
FORCED_MIN_SWINGS = 6
#: A swing of a forced vibration reaches at least this fraction of the largest one.
FORCED_SWING_FRACTION = 0.3

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ForceSeries:
    """A force recording on the clip's clock.

    Attributes
    ----------
    times_s : ndarray, shape (N,), float64
        Sample times, strictly increasing, seconds on the clip's clock: the same origin as the frames'
        timestamps (seconds from the clip's first frame); the record may start before 0.
    force_n : ndarray, shape (N, 3) or (N, 1), float64
        ``fx, fy, fz`` in the sensor's frame, newtons, or one signed magnitude. A 1-D array of shape
        (N,) is taken as (N, 1).
    source : str
        Where it came from, for messages and the result: ``"topic /ft_sensor/wrench"``, ``"log force.csv"``.
    frame_id : str or None
        The sensor's frame (a ROS ``frame_id``) when known.
    in_camera_frame : bool
        True when the force has already been rotated into the camera's optical frame.

    Raises
    ------
    ForceError
        Wrong shapes, fewer than :data:`MIN_SAMPLES` samples, non-finite values, or times that do not
        strictly increase. Rows are counted from 1 (the first sample).
    """

    times_s: FloatArray
    force_n: FloatArray
    source: str
    frame_id: str | None = None
    in_camera_frame: bool = False

    def __post_init__(self) -> None:
        times, force = _checked_samples(self.times_s, self.force_n, where=f"the force {self.source}")
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "force_n", force)


@dataclass(frozen=True)
class ForceExcitation:
    """The excitation found in a force recording.

    Attributes
    ----------
    kind : ``"step_release"``, ``"impulse"`` or ``"forced"``
    value : float
        Held force in N (step_release), impulse in N·s (impulse), or RMS of the oscillating force in N
        (forced; a sinusoid's amplitude is √2 times it). Positive.
    uncertainty : float
        Standard uncertainty of ``value``, from the sensor's noise, the baseline's drift and the sampling.
    time_s : float
        Clip clock: the release instant (step_release: where the force crosses halfway between the hold
        and the baseline on its final drop, interpolated between samples), the strike's centroid
        (impulse), or the start of the forcing (forced: its first swing above the noise).
    direction : ndarray, shape (3,), float64, or None
        Unit vector of the force in the series' frame, pointing the way the robot pushed; None for a 1-D
        series.
    source : str
        The series' source.
    notes : list of str
        What the reader of the result should know: the direction used, other events, drift removed.
    hold_s : (float, float) or None
        Start and end of the hold (step_release).
    pulse_s : (float, float) or None
        Start and end of the pulse (impulse).
    """

    kind: Literal["step_release", "impulse", "forced"]
    value: float
    uncertainty: float
    time_s: float
    direction: FloatArray | None
    source: str
    notes: list[str]
    hold_s: tuple[float, float] | None = None
    pulse_s: tuple[float, float] | None = None


def dominant_direction(series: ForceSeries) -> tuple[FloatArray | None, FloatArray]:
    """The force as one signed number: its component along the direction in which it changes.

    For fx, fy, fz: the principal axis (SVD) of the samples that stand out from the baseline, the
    baseline (the quiet samples' robust linear fit, per axis) removed; signed so that the push or the
    strike is positive. For a 1-D series: the values themselves, their sign flipped when the push reads
    negative (a sensor that reads compression as negative).

    Parameters
    ----------
    series : ForceSeries

    Returns
    -------
    direction : ndarray, shape (3,), float64, or None
        Unit vector in the series' frame; None for a 1-D series.
    projected : ndarray, shape (N,), float64
        ``force_n @ direction`` (baseline included), or the (possibly sign-flipped) 1-D values.
    """
    direction, projected, _ = _direction(series)
    return direction, projected


def find_excitation(series: ForceSeries, *, window_s: tuple[float, float] | None = None) -> ForceExcitation:
    """Find the excitation in a force recording: a push held then let go, a strike, or a forcing.

    The force is projected on its dominant direction (:func:`dominant_direction`), its baseline removed
    and its noise estimated from the quiet parts (see the module's docstring). Then:

    - *push, hold, release*: a stretch longer than :data:`PULSE_MAX_S` well above the noise that drops to
      the baseline. Value: the median over the hold; time: where the final drop crosses halfway;
    - *strike*: a pulse shorter than :data:`PULSE_MAX_S` back to the baseline. Value: J = ∫(F - baseline)
      dt over the pulse (trapezoid); time: its centroid;
    - *forced*: the force swings across the baseline, again and again, to the end of the record. Value:
      its RMS (the frequency-response fit that turns it into k and m is not available yet).

    With several pushes or strikes, the last before the end of ``window_s`` is used when it is given,
    otherwise the strongest (largest peak force); the others are noted. A 3-D force not rotated into the
    camera's frame is used along its dominant direction, and the notes say so.

    The baseline is the level the record ends at, so a record that ends while the force is still held
    reads the push as a release of the opposite sign (from the record's start, slow, as the notes say):
    end such a record after the release.

    Parameters
    ----------
    series : ForceSeries
    window_s : (float, float) or None
        Start and end, clip clock, of the analysed window: the excitation must come before its end.

    Returns
    -------
    ForceExcitation

    Raises
    ------
    ForceError
        No hold, release or strike above the noise; none before the window's end; a bad window.
    """
    window = _checked_window(window_s)
    times = series.times_s
    direction, projected, flipped = _direction(series)
    base = _baseline(times, projected)
    above = projected - base.level
    forced = _forcing(times, above, base)
    events, ignored = _events(times, above, base)
    if forced is not None:  # an oscillation has no push to sign by
        notes = _frame_notes(series, direction, flipped=False) + _before_forcing(events, forced)
        return _excitation(forced, direction=direction, source=series.source, notes=notes)
    notes = _frame_notes(series, direction, flipped=flipped) + _drift_notes(times, base)
    if not events:
        raise ForceError(_nothing_message(series.source, above, base.sigma, ignored))
    chosen, choice_notes = _choose(events, window, source=series.source)
    return _excitation(chosen, direction=direction, source=series.source, notes=notes + choice_notes)


def excitation_of(found: ForceExcitation) -> Excitation:
    """The :class:`~workers.pipeline.model.Excitation` (kind, value, uncertainty) for the mechanics.

    Parameters
    ----------
    found : ForceExcitation
        A ``step_release`` or an ``impulse``.

    Returns
    -------
    Excitation
        For the main object (no object, point or box chosen).

    Raises
    ------
    ForceError
        For a ``forced`` excitation: k and m from a forced vibration need the frequency-response fit.
    """
    if found.kind == "forced":
        raise ForceError(
            f"the force {found.source} keeps oscillating (a forced vibration, RMS {found.value:.3g} N): "
            "stiffness and mass from a forced vibration need the frequency-response fit between force and "
            "motion, which is not available yet; record a push, hold and release or a strike, or give "
            "--force-n / --impulse-ns"
        )
    return Excitation(
        kind=found.kind,
        value=found.value,
        uncertainty=found.uncertainty,
        release_time_s=found.time_s,
        source=found.source,
        notes=tuple(found.notes),
    )


def recorded_excitation(series: ForceSeries | None, *, asked: bool) -> tuple[Excitation | None, list[str]]:
    """The excitation a force recording shows (:func:`find_excitation`, :func:`excitation_of`), and notes.

    Parameters
    ----------
    series : ForceSeries or None
        The recording (None: there is none).
    asked : bool
        Whether the user asked for it (a force log, a force topic named): then a recording that shows no
        hold, release or strike is an error; a recording only found beside the frames gives a note instead,
        and the analysis goes on without it.

    Returns
    -------
    (Excitation or None, list of str)

    Raises
    ------
    ForceError
        When ``asked`` and the recording shows no usable excitation.
    """
    if series is None:
        return None, []
    try:
        return excitation_of(find_excitation(series)), []
    except ForceError as exc:
        if asked:
            raise
        return None, [f"the force recorded in {series.source} was not used: {exc}"]


def chosen_excitations(typed: list[Excitation], recorded: Excitation | None) -> list[Excitation]:
    """The excitations an analysis uses: the typed ones, else the recorded one. A typed value for the main
    object overrides the recording's, and says so (the recording's release instant still sets the fit's
    start when both are of one kind).

    Parameters
    ----------
    typed : list of Excitation
        Given by the user (``source`` ``request``).
    recorded : Excitation or None
        From the force sensor (:func:`excitation_of`).

    Returns
    -------
    list of Excitation
    """
    if recorded is None:
        return list(typed)
    if not typed:
        return [recorded]
    out = []
    for exc in typed:
        main = exc.object_id is None and exc.point_px is None and exc.box_px is None
        if not main:
            out.append(exc)
            continue
        note = (
            f"the typed {exc.kind.replace('_', ' ')} ({exc.value:.4g}) overrides the one recorded in "
            f"{recorded.source} ({recorded.kind.replace('_', ' ')}, {recorded.value:.4g} ± "
            f"{recorded.uncertainty:.2g})"
        )
        same = exc.kind == recorded.kind
        out.append(
            dataclasses.replace(
                exc, release_time_s=recorded.release_time_s if same else None, notes=(*exc.notes, note)
            )
        )
    return out


# --- samples and logs -----------------------------------------------------------------------------------


def _checked_samples(times: Any, force: Any, *, where: str) -> tuple[FloatArray, FloatArray]:
    """Times (N,) and force (N, 3 or 1) as float64 copies, or a ForceError naming the problem."""
    try:
        t = np.array(times, dtype=np.float64)
        f = np.array(force, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ForceError(f"{where}: times and forces must be numbers ({exc})") from None
    if f.ndim == 1:
        f = f[:, None]
    if t.ndim != 1 or f.ndim != 2 or f.shape[1] not in (1, 3) or f.shape[0] != t.size:
        raise ForceError(
            f"{where}: times of shape {t.shape} and forces of shape {f.shape} do not fit; give times (N,) "
            "and forces (N, 3) (fx, fy, fz) or (N, 1) (one signed magnitude)"
        )
    if t.size < MIN_SAMPLES:
        raise ForceError(
            f"{where} has {t.size} samples, too few to tell a hold or a strike from noise; record at least "
            f"{MIN_SAMPLES} (a few hundred around the excitation)"
        )
    bad = ~(np.isfinite(t) & np.all(np.isfinite(f), axis=1))
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise ForceError(
            f"{where}: row {row + 1} is not finite (time {t[row]}, force {f[row].tolist()}); remove or "
            "repair the rows with NaN or infinite values"
        )
    steps = np.flatnonzero(np.diff(t) <= 0)
    if steps.size:
        row = int(steps[0]) + 1
        how = "repeat" if t[row] == t[row - 1] else "run backwards"
        raise ForceError(
            f"{where}: times {how} at row {row + 1} ({t[row]:.6g} s after {t[row - 1]:.6g} s); sort the "
            "samples by time and drop duplicates, or fix the clock"
        )
    return t, f


# --- direction, baseline and noise ----------------------------------------------------------------------


@dataclass(frozen=True)
class _Line:
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
class _Baseline:
    """The baseline at every sample (N,), the quiet samples' mask (N,) and their noise SD."""

    level: FloatArray
    quiet: NDArray[np.bool_]
    sigma: float
    line: _Line


def _direction(series: ForceSeries) -> tuple[FloatArray | None, FloatArray, bool]:
    """Unit direction (3,) or None, the projected force (N,), and whether a 1-D force's sign was flipped."""
    t, force = series.times_s, series.force_n
    if force.shape[1] == 1:
        values = force[:, 0]
        base = _baseline(t, values)
        above = values - base.level
        flipped = bool(np.sum(above[np.abs(above) > QUIET_SIGMAS * base.sigma]) < 0)
        return None, -values if flipped else values.copy(), flipped
    axis = _principal_axis(force - np.median(force, axis=0))
    base = _baseline(t, force @ axis)
    quiet = base.quiet
    lines = [_robust_line(t[quiet], force[quiet, k]) for k in range(3)] if quiet.sum() >= 2 else []
    rest = np.stack([line.at(t) for line in lines], axis=1) if lines else np.median(force, axis=0)
    change = force - rest
    active = np.abs(change @ axis) > QUIET_SIGMAS * base.sigma
    if active.sum() >= 2:
        axis = _principal_axis(change[active])
    if np.sum(change[active] @ axis) < 0:
        axis = -axis
    return axis, force @ axis, False


def _principal_axis(samples: FloatArray) -> FloatArray:
    """First right singular vector of (M, 3) samples: the direction of most of their energy."""
    _, _, vt = np.linalg.svd(samples, full_matrices=False)
    return np.asarray(vt[0], dtype=np.float64)


def _noise_floor(values: FloatArray) -> float:
    """Smallest noise SD worth believing: the quantisation step's, or a tiny fraction of the values."""
    steps = np.abs(np.diff(values))
    steps = steps[steps > 0]
    quantum = float(steps.min()) / math.sqrt(12.0) if steps.size else 0.0
    return max(quantum, 1e-12 * max(1.0, float(np.max(np.abs(values)))))


def _difference_noise(values: FloatArray) -> float:
    """Noise SD from the MAD of second differences: blind to slow changes, steps and short pulses."""
    second = np.diff(values, 2)
    return max(MAD_TO_SD * float(np.median(np.abs(second))) / math.sqrt(6.0), _noise_floor(values))


def _baseline(t: FloatArray, values: FloatArray) -> _Baseline:
    """The quiet samples and the robust line through them, starting from the level the record ends at.

    A sample is quiet when it lies within :data:`QUIET_SIGMAS` noise SDs of the line and outside the
    feet of any excursion beyond them (:func:`_excursions`); the noise is the MAD of the quiet samples
    about the line. Three rounds.
    """
    n = values.size
    sigma = _difference_noise(values)
    rest, count = _resting_level(t, values, sigma)
    line = _Line(float(np.mean(t)), rest, 0.0, sigma, count, float(count), math.inf)
    quiet = np.ones(n, dtype=bool)
    dt = float(np.median(np.diff(t)))
    for _ in range(3):
        candidate = ~_excursions(values - line.at(t), sigma=sigma, dt=dt)
        if candidate.sum() < MIN_SAMPLES:
            break
        quiet = candidate
        line = _robust_line(t[quiet], values[quiet])
        sigma = max(line.sigma, _noise_floor(values))
    return _Baseline(level=line.at(t), quiet=quiet, sigma=sigma, line=line)


def _excursions(residual: FloatArray, *, sigma: float, dt: float) -> NDArray[np.bool_]:
    """Samples (N,) in an excursion from the baseline: beyond :data:`QUIET_SIGMAS` noise SDs, widened to
    where its 10-ms running mean falls within 3 of that mean's SDs of the baseline, and by 5 ms more."""
    active = np.abs(residual) > QUIET_SIGMAS * sigma
    width = max(5, round(0.01 / dt) | 1)
    smooth = np.convolve(residual, np.ones(width) / width, mode="same")
    hits = np.concatenate([[0], np.cumsum(active)])
    wide = np.zeros_like(active)
    for first, last in _runs(active | (np.abs(smooth) > 3 * sigma / math.sqrt(width)), gap=0):
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


def _robust_line(t: FloatArray, y: FloatArray) -> _Line:
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
    return _Line(t_mean, intercept, slope, sigma, y.size, _effective_count(residual), sxx_plain or math.inf)


def _effective_count(residual: FloatArray) -> float:
    """Independent samples among correlated ones: n (1 - ρ) / (1 + ρ), ρ the lag-1 autocorrelation."""
    n = residual.size
    centred = residual - residual.mean()
    power = float(centred @ centred)
    if n < 3 or power <= 0:
        return float(max(n, 1))
    rho = min(max(float(centred[1:] @ centred[:-1]) / power, 0.0), 0.95)
    return n * (1.0 - rho) / (1.0 + rho)


def _frame_notes(series: ForceSeries, direction: FloatArray | None, *, flipped: bool) -> list[str]:
    """What the reader should know about the direction used."""
    if flipped:
        return [
            "the force reads negative during the push (compression read as negative): its sign was flipped"
        ]
    if direction is None:
        return []
    vector = ", ".join(f"{component:+.3f}" for component in direction)
    if series.in_camera_frame:
        return [f"the force along its dominant direction ({vector}, camera optical frame) was used"]
    frame = f"frame {series.frame_id}" if series.frame_id else "the sensor's frame"
    return [
        f"no transform recorded: the force's magnitude along its dominant direction ({vector} in {frame}) "
        "was used"
    ]


def _drift_notes(t: FloatArray, base: _Baseline) -> list[str]:
    """A note when the baseline drifted by more than three noise SDs over the record, significantly."""
    line = base.line
    drift = line.slope * float(t[-1] - t[0])
    slope_se = line.sigma / math.sqrt(line.sxx * line.n_eff / max(line.n, 1))
    if abs(drift) <= 3 * base.sigma or abs(line.slope) <= 3 * slope_se:
        return []
    return [f"the sensor's baseline drifted by {drift:+.3g} N over the record; the drift was removed"]


# --- events -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Event:
    """One push, strike or forcing found in the force."""

    kind: Literal["step_release", "impulse", "forced"]
    value: float
    uncertainty: float
    time_s: float
    peak_n: float
    notes: list[str] = field(default_factory=list)
    hold_s: tuple[float, float] | None = None
    pulse_s: tuple[float, float] | None = None


_UNITS = {"step_release": "N", "impulse": "N·s", "forced": "N RMS"}


def _excitation(
    event: _Event, *, direction: FloatArray | None, source: str, notes: list[str]
) -> ForceExcitation:
    return ForceExcitation(
        kind=event.kind,
        value=event.value,
        uncertainty=event.uncertainty,
        time_s=event.time_s,
        direction=direction,
        source=source,
        notes=notes + event.notes,
        hold_s=event.hold_s,
        pulse_s=event.pulse_s,
    )


def _runs(mask: NDArray[np.bool_], *, gap: int = 2) -> list[tuple[int, int]]:
    """First and last index of each run of True, runs closer than ``gap`` samples joined."""
    index = np.flatnonzero(mask)
    if index.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(index) > gap + 1)
    starts = np.concatenate([[index[0]], index[breaks + 1]])
    ends = np.concatenate([index[breaks], [index[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _running_median(values: FloatArray, width: int = 5) -> FloatArray:
    """Median over ``width`` samples centred on each one (edges repeated)."""
    half = width // 2
    padded = np.pad(values, half, mode="edge")
    return np.asarray(np.median(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1))


def _events(t: FloatArray, above: FloatArray, base: _Baseline) -> tuple[list[_Event], list[str]]:
    """Pushes and strikes standing out from the baseline, and why other excursions were passed over.

    ``above`` (N,) is the force minus its baseline, the push positive. A run of samples above the noise
    inside a strike's pulse (a ringing sensor's next swing) belongs to that strike.
    """
    sigma = base.sigma
    smooth = _running_median(above)
    events: list[_Event] = []
    ignored: list[str] = []
    claimed = -math.inf
    for first, last in _runs(above > EDGE_SIGMAS * sigma):
        peak = float(above[first : last + 1].max())
        if peak <= EVENT_SIGMAS * sigma or t[first] <= claimed:
            continue
        at = f"at {t[first]:.3f} s ({peak:.3g} N)"
        if last == above.size - 1:
            ignored.append(f"the force is still above its baseline at the end of the record (from {at})")
            continue
        if last == first:
            ignored.append(f"a one-sample spike {at}: a glitch, or a strike too short for the sampling")
            continue
        if t[last] - t[first] <= PULSE_MAX_S:
            found = _strike(t, above, first, last, base)
        else:
            found = _hold(t, above, smooth, (first, last), base)
        if isinstance(found, str):
            ignored.append(found)
            continue
        events.append(found)
        claimed = found.pulse_s[1] if found.pulse_s else claimed
    return events, ignored


def _hold(
    t: FloatArray, above: FloatArray, smooth: FloatArray, run: tuple[int, int], base: _Baseline
) -> _Event | str:
    """A push held then let go, over the run ``(first, last)`` of samples above the noise.

    The hold is the stretch ending where the final drop starts in which the 5-sample running median
    stays within max(4 SD, :data:`HOLD_BAND` x the force) of the held force, from where it first reaches
    that force (the end of the push's ramp); the held force is the median over it. The release is where
    the final drop crosses half the held force, interpolated linearly between samples.
    """
    first, last = run
    span = smooth[first : last + 1]
    level = float(np.median(above[first : last + 1][span >= 0.5 * span.max()]))
    for _ in range(2):
        cross = _last_crossing(above, first, last, 0.5 * level)
        tolerance = max(4 * base.sigma, HOLD_BAND * level)
        steady = np.flatnonzero(smooth[first : cross + 1] >= level - tolerance)
        top = first + int(steady[-1]) if steady.size else first
        away = np.flatnonzero(np.abs(smooth[first:top] - level) > tolerance)
        start = first + int(away[-1]) + 1 if away.size else first
        level = float(np.median(above[start : top + 1]))
        side = np.sign(smooth[start : top + 1] - level)
        start += int(np.argmax(side != side[0]))
        if top - start + 1 < MIN_HOLD_SAMPLES:
            return f"a push at {t[first]:.3f} s with no steady hold before it was let go ({level:.3g} N)"
        level = float(np.median(above[start : top + 1]))
    half, drop = 0.5 * level, float(above[cross] - above[cross + 1])
    fraction = min(max((above[cross] - half) / drop, 0.0), 1.0) if drop > 0 else 0.0
    release = float(t[cross] + fraction * (t[cross + 1] - t[cross]))
    notes = _release_notes(t, above, cross, level)
    uncertainty = _hold_uncertainty(t, above, slice(start, top + 1), level, base)
    return _Event(
        "step_release", level, uncertainty, release, level, notes, hold_s=(float(t[start]), float(t[top]))
    )


def _last_crossing(above: FloatArray, first: int, last: int, level: float) -> int:
    """Last index i in the run (or just after it) with above[i] >= level > above[i + 1]."""
    stop = min(last + 1, above.size - 2)
    down = np.flatnonzero((above[first : stop + 1] >= level) & (above[first + 1 : stop + 2] < level))
    return first + int(down[-1]) if down.size else last


def _release_notes(t: FloatArray, above: FloatArray, cross: int, level: float) -> list[str]:
    """Notes on a slow release or a gap in the samples at the release."""
    notes = []
    steps = np.diff(t)
    gap = float(steps[cross])
    if gap > 3 * float(np.median(steps)):
        notes.append(
            f"a gap of {gap * 1e3:.3g} ms in the force at the release: its instant is that uncertain"
        )
    top = cross
    while top > 0 and above[top] < 0.9 * level:
        top -= 1
    bottom = cross + 1
    while bottom < above.size - 1 and above[bottom] > 0.1 * level:
        bottom += 1
    fall = float(t[bottom] - t[top])
    if fall > 0.02:
        notes.append(f"the force fell over about {fall * 1e3:.0f} ms: a slow release, not a sudden one")
    return notes


def _hold_uncertainty(t: FloatArray, above: FloatArray, hold: slice, level: float, base: _Baseline) -> float:
    """Standard uncertainty of the held force: three shares, combined in quadrature.

    - noise: √(π/2) x SD / √(effective samples), the median's standard error, the samples' correlation
      (sampling faster than the noise changes) counted through their lag-1 autocorrelation;
    - baseline: the drift line's standard error at the hold;
    - change: when the force creeps during the hold (a slope beyond 3 of its standard errors), its change
      over the hold / √12, since the median may differ from the force at the release by that much.
    """
    times, values = t[hold], above[hold]
    spread = values - level
    sd = max(MAD_TO_SD * float(np.median(np.abs(spread))), base.sigma * 0.5)
    n_eff = _effective_count(spread)
    noise = math.sqrt(math.pi / 2) * sd / math.sqrt(n_eff)
    drift = base.line.se(float(np.mean(times)))
    x = times - times.mean()
    sxx = float(x @ x)
    slope = float(x @ (values - values.mean())) / sxx
    slope_se = sd / math.sqrt(sxx * n_eff / values.size)
    change = abs(slope) * float(x[-1] - x[0]) / math.sqrt(12) if abs(slope) > 3 * slope_se else 0.0
    return math.sqrt(noise**2 + drift**2 + change**2)


def _strike(t: FloatArray, above: FloatArray, first: int, last: int, base: _Baseline) -> _Event | str:
    """A strike over the run ``(first, last)``: its impulse (trapezoid), centroid and uncertainty.

    The pulse runs from the last sample at or below one noise SD before the run to the first of a few
    samples (5 ms) all within :data:`EDGE_SIGMAS` SDs of the baseline after it (a ringing sensor's swings
    belong to the pulse). Uncertainty, in quadrature: the noise's, SD x √(duration x dt); the baseline's,
    its standard error x duration; the sampling's, :func:`_sampling_share`.
    """
    sigma, n = base.sigma, above.size
    dt = float(np.median(np.diff(t)))
    start = first
    while start > 0 and above[start - 1] > sigma:
        start -= 1
    if start == 0:
        return f"a strike at {t[first]:.3f} s cut by the start of the record"
    start -= 1
    settle = max(3, round(0.005 / dt))
    calm = np.abs(above[last + 1 :]) <= EDGE_SIGMAS * sigma
    settled = np.flatnonzero(np.convolve(calm, np.ones(settle), mode="valid") >= settle)
    end = last + 1 + int(settled[0]) if settled.size else n
    if end >= n - 1:
        return f"a strike at {t[first]:.3f} s whose force has not settled by the end of the record"
    times, values = t[start : end + 1], above[start : end + 1]
    weights = _trapezoid_weights(times)
    impulse = float(weights @ values)
    if impulse <= 0:
        return f"a pulse at {t[first]:.3f} s whose impulse is not positive"
    centroid = float(weights @ (values * times)) / impulse
    duration = float(times[-1] - times[0])
    noise = sigma * math.sqrt(duration * dt)
    shares = (noise, base.line.se(centroid) * duration, _sampling_share(weights, values))
    peak = float(above[first : last + 1].max())
    pulse = (float(times[0]), float(times[-1]))
    return _Event("impulse", impulse, math.hypot(*shares), centroid, peak, pulse_s=pulse)


def _trapezoid_weights(times: FloatArray) -> FloatArray:
    """Weights w (M,) such that w @ y is the trapezoid integral of y over ``times`` (M,)."""
    weights = np.empty_like(times)
    weights[1:-1] = 0.5 * (times[2:] - times[:-2])
    weights[0], weights[-1] = 0.5 * (times[1] - times[0]), 0.5 * (times[-1] - times[-2])
    return weights


def _sampling_share(weights: FloatArray, values: FloatArray) -> float:
    """The trapezoid's sampling (aliasing) error of a pulse, as a standard uncertainty.

    The pulse integrated over every 2nd sample (2 offsets) and every 3rd (3 offsets): half the spread of
    those sums is the error at a half and a third of the rate. A pulse with kinks at its ends has a
    spectrum falling as 1/f², so its error at the full rate is about a 4th and a 9th of those; the larger
    is taken. (Checked on half-sine, triangular and skewed pulses of 4 to 30 ms at 500 Hz and 1 kHz over
    random sampling phases: the actual error's SD is 0.5 to 1.3 times this, never beyond 3.2 times.)
    """
    shares = []
    for step, scale in ((2, 4.0), (3, 9.0)):
        sums = [step * float(weights[k::step] @ values[k::step]) for k in range(step)]
        shares.append(0.5 * (max(sums) - min(sums)) / scale)
    return max(shares)


def _forcing(t: FloatArray, above: FloatArray, base: _Baseline) -> _Event | None:
    """A forced vibration: the force swings up and down, regularly and by comparable amounts, to the end.

    Swings are found between turning points that stand out by 2 x :data:`QUIET_SIGMAS` noise SDs
    (:func:`_turning_points`), so the baseline does not matter. The trailing run of swings whose smallest
    is at least :data:`FORCED_SWING_FRACTION` of the largest (sustained, not decaying), cut at any gap
    over 3 x their median spacing, is a forcing when it has at least :data:`FORCED_MIN_SWINGS` swings,
    the last within about a period of the record's end. Value: the RMS about the swings' mean over whole
    cycles, the noise's share removed; time: where the first swing leaves that mean.
    """
    points = _turning_points(above, 2 * QUIET_SIGMAS * base.sigma)
    if len(points) < FORCED_MIN_SWINGS + 1:
        return None
    swings = np.abs(np.diff(above[points]))
    k, smallest, largest = swings.size - 1, float(swings[-1]), float(swings[-1])
    while k > 0 and FORCED_SWING_FRACTION * max(largest, swings[k - 1]) <= min(smallest, swings[k - 1]):
        k -= 1
        smallest, largest = min(smallest, float(swings[k])), max(largest, float(swings[k]))
    spacing = np.diff(t[points[k:]])
    half_period = float(np.median(spacing))
    chain = (
        points[k + 1 + int(np.flatnonzero(spacing > 3 * half_period)[-1]) :]
        if spacing.max() > 3 * half_period
        else points[k:]
    )
    if chain.size < FORCED_MIN_SWINGS + 1:
        return None
    if t[-1] - t[chain[-1]] > 2.5 * half_period:
        return None
    whole = chain[-1] if (chain.size - 1) % 2 == 0 else chain[-2]
    centre = float(np.mean(above[chain[0] : whole]))
    first = int(chain[0])
    while first > 0 and abs(above[first - 1] - centre) > EDGE_SIGMAS * base.sigma:
        first -= 1
    swing = above[first:] - centre
    rms = math.sqrt(max(float(np.mean(swing**2)) - base.sigma**2, 0.0))
    uncertainty = base.sigma / math.sqrt(_effective_count(swing))
    frequency = 0.5 * (chain.size - 1) / float(t[chain[-1]] - t[chain[0]])
    note = (
        f"the force keeps oscillating to the end of the record (about {frequency:.3g} Hz from "
        f"{t[first]:.3f} s, RMS {rms:.3g} N): a forced vibration, not a hold or a strike"
    )
    return _Event("forced", rms, uncertainty, float(t[first]), largest, [note])


def _turning_points(values: FloatArray, height: float) -> NDArray[np.intp]:
    """Indices of alternating maxima and minima, each left behind by more than ``height`` (hysteresis)."""
    points: list[int] = []
    high = low = 0
    state = 0  # 0 undecided, 1 rising (tracking a maximum), -1 falling (tracking a minimum)
    for i, value in enumerate(values.tolist()):
        if state >= 0 and value > values[high]:
            high = i
        if state <= 0 and value < values[low]:
            low = i
        if state >= 0 and values[high] - value > height:
            points.append(high)
            state, low = -1, i
        elif state <= 0 and value - values[low] > height:
            points.append(low)
            state, high = 1, i
    return np.asarray(points, dtype=np.intp)


def _before_forcing(events: list[_Event], forced: _Event) -> list[str]:
    """A note naming the pushes or strikes that end before a forcing starts (not used)."""
    before = [event for event in events if (event.pulse_s or (0.0, event.time_s))[1] < forced.time_s]
    if not before:
        return []
    listed = ", ".join(f"{event.kind} at {event.time_s:.3f} s" for event in before)
    return [f"before the forcing: {listed}; end the record before the forcing to use it"]


def _checked_window(window_s: tuple[float, float] | None) -> tuple[float, float] | None:
    if window_s is None:
        return None
    start, end = (float(value) for value in window_s)
    if not (math.isfinite(start) and math.isfinite(end) and start < end):
        raise ForceError(
            f"the window {window_s} is not a time span; give (start, end) in seconds, start before end"
        )
    return start, end


def _choose(
    events: list[_Event], window: tuple[float, float] | None, *, source: str
) -> tuple[_Event, list[str]]:
    """The last event before the window's end, or the strongest; a note listing the others."""
    if window is None:
        chosen = max(events, key=lambda event: event.peak_n)
        why = "the strongest was used (give the analysed window to choose)"
    else:
        before = [event for event in events if event.time_s <= window[1]]
        if not before:
            times = ", ".join(f"{event.time_s:.3f}" for event in events)
            raise ForceError(
                f"the force {source} is released or struck only at {times} s, after the window's end "
                f"({window[1]:.3f} s): the excitation must come before the motion; check the force's "
                "clock against the clip's (the log's offset_s) or the window"
            )
        chosen = max(before, key=lambda event: event.time_s)
        why = "the last before the window's end was used"
    others = [event for event in events if event is not chosen]
    if not others:
        return chosen, []
    listed = ", ".join(
        f"{event.kind} at {event.time_s:.3f} s ({event.value:.3g} {_UNITS[event.kind]})" for event in others
    )
    return chosen, [f"{len(others)} other excitation(s) in the force, not used: {listed}; {why}"]


def _nothing_message(source: str, above: FloatArray, sigma: float, ignored: list[str]) -> str:
    """The ForceError's message when no hold, release or strike was found."""
    largest = float(np.max(np.abs(above)))
    passed = f"; passed over: {'; '.join(ignored)}" if ignored else ""
    return (
        f"the force {source} shows no hold, release or strike above its noise ({sigma:.3g} N): its largest "
        f"change from the baseline is {largest:.3g} N{passed}; give --force-n / --impulse-ns, or choose "
        "another --force-topic"
    )
