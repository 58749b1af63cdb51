"""One object measured: its motion tracked and fitted, the frequency and damping with uncertainties that
include the model's systematic floors, the amplitude at release in metres, stiffness and mass from the
excitation, and the series the figures plot.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import Intrinsics
from workers.pipeline.confidence import Confidence
from workers.pipeline.detection import regime_of
from workers.pipeline.errors import ParameterError
from workers.pipeline.mechanics import release_amplitude, release_instant, stiffness_and_mass
from workers.pipeline.metric import metric_amplitude
from workers.pipeline.model import Excitation, ObjectMeasurement
from workers.pipeline.peaks import Peak
from workers.pipeline.ringdown import Ringdown, RingdownFit, sliding_ringdown
from workers.pipeline.stream import FrameBuffers
from workers.pipeline.tracking import CoarseView, second_motion, track_object

#: Systematic floors on the ring-down fit's statistical uncertainties (model mismatch: projection
#: nonlinearity, registration errors correlated with the motion), measured on randomised ground truth.
FREQUENCY_REL_FLOOR = 3e-4
#: ... and, for a strongly damped object, this fraction of its resonance's half-power width (2 zeta f):
#: model mismatch shifts a broad resonance further (a clear 8-10 Hz object at zeta 0.09 is 8e-4 off).
FREQUENCY_LINEWIDTH_FLOOR = 0.005
DAMPING_REL_FLOOR = 0.015
DAMPING_ABS_FLOOR = 3e-4


def frequency_sd_hz(fit: RingdownFit) -> float:
    """The frequency's standard uncertainty: the fit's own with the systematic floors added."""
    f_floor = max(FREQUENCY_REL_FLOOR, FREQUENCY_LINEWIDTH_FLOOR * 2 * abs(fit.damping_ratio))
    return math.hypot(fit.frequency_sd_hz, f_floor * fit.frequency_hz)


def damping_sd(fit: RingdownFit) -> float:
    """The damping ratio's standard uncertainty: the fit's own with the systematic floors added."""
    return math.sqrt(fit.damping_sd**2 + (DAMPING_REL_FLOOR * fit.damping_ratio) ** 2 + DAMPING_ABS_FLOOR**2)


def bounding_box(mask: NDArray[np.bool_]) -> tuple[int, int, int, int]:
    """(x, y, width, height) of a mask's pixels; zeros for an empty mask."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return (0, 0, 0, 0)
    x0, y0 = int(xs.min()), int(ys.min())
    return (x0, y0, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1)


def measure_object(
    *,
    label: int,
    peak: Peak,
    mask: NDArray[np.bool_],
    full_mask: NDArray[np.bool_],
    buffers: FrameBuffers,
    fps: float,
    pixel_scale: float,
    intrinsics: Intrinsics | None,
    depth_override: float | None,
    excitation: Excitation | None,
    excluded: list[str],
    band_hz: tuple[float, float] | None = None,
    confidence: Confidence | None = None,
    coarse: CoarseView | None = None,
) -> ObjectMeasurement:
    """Measure one object of the window.

    Parameters
    ----------
    label : int
        The object's id (its value in the label image).
    peak : Peak
        Its spectral peak (the fit's starting frequency; its harmonics are reported).
    mask : ndarray of bool, shape (h, w)
        Its pixels on the flow grid.
    full_mask : ndarray of bool, shape (H, W)
        ... at input resolution, over the whole frame.
    buffers : FrameBuffers
    fps : float
        Rate of the flow samples, Hz.
    pixel_scale : float
        Input pixels per grid pixel.
    intrinsics : Intrinsics or None
    depth_override : float or None
        A user-given constant distance (clips without depth).
    excitation : Excitation or None
        How it was excited; None: stiffness and mass are not measured.
    excluded : list of str
        Notes on pixels removed from its mask.
    band_hz : (low, high), optional
        The analysed band (the fitted frequency stays inside it).
    confidence : Confidence, optional
        Of the grid's flow (:mod:`workers.pipeline.confidence`).
    coarse : CoarseView, optional
        The object on the first pass's coarse grid (see :func:`~workers.pipeline.tracking.track_object`).

    Returns
    -------
    ObjectMeasurement
    """
    track = track_object(
        buffers,
        mask,
        fps=fps,
        pixel_scale=pixel_scale,
        frequency_guess_hz=peak.frequency_hz,
        band_hz=band_hz,
        confidence=confidence,
        coarse=coarse,
    )
    fit, onset, velocity = track.fit, track.onset, track.velocity_px
    f_sd = frequency_sd_hz(fit)
    zeta_sd = damping_sd(fit)
    kind = excitation.kind if excitation else None
    t_rel = release_instant(fit, fps=fps, excitation=kind)
    amp_px = release_amplitude(fit, t_release_s=t_rel, excitation=kind)
    amp_sd_px = fit.amplitude_sd * math.exp(-fit.decay_per_s * t_rel)
    release_time = buffers.start_s + float(buffers.times_s[onset]) + t_rel
    times_from_onset = buffers.times_s - buffers.times_s[onset]

    metric = metric_amplitude(
        fit=fit,
        amplitude_px=amp_px,
        amplitude_sd_px=amp_sd_px,
        axis_px=track.axis_px,
        source=track.source,
        depth=buffers.depth,
        region=track.region,
        shifts_grid_px=None if track.shifts_px is None else track.shifts_px / pixel_scale,
        times_from_onset_s=times_from_onset,
        onset=onset,
        full_mask=full_mask,
        intrinsics=intrinsics,
        depth_override_m=depth_override,
    )
    null_reasons = list(metric.null_reasons)
    notes = [*excluded, *metric.notes]
    k = k_sd = m = m_sd = None
    if excitation is None:
        null_reasons.append("no excitation given: stiffness and mass need a held force or an impulse")
    elif metric.amplitude_m is not None and metric.amplitude_sd_m is not None:
        mech = stiffness_and_mass(
            kind=excitation.kind,
            value=excitation.value,
            value_sd=excitation.uncertainty,
            amplitude_m=metric.amplitude_m,
            amplitude_sd_m=metric.amplitude_sd_m,
            natural_frequency_hz=fit.natural_frequency_hz,
            damped_frequency_hz=fit.frequency_hz,
            frequency_sd_hz=f_sd,
        )
        k, k_sd, m, m_sd = mech.stiffness_n_per_m, mech.stiffness_sd, mech.mass_kg, mech.mass_sd
        null_reasons.extend(mech.null_reasons)

    n = len(velocity)
    ringdown = None
    if n - onset >= 16:
        ringdown = sliding_ringdown(velocity[onset:], fps=fps, frequency_hz=fit.frequency_hz)
        ringdown = Ringdown(
            times_s=ringdown.times_s + float(buffers.times_s[onset]),
            amplitude=ringdown.amplitude,
            frequency_hz=ringdown.frequency_hz,
            spectrogram_hz=ringdown.spectrogram_hz,
            spectrogram_power=ringdown.spectrogram_power,
        )
    # Clipped where the sensor's grey level is at its limit: one colour channel at 0 (a saturated blue)
    # still carries texture in the others.
    grey = buffers.first_rgb[full_mask].astype(np.float32).mean(axis=1)
    saturated = float(np.mean((grey >= 254) | (grey <= 1))) if grey.size else 0.0
    disp = np.concatenate([[0.0], np.cumsum(velocity)])
    t = times_from_onset[: n + 1]
    model = np.full(n + 1, np.nan)
    after = t >= t_rel
    model[after] = fit.displacement(t[after])
    # Align the integrated displacement to the model's mean level after release.
    if after.any():
        disp = disp - np.nanmean(disp[after] - model[after])
    obj = ObjectMeasurement(
        id=label,
        eigenfrequency_hz=fit.frequency_hz,
        eigenfrequency_sd_hz=f_sd,
        natural_frequency_hz=fit.natural_frequency_hz,
        damping_ratio=fit.damping_ratio,
        damping_ratio_sd=zeta_sd,
        amplitude_px=amp_px,
        amplitude_m=metric.amplitude_m,
        amplitude_sd_m=metric.amplitude_sd_m,
        depth_m=metric.depth_m,
        motion_direction=metric.direction,
        stiffness_n_per_m=k,
        stiffness_sd=k_sd,
        mass_kg=m,
        mass_sd=m_sd,
        pixel_count=int(full_mask.sum()),
        bbox_px=bounding_box(full_mask),
        harmonics_hz=list(peak.harmonics_hz),
        release_time_s=release_time,
        snr_db=fit.snr_db,
        detection_db=fit.detection_db,
        concentration=fit.concentration,
        second_motion=second_motion(buffers.flow, mask, frequency_hz=fit.frequency_hz, fps=fps),
        null_reasons=null_reasons,
        amplitude_source=track.source,
        notes=notes,
        ringdown=ringdown,
        saturated_fraction=saturated,
        fitted_duration_s=float(buffers.times_s[n] - buffers.times_s[onset]),
        displacement_px=disp,
        model_displacement_px=model,
        axis_px=track.axis_px,
    )
    # Whether it decays is judged on the fit's own (statistical) uncertainty, before systematic floors.
    decay_sd = fit.damping_sd * 2 * math.pi * fit.natural_frequency_hz * fit.duration_s
    obj.regime = regime_of(obj, decay=fit.decay, decay_sd=decay_sd)
    if obj.regime != "ring_down":
        # Damping needs a decay to measure; a sustained (or growing) oscillation shows none here.
        obj.damping_ratio = obj.damping_ratio_sd = None
        obj.natural_frequency_hz = fit.frequency_hz
        grows = "grows" if obj.regime == "growing" else "does not decay"
        obj.null_reasons.insert(
            0,
            f"damping: the motion {grows} in the analysed window ({math.exp(-fit.decay) * 100:.0f} % of its "
            f"amplitude left after {fit.duration_s:.3g} s): a {obj.regime} vibration, not a ring-down",
        )
        if excitation is None:
            obj.release_time_s = None
    return obj


def assign_excitations(
    excitations: list[Excitation], labels: NDArray[np.uint16], count: int
) -> dict[int, Excitation]:
    """Resolve each excitation to an object label: by id, by an image point, by a box, or the main one."""
    out: dict[int, Excitation] = {}
    for exc in excitations:
        label: int
        if exc.object_id is not None:
            label = exc.object_id
            where = f"object {label}"
        elif exc.point_px is not None:
            x, y = (round(v) for v in exc.point_px)
            where = f"point ({x}, {y})"
            if not (0 <= y < labels.shape[0] and 0 <= x < labels.shape[1]):
                raise ParameterError(
                    f"excitation {where} is outside the {labels.shape[1]}x{labels.shape[0]} frame"
                )
            label = int(labels[y, x])
            if label == 0:
                # Nearest object within 5 % of the frame diagonal.
                ys, xs = np.nonzero(labels)
                if len(xs):
                    d2 = (xs - x) ** 2 + (ys - y) ** 2
                    i = int(np.argmin(d2))
                    if d2[i] <= (0.05 * math.hypot(*labels.shape)) ** 2:
                        label = int(labels[ys[i], xs[i]])
        elif exc.box_px is not None:
            x, y, w, h = (round(v) for v in exc.box_px)
            where = f"box ({x}, {y}, {w}, {h})"
            crop = labels[max(0, y) : max(0, y + h), max(0, x) : max(0, x + w)]
            counts = np.bincount(crop.ravel(), minlength=count + 1)[1:]
            label = int(np.argmax(counts)) + 1 if counts.size and counts.max() > 0 else 0
        else:
            label = 1
            where = "the main object"
        if count == 0:
            continue  # nothing moved: the quality notes say so; the excitation applies to nothing
        if not 1 <= label <= count:
            raise ParameterError(
                f"excitation for {where} matches no object: {count} object(s) were found; "
                "name one by id, or by a point or box on it"
            )
        if label in out:
            raise ParameterError(f"two excitations apply to object {label}; give at most one per object")
        out[label] = exc
    return out


__all__ = ["assign_excitations", "bounding_box", "damping_sd", "frequency_sd_hz", "measure_object"]
