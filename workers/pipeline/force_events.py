"""Pushes, strikes and forcings found in a force record whose baseline is known
(:mod:`workers.pipeline.force_baseline`): the held force and its release, a strike's impulse, a force that
keeps acting, each with its standard uncertainty. Times in seconds, forces in newtons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.force_baseline import MAD_TO_SD, MIN_SAMPLES, QUIET_SIGMAS, Baseline, runs
from workers.pipeline.lstsq import effective_count

FloatArray = NDArray[np.float64]

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
#: A forced vibration is sustained: the RMS of its second half is at least this fraction of its first's.
FORCED_SWING_FRACTION = 0.3


@dataclass(frozen=True)
class Event:
    """One push, strike or forcing found in the force."""

    kind: Literal["step_release", "impulse", "forced"]
    value: float
    uncertainty: float
    time_s: float
    peak_n: float
    notes: list[str] = field(default_factory=list)
    hold_s: tuple[float, float] | None = None
    pulse_s: tuple[float, float] | None = None


UNITS = {"step_release": "N", "impulse": "N·s", "forced": "N RMS"}


def _running_median(values: FloatArray, width: int = 5) -> FloatArray:
    """Median over ``width`` samples centred on each one (edges repeated)."""
    half = width // 2
    padded = np.pad(values, half, mode="edge")
    return np.asarray(np.median(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1))


def find_events(t: FloatArray, above: FloatArray, base: Baseline) -> tuple[list[Event], list[str]]:
    """Pushes and strikes standing out from the baseline, and why other excursions were passed over.

    ``above`` (N,) is the force minus its baseline, the push positive. A run of samples above the noise
    inside a strike's pulse (a ringing sensor's next swing) belongs to that strike.
    """
    sigma = base.sigma
    smooth = _running_median(above)
    events: list[Event] = []
    ignored: list[str] = []
    claimed = -math.inf
    for first, last in runs(above > EDGE_SIGMAS * sigma):
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
    t: FloatArray, above: FloatArray, smooth: FloatArray, run: tuple[int, int], base: Baseline
) -> Event | str:
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
    return Event(
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


def _hold_uncertainty(t: FloatArray, above: FloatArray, hold: slice, level: float, base: Baseline) -> float:
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
    n_eff = effective_count(spread)
    noise = math.sqrt(math.pi / 2) * sd / math.sqrt(n_eff)
    drift = base.line.se(float(np.mean(times)))
    x = times - times.mean()
    sxx = float(x @ x)
    slope = float(x @ (values - values.mean())) / sxx
    slope_se = sd / math.sqrt(sxx * n_eff / values.size)
    change = abs(slope) * float(x[-1] - x[0]) / math.sqrt(12) if abs(slope) > 3 * slope_se else 0.0
    return math.sqrt(noise**2 + drift**2 + change**2)


def _strike(t: FloatArray, above: FloatArray, first: int, last: int, base: Baseline) -> Event | str:
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
    weights = trapezoid_weights(times)
    impulse = float(weights @ values)
    if impulse <= 0:
        return f"a pulse at {t[first]:.3f} s whose impulse is not positive"
    centroid = float(weights @ (values * times)) / impulse
    duration = float(times[-1] - times[0])
    noise = sigma * math.sqrt(duration * dt)
    shares = (noise, base.line.se(centroid) * duration, _sampling_share(weights, values))
    peak = float(above[first : last + 1].max())
    pulse = (float(times[0]), float(times[-1]))
    return Event("impulse", impulse, math.hypot(*shares), centroid, peak, pulse_s=pulse)


def trapezoid_weights(times: FloatArray) -> FloatArray:
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


def find_forcing(t: FloatArray, above: FloatArray, base: Baseline) -> Event | None:
    """A forced vibration: the force keeps swinging up and down, without dying away, to the end.

    Swings are found between turning points that stand out by 2 x :data:`QUIET_SIGMAS` noise SDs
    (:func:`_turning_points`), so the baseline does not matter. The trailing run of them, cut at any gap
    over 3 x their median spacing, is a forcing when it has at least :data:`FORCED_MIN_SWINGS` swings, the
    last within about a period of the record's end, and is sustained: the RMS of its second half is at
    least :data:`FORCED_SWING_FRACTION` of its first half's (a sensor ringing after a strike dies away).
    One tone or many (a sweep, a multisine, a random force) alike. Value: the RMS about the swings' mean,
    the noise's share removed; time: where the first swing leaves the level before it.
    """
    points = _turning_points(above, 2 * QUIET_SIGMAS * base.sigma)
    if len(points) < FORCED_MIN_SWINGS + 1:
        return None
    spacing = np.diff(t[points])
    half_period = float(np.median(spacing[-2 * FORCED_MIN_SWINGS :]))
    gaps = np.flatnonzero(spacing > 3 * half_period)
    chain = points[int(gaps[-1]) + 1 :] if gaps.size else points
    if chain.size < FORCED_MIN_SWINGS + 1 or t[-1] - t[chain[-1]] > 2.5 * half_period:
        return None
    whole = chain[-1] if (chain.size - 1) % 2 == 0 else chain[-2]
    centre = float(np.mean(above[chain[0] : whole]))
    first = int(chain[0])
    before = float(np.median(above[:first])) if first >= MIN_SAMPLES else centre  # the level it left
    while first > 0 and abs(above[first - 1] - before) > EDGE_SIGMAS * base.sigma:
        first -= 1
    swing = above[first:] - centre
    half = swing.size // 2
    if np.sqrt(np.mean(swing[half:] ** 2)) < FORCED_SWING_FRACTION * np.sqrt(np.mean(swing[:half] ** 2)):
        return None  # dying away: a ringing, not a forcing
    rms = math.sqrt(max(float(np.mean(swing**2)) - base.sigma**2, 0.0))
    uncertainty = base.sigma / math.sqrt(effective_count(swing))
    frequency = 0.5 * (chain.size - 1) / float(t[chain[-1]] - t[chain[0]])
    note = (
        f"the force keeps oscillating to the end of the record (about {frequency:.3g} Hz from "
        f"{t[first]:.3f} s, RMS {rms:.3g} N): a forced vibration, not a hold or a strike"
    )
    largest = float(np.max(np.abs(swing)))
    return Event("forced", rms, uncertainty, float(t[first]), largest, [note])


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


def before_forcing(events: list[Event], forced: Event) -> list[str]:
    """A note naming the pushes or strikes that end before a forcing starts (not used)."""
    before = [event for event in events if (event.pulse_s or (0.0, event.time_s))[1] < forced.time_s]
    if not before:
        return []
    listed = ", ".join(f"{event.kind} at {event.time_s:.3f} s" for event in before)
    return [f"before the forcing: {listed}; end the record before the forcing to use it"]
