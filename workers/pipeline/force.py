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
from workers.pipeline.force_baseline import MIN_SAMPLES, Baseline, baseline, difference_noise, signed_force
from workers.pipeline.force_events import UNITS, Event, before_forcing, find_events, find_forcing
from workers.pipeline.model import Excitation

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
        Wrong shapes, fewer than :data:`~workers.pipeline.force_baseline.MIN_SAMPLES` samples, non-finite
        values, or times that do not strictly increase. Rows are counted from 1 (the first sample).
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
    in_camera_frame : bool
        ``direction`` is in the camera's optical frame (a transform was recorded): the mechanics then
        take the force's component along the object's motion.
    times_s, along_n : ndarray, shape (N,), float64, or None
        The record's times and the force along ``direction`` with its baseline removed (the push
        positive): what the mechanics weigh at the object's frequency (a release that takes time, a
        strike's shape) and what a forced vibration's response is fitted to.
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
    in_camera_frame: bool = False
    times_s: FloatArray | None = field(default=None, compare=False, repr=False)
    along_n: FloatArray | None = field(default=None, compare=False, repr=False)


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
    direction, projected, _ = signed_force(series.times_s, series.force_n)
    return direction, projected


def find_excitation(series: ForceSeries, *, window_s: tuple[float, float] | None = None) -> ForceExcitation:
    """Find the excitation in a force recording: a push held then let go, a strike, or a forcing.

    The force is projected on its dominant direction (:func:`dominant_direction`), its baseline removed
    and its noise estimated from the quiet parts (see the module's docstring). Then:

    - *push, hold, release*: a stretch longer than
      :data:`~workers.pipeline.force_events.PULSE_MAX_S` well above the noise that drops to the baseline.
      Value: the median over the hold; time: where the final drop crosses halfway;
    - *strike*: a shorter pulse back to the baseline. Value: J = ∫(F - baseline) dt over the pulse
      (trapezoid); time: its centroid;
    - *forced*: the force swings across the baseline, again and again, to the end of the record. Value:
      its RMS (k and m then come from the response between the force and the motion,
      :mod:`workers.pipeline.response`).

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
    direction, projected, flipped = signed_force(series.times_s, series.force_n)
    base = baseline(times, projected)
    above = projected - base.level
    # A force that never rests hides the baseline's noise: the samples' own (second differences) sets it.
    forced = find_forcing(
        times, above, dataclasses.replace(base, sigma=min(base.sigma, difference_noise(projected)))
    )
    events, ignored = find_events(times, above, base)
    if forced is not None:  # an oscillation has no push to sign by
        notes = _frame_notes(series, direction, flipped=False) + before_forcing(events, forced)
        return _excitation(forced, direction=direction, series=series, notes=notes, along=above)
    notes = _frame_notes(series, direction, flipped=flipped) + _drift_notes(times, base)
    if not events:
        raise ForceError(_nothing_message(series.source, above, base.sigma, ignored))
    chosen, choice_notes = _choose(events, window, source=series.source)
    return _excitation(chosen, direction=direction, series=series, notes=notes + choice_notes, along=above)


def excitation_of(found: ForceExcitation) -> Excitation:
    """The :class:`~workers.pipeline.model.Excitation` (kind, value, uncertainty) for the mechanics, with
    the record's samples and the span of the release or the strike in them (the mechanics weigh them at
    the object's frequency), or a forcing's samples (for the response fit, :mod:`workers.pipeline.response`).

    Parameters
    ----------
    found : ForceExcitation

    Returns
    -------
    Excitation
        For the main object (no object, point or box chosen).
    """
    span = _drop_span(found) if found.kind == "step_release" else found.pulse_s
    return Excitation(
        kind=found.kind,
        value=found.value,
        uncertainty=found.uncertainty,
        release_time_s=None if found.kind == "forced" else found.time_s,
        source=found.source,
        notes=tuple(found.notes),
        direction=_camera_direction(found),
        force_times_s=found.times_s,
        force_along_n=found.along_n,
        event_s=span,
    )


def _drop_span(found: ForceExcitation) -> tuple[float, float] | None:
    """Start and end of a release's drop, centred on its halfway instant: as long as the fall from 90 % to
    10 % of the held force takes, over 0.8 (a linear fall's whole length)."""
    if found.hold_s is None or found.times_s is None or found.along_n is None:
        return None
    t, force = found.times_s, found.along_n
    first = int(np.searchsorted(t, found.hold_s[1]))
    crossings = []
    for share in (0.9, 0.1):
        below = np.flatnonzero(force[first:] < share * found.value)
        if below.size == 0 or first + below[0] == 0:
            return None
        i = first + int(below[0])
        y0, y1 = force[i - 1] - share * found.value, force[i] - share * found.value
        crossings.append(t[i - 1] + (t[i] - t[i - 1]) * y0 / (y0 - y1))
    half = max((crossings[1] - crossings[0]) / 0.8, float(np.median(np.diff(t)))) / 2
    return (found.time_s - half, found.time_s + half)


def _camera_direction(found: ForceExcitation) -> tuple[float, float, float] | None:
    """The force's unit direction in the camera's frame, when a transform put it there."""
    if not found.in_camera_frame or found.direction is None:
        return None
    x, y, z = (float(c) for c in found.direction)
    return (x, y, z)


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
        return [
            f"the force's dominant direction is ({vector}) in the camera optical frame (a transform was "
            "recorded)"
        ]
    frame = f"frame {series.frame_id}" if series.frame_id else "the sensor's frame"
    return [
        f"no transform recorded: the force's magnitude along its dominant direction ({vector} in {frame}) "
        "was used"
    ]


def _drift_notes(t: FloatArray, base: Baseline) -> list[str]:
    """A note when the baseline drifted by more than three noise SDs over the record, significantly."""
    line = base.line
    drift = line.slope * float(t[-1] - t[0])
    slope_se = line.sigma / math.sqrt(line.sxx * line.n_eff / max(line.n, 1))
    if abs(drift) <= 3 * base.sigma or abs(line.slope) <= 3 * slope_se:
        return []
    return [f"the sensor's baseline drifted by {drift:+.3g} N over the record; the drift was removed"]


def _excitation(
    event: Event, *, direction: FloatArray | None, series: ForceSeries, notes: list[str], along: FloatArray
) -> ForceExcitation:
    return ForceExcitation(
        kind=event.kind,
        value=event.value,
        uncertainty=event.uncertainty,
        time_s=event.time_s,
        direction=direction,
        source=series.source,
        notes=notes + event.notes,
        hold_s=event.hold_s,
        pulse_s=event.pulse_s,
        in_camera_frame=series.in_camera_frame,
        times_s=series.times_s,
        along_n=along,
    )


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
    events: list[Event], window: tuple[float, float] | None, *, source: str
) -> tuple[Event, list[str]]:
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
        f"{event.kind} at {event.time_s:.3f} s ({event.value:.3g} {UNITS[event.kind]})" for event in others
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
