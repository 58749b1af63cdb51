"""Mechanics: the release instant and the amplitude at release, and stiffness and mass from the
excitation.

Physics: ω = 2πf; spring-mass ω_n² = k/m. Held by force F then released: A = F/k. Struck by impulse J:
v0 = J/m and A = v0/ω_d.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.force_events import trapezoid_weights
from workers.pipeline.model import Excitation
from workers.pipeline.ringdown import RingdownFit

#: Standard uncertainty (radians) of the angle between a recorded force and the object's motion: the
#: robot's hand-eye calibration (its /tf) and the motion's axis (the flow's principal axis and the depth
#: series) are each good to about a degree or two.
DIRECTION_SD_RAD = math.radians(2.0)
#: Least share of a recorded force along the object's motion (cos of the angle between them) for k and m:
#: beyond about 75° the component is small and its uncertainty, |F| sin θ · DIRECTION_SD_RAD, large.
MIN_ALONG_MOTION = 0.25


def detect_release(
    velocity: NDArray[np.floating], *, relative: float = 0.12, noise_factor: float = 6.0
) -> int:
    """Index of the first flow sample in which the object moves.

    Still frames before a release carry only noise; the release is the first sample whose speed exceeds
    both ``relative`` x the peak speed and ``noise_factor`` x the noise of the quiet samples.

    Parameters
    ----------
    velocity : ndarray, shape (N,)

    Returns
    -------
    int
        0 when the object moves from the start.
    """
    speed = np.abs(np.asarray(velocity, np.float64))
    peak = float(speed.max()) if speed.size else 0.0
    if peak <= 0:
        return 0
    quiet = speed[speed < 0.05 * peak]
    noise = float(np.median(quiet)) * 1.4826 if quiet.size >= 4 else 0.0
    threshold = max(relative * peak, noise_factor * noise)
    above = np.flatnonzero(speed > threshold)
    first = int(above[0]) if above.size else 0
    # Walk back over the ramp: samples still clearly above the noise belong to the motion.
    floor = max(noise_factor * noise, 0.02 * peak)
    while first > 0 and speed[first - 1] > floor:
        first -= 1
    return first


def release_instant(fit: RingdownFit, *, sample_rate_hz: float, excitation: str | None) -> float:
    """Release time from the fitted model, seconds relative to the fit's first sample.

    Flow sample j spans frames j -> j+1, so a release first seen in sample j happened in [0, 1/fps) of the
    fit's time. For a step release the velocity is zero at release (the displacement is at its held
    extreme); for an impulse the displacement is zero. The instant is the last such point of the model
    at or before 1/fps; without an excitation the fit start is returned.

    Returns
    -------
    float
        Seconds from the fit start (at most 1/fps, at least one period earlier).
    """
    if excitation not in ("step_release", "impulse"):
        return 0.0
    omega = 2 * math.pi * fit.frequency_hz
    sigma = fit.decay_per_s
    # x ∝ e^{-σt} cos(ωt + φ); dx/dt = 0 where ωt + φ + atan(σ/ω) = nπ; x = 0 where ωt + φ = π/2 + nπ.
    offset = fit.phase_rad + (math.atan2(sigma, omega) if excitation == "step_release" else -math.pi / 2)
    t_max = 1.0 / sample_rate_hz
    n = math.floor((omega * t_max + offset) / math.pi)
    return (n * math.pi - offset) / omega


def release_amplitude(fit: RingdownFit, *, t_release_s: float, excitation: str | None) -> float:
    """Amplitude at the release instant, in the fit's units.

    Step release: the held displacement |x(t_r)|. Impulse or none: the envelope A e^{-σ t_r}.
    """
    envelope = fit.amplitude * math.exp(-fit.decay_per_s * t_release_s)
    if excitation == "step_release":
        omega = 2 * math.pi * fit.frequency_hz
        return abs(envelope * math.cos(omega * t_release_s + fit.phase_rad))
    return envelope


@dataclass(frozen=True)
class Mechanics:
    """Stiffness and mass with standard uncertainties; None when not measurable (see ``null_reasons``)."""

    stiffness_n_per_m: float | None = None
    stiffness_uncertainty_n_per_m: float | None = None
    mass_kg: float | None = None
    mass_uncertainty_kg: float | None = None
    null_reasons: list[str] = field(default_factory=list)


def stiffness_and_mass(
    *,
    kind: Literal["step_release", "impulse"],
    value: float,
    value_sd: float,
    amplitude_m: float,
    amplitude_uncertainty_m: float,
    natural_frequency_hz: float,
    damped_frequency_hz: float,
    frequency_sd_hz: float,
) -> Mechanics:
    """k and m from the excitation, the release amplitude and the frequency.

    Parameters
    ----------
    kind : ``"step_release"`` (value = held force F, N) or ``"impulse"`` (value = impulse J, N·s)
    value, value_sd : float
    amplitude_m, amplitude_uncertainty_m : float
        Held displacement (step release) or envelope amplitude at release (impulse), metres.
    natural_frequency_hz, damped_frequency_hz, frequency_sd_hz : float

    Returns
    -------
    Mechanics
    """
    if amplitude_m <= 0:
        return Mechanics(null_reasons=["amplitude is zero: the object did not move measurably"])
    wn = 2 * math.pi * natural_frequency_hz
    wd = 2 * math.pi * damped_frequency_hz
    rel_a = amplitude_uncertainty_m / amplitude_m
    rel_v = value_sd / value
    rel_w = frequency_sd_hz / max(natural_frequency_hz, 1e-12)
    if kind == "step_release":
        k = value / amplitude_m
        m = k / wn**2
        rel_k = math.hypot(rel_v, rel_a)
        rel_m = math.sqrt(rel_k**2 + (2 * rel_w) ** 2)
    else:
        m = value / (amplitude_m * wd)
        k = m * wn**2
        rel_m = math.sqrt(rel_v**2 + rel_a**2 + rel_w**2)
        rel_k = math.sqrt(rel_v**2 + rel_a**2 + rel_w**2)  # k = J ω / A: one power of ω
    return Mechanics(
        stiffness_n_per_m=k, stiffness_uncertainty_n_per_m=k * rel_k, mass_kg=m, mass_uncertainty_kg=m * rel_m
    )


def along_motion(
    excitation: Excitation, motion_direction: tuple[float, float, float] | None
) -> tuple[Excitation | None, list[str]]:
    """The excitation's component along the object's motion, for a 1-DOF spring-mass along that axis.

    A force recorded in the camera's frame (``excitation.direction`` set: a transform was recorded) acts
    on the object's mode only through its component along the motion: F_along = F · |cos θ|, and likewise
    J_along for a strike (and a forcing's samples alike). Its uncertainty adds
    |F| sin θ · :data:`DIRECTION_SD_RAD`. An excitation without
    a direction (typed, or a sensor with no transform) is returned as it is.

    Parameters
    ----------
    excitation : Excitation
    motion_direction : (x, y, z) or None
        The object's unit motion direction in the camera's frame (its sign is arbitrary).

    Returns
    -------
    excitation : Excitation or None
        With ``value`` and ``uncertainty`` projected and a note saying so; None when the force acts
        nearly across the motion (less than :data:`MIN_ALONG_MOTION` of it along), with the reason.
    reasons : list of str
        Why k and m are not measured (only with None).
    """
    if excitation.direction is None:
        return excitation, []
    force = np.asarray(excitation.direction, np.float64)
    if motion_direction is None:
        note = (
            "the object's motion direction is unknown: the force's magnitude along its own direction was used"
        )
        return dataclasses.replace(excitation, notes=(*excitation.notes, note)), []
    motion = np.asarray(motion_direction, np.float64)
    cos = min(abs(float(force @ motion)) / float(np.linalg.norm(force) * np.linalg.norm(motion)), 1.0)
    angle = math.degrees(math.acos(cos))
    if cos < MIN_ALONG_MOTION:
        return None, [
            f"the recorded force acts nearly across the object's motion ({angle:.0f}° from it): its "
            f"component along the motion ({cos * excitation.value:.3g} of {excitation.value:.3g}) is too "
            "uncertain for stiffness and mass; push or strike along the motion"
        ]
    sin = math.sqrt(max(1.0 - cos * cos, 0.0))
    value = excitation.value * cos
    sd = math.hypot(excitation.uncertainty * cos, excitation.value * sin * DIRECTION_SD_RAD)
    vector = ", ".join(f"{c:+.3f}" for c in motion)
    note = (
        f"the force was projected on the object's motion direction ({vector}, camera optical frame), "
        f"{angle:.1f}° from the force: {value:.4g} of {excitation.value:.4g}"
    )
    along = None if excitation.force_along_n is None else excitation.force_along_n * cos
    projected = dataclasses.replace(
        excitation, value=value, uncertainty=sd, notes=(*excitation.notes, note), force_along_n=along
    )
    return projected, []


def at_frequency(excitation: Excitation, *, frequency_hz: float) -> Excitation:
    """A recorded release or strike weighed at the object's frequency: what it excites of the oscillation.

    A spring-mass let go by a force that falls from F to 0 rings with amplitude (1/k) |∫ F'(t) e^{-iωt} dt|:
    F/k for a sudden drop, less for one that takes time (sin(ωT/2) / (ωT/2) for a linear fall over T: a
    gripper opening over 40 ms at 10 Hz starts 76 % of a sudden release's swing). A strike sets the
    velocity |∫ F(t) e^{-iωt} dt| / m, its impulse for a pulse short against the period. So the held force
    (the impulse) is scaled by the ratio of the drop's (the pulse's) Fourier component at ω to its plain
    sum, over the recorded samples in ``excitation.event_s``. An excitation without samples (typed) is
    returned as it is, and so is one whose ratio rounds to 1.

    Parameters
    ----------
    excitation : Excitation
    frequency_hz : float
        The object's (damped) frequency.

    Returns
    -------
    Excitation
        With ``value`` and ``uncertainty`` scaled and a note saying by how much.
    """
    t, force = excitation.force_times_s, excitation.force_along_n
    if excitation.kind == "forced" or t is None or force is None or excitation.event_s is None:
        return excitation
    dt = float(np.median(np.diff(t)))
    start, end = excitation.event_s
    margin = max(0.5 * (end - start), 0.01, 2 * dt)  # the drop's feet, which its span may leave out
    inside = (t >= start - margin) & (t <= end + margin)
    if inside.sum() < 2:
        return excitation
    t, force = t[inside], force[inside]
    omega = 2 * math.pi * frequency_hz
    if excitation.kind == "step_release":
        change, when = np.diff(force), 0.5 * (t[1:] + t[:-1])
    else:  # the pulse's trapezoid integral, as its impulse was taken
        change, when = force * trapezoid_weights(t), t
    plain = abs(float(change.sum()))
    if plain <= 0:
        return excitation
    factor = min(abs(complex(np.sum(change * np.exp(-1j * omega * when)))) / plain, 1.0)
    if factor > 0.999:
        return excitation
    what = "release" if excitation.kind == "step_release" else "strike"
    note = (
        f"the {what} took {(end - start) * 1000:.0f} ms: at {frequency_hz:.4g} Hz it excites "
        f"{factor * 100:.1f} % of what a sudden one would, so it counts as {excitation.value * factor:.4g} "
        f"{'N' if excitation.kind == 'step_release' else 'N·s'}"
    )
    return dataclasses.replace(
        excitation,
        value=excitation.value * factor,
        uncertainty=excitation.uncertainty * factor,
        notes=(*excitation.notes, note),
    )
