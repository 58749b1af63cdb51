"""One object measured: its motion tracked and fitted, the frequency and damping with uncertainties that
include the model's systematic floors, the amplitude at release in metres, stiffness and mass from the
excitation, and the series the figures plot.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import Intrinsics
from workers.pipeline.confidence import Confidence
from workers.pipeline.errors import AnalysisError, ForceError, ParameterError
from workers.pipeline.mechanics import (
    Mechanics,
    along_motion,
    at_frequency,
    release_amplitude,
    release_instant,
    stiffness_and_mass,
)
from workers.pipeline.metric import DepthContext, ImageAmplitude, MetricAmplitude, metric_amplitude
from workers.pipeline.model import BAND_NYQUIST_FRACTION, Excitation, ObjectMeasurement
from workers.pipeline.modes import GridDepth, ObjectModeShapes, object_modes
from workers.pipeline.peaks import Peak
from workers.pipeline.release_fit import FitHints
from workers.pipeline.ringdown import (
    Ringdown,
    RingdownFit,
    damping_sd,
    frequency_sd_hz,
    regime_of_fit,
    sliding_ringdown,
)
from workers.pipeline.stream import FrameBuffers
from workers.pipeline.tracking import CoarseView, Track, second_motion, track_object


def bounding_box(mask: NDArray[np.bool_]) -> tuple[int, int, int, int]:
    """(x, y, width, height) of a mask's pixels; zeros for an empty mask."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return (0, 0, 0, 0)
    x0, y0 = int(xs.min()), int(ys.min())
    return (x0, y0, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1)


@dataclass(frozen=True)
class WindowContext:
    """What every object of a window is measured against.

    Attributes
    ----------
    buffers : FrameBuffers
    sample_rate_hz : float
        Rate of the flow samples, Hz.
    pixel_scale : float
        Input pixels per grid pixel.
    intrinsics : Intrinsics or None
    depth_override_m : float or None
        A user-given constant distance (clips without depth).
    band_hz : (low, high) or None
        The analysed band (the fitted frequency stays inside it).
    confidence : Confidence or None
        Of the grid's flow (:mod:`workers.pipeline.confidence`).
    """

    buffers: FrameBuffers
    sample_rate_hz: float
    pixel_scale: float
    intrinsics: Intrinsics | None = None
    depth_override_m: float | None = None
    band_hz: tuple[float, float] | None = None
    confidence: Confidence | None = None


@dataclass(frozen=True)
class Region:
    """One object of the window, as segmentation found it.

    Attributes
    ----------
    label : int
        The object's id (its value in the label image).
    peak : Peak
        Its spectral peak (the fit's starting frequency; its harmonics are reported).
    mask : ndarray of bool, shape (h, w)
        Its pixels on the flow grid.
    full_mask : ndarray of bool, shape (H, W)
        ... at input resolution, over the whole frame.
    excluded : tuple of str
        Notes on pixels removed from its mask.
    coarse : CoarseView or None
        The object on the first pass's coarse grid (see :func:`~workers.pipeline.tracking.track_object`).
    """

    label: int
    peak: Peak
    mask: NDArray[np.bool_]
    full_mask: NDArray[np.bool_]
    excluded: tuple[str, ...] = ()
    coarse: CoarseView | None = None


@dataclass(frozen=True)
class _Release:
    """When and from how far the object was let go (or struck), from its fitted motion."""

    t_rel: float  # seconds after the motion's onset
    amp_px: float
    amp_sd_px: float
    time_s: float  # seconds from the clip's first frame
    times_from_onset: NDArray[np.float64]


def measure_object(
    region: Region, window: WindowContext, *, excitation: Excitation | None = None
) -> ObjectMeasurement:
    """Measure one object of the window.

    Parameters
    ----------
    region : Region
    window : WindowContext
    excitation : Excitation or None
        How it was excited; None: stiffness and mass are not measured.

    Returns
    -------
    ObjectMeasurement
    """
    track = track_object(
        window.buffers,
        region.mask,
        sample_rate_hz=window.sample_rate_hz,
        pixel_scale=window.pixel_scale,
        hints=FitHints(region.peak.frequency_hz, window.band_hz, _free_from(excitation, window)),
        confidence=window.confidence,
        coarse=region.coarse,
    )
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="modes") as pool:
        # the modes need the motion's onset only: sought beside the rest (their transforms and products
        # release the interpreter)
        modes = pool.submit(_modes, track, region, window)
        return _measured(region, window, track, excitation, modes.result)


def _measured(
    region: Region,
    window: WindowContext,
    track: Track,
    excitation: Excitation | None,
    modes: Callable[[], ObjectModeShapes | None],
) -> ObjectMeasurement:
    """The object's measurement from its track (:func:`measure_object`); ``modes`` gives its modes."""
    fit = track.fit
    release = _release(track, window, excitation)
    metric = _metric(track, release, region, window)
    mech, used = _mechanics(track, release, metric, excitation, window)
    ringdown = _ringdown(track, window)
    regime = regime_of_fit(fit, ringdown)
    ringing = regime == "ring_down"
    displacement, model = _displacements(track, release)
    return ObjectMeasurement(
        id=region.label,
        eigenfrequency_hz=fit.frequency_hz,
        eigenfrequency_uncertainty_hz=frequency_sd_hz(fit),
        # Damping needs a decay to measure; a sustained (or growing) oscillation shows none here.
        natural_frequency_hz=fit.natural_frequency_hz if ringing else fit.frequency_hz,
        damping_ratio=fit.damping_ratio if ringing else None,
        damping_ratio_uncertainty=damping_sd(fit) if ringing else None,
        amplitude_px=release.amp_px,
        amplitude_m=metric.amplitude_m,
        amplitude_uncertainty_m=metric.amplitude_uncertainty_m,
        depth_m=metric.depth_m,
        motion_direction=metric.direction,
        stiffness_n_per_m=mech.stiffness_n_per_m,
        stiffness_uncertainty_n_per_m=mech.stiffness_uncertainty_n_per_m,
        mass_kg=mech.mass_kg,
        mass_uncertainty_kg=mech.mass_uncertainty_kg,
        pixel_count=int(region.full_mask.sum()),
        bbox_px=bounding_box(region.full_mask),
        harmonics_hz=list(region.peak.harmonics_hz),
        release_time_s=release.time_s if ringing or excitation is not None else None,
        snr_db=fit.snr_db,
        detection_db=fit.detection_db,
        concentration=fit.concentration,
        second_motion=second_motion(
            window.buffers.flow,
            region.mask,
            frequency_hz=fit.frequency_hz,
            sample_rate_hz=window.sample_rate_hz,
        ),
        null_reasons=[*_regime_reasons(fit, regime), *metric.null_reasons, *mech.null_reasons],
        amplitude_source=track.source,
        notes=[*region.excluded, *metric.notes],
        ringdown=ringdown,
        saturated_fraction=_saturated(window.buffers.first_rgb, region.full_mask),
        fitted_duration_s=float(
            window.buffers.times_s[len(track.velocity_px)] - window.buffers.times_s[track.onset]
        ),
        displacement_px=displacement,
        model_displacement_px=model,
        axis_px=track.axis_px,
        regime=regime,
        modes=modes(),
        excitation=used,
    )


def _free_from(excitation: Excitation | None, window: WindowContext) -> float | None:
    """Window clock: when the object is free, where a force sensor saw the release or the strike end."""
    if excitation is None or excitation.event_s is None:
        return None
    return excitation.event_s[1] - window.buffers.start_s


def _modes(track: Track, region: Region, window: WindowContext) -> ObjectModeShapes | None:
    """The object's modes and their shapes over its mask (:mod:`workers.pipeline.modes`), from its
    motion's onset; None when the window is too short to seek them."""
    band = window.band_hz or (0.0, BAND_NYQUIST_FRACTION * window.sample_rate_hz / 2)
    intrinsics = window.intrinsics
    depth = window.buffers.depth if window.buffers.depth is not None else window.depth_override_m
    try:
        return object_modes(
            window.buffers.flow,
            region.mask,
            sample_rate_hz=window.sample_rate_hz,
            band_hz=band,
            start_index=track.onset,
            roi=window.buffers.box(region.full_mask.shape),
            depth=None
            if depth is None or intrinsics is None
            else GridDepth(depth, (intrinsics.fx, intrinsics.fy)),
        )
    except (AnalysisError, ParameterError):
        return None


def _release(track: Track, window: WindowContext, excitation: Excitation | None) -> _Release:
    """The release (or strike) instant and the amplitude then, from the fitted model."""
    fit, buffers = track.fit, window.buffers
    kind = excitation.kind if excitation else None
    fit_start_s = buffers.start_s + float(buffers.times_s[track.onset])
    if excitation is not None and excitation.release_time_s is not None:
        t_rel = excitation.release_time_s - fit_start_s  # a force sensor saw it: no guess from the motion
    else:
        t_rel = release_instant(fit, sample_rate_hz=window.sample_rate_hz, excitation=kind)
    return _Release(
        t_rel=t_rel,
        amp_px=release_amplitude(fit, t_release_s=t_rel, excitation=kind),
        amp_sd_px=fit.amplitude_sd * math.exp(-fit.decay_per_s * t_rel),
        time_s=fit_start_s + t_rel,
        times_from_onset=buffers.times_s - buffers.times_s[track.onset],
    )


def _metric(track: Track, release: _Release, region: Region, window: WindowContext) -> MetricAmplitude:
    """The amplitude at release in metres (see :func:`~workers.pipeline.metric.metric_amplitude`)."""
    fit, onset, buffers = track.fit, track.onset, window.buffers
    amp_px, amp_sd_px, times_from_onset = release.amp_px, release.amp_sd_px, release.times_from_onset
    full_mask, intrinsics, depth_override = region.full_mask, window.intrinsics, window.depth_override_m
    pixel_scale = window.pixel_scale
    metric = metric_amplitude(
        ImageAmplitude(
            fit=fit,
            amplitude_px=amp_px,
            amplitude_sd_px=amp_sd_px,
            axis_px=track.axis_px,
            source=track.source,
        ),
        DepthContext(
            depth=buffers.depth,
            region=track.region,
            shifts_grid_px=None if track.shifts_px is None else track.shifts_px / pixel_scale,
            times_from_onset_s=times_from_onset,
            onset=onset,
            override_m=depth_override,
        ),
        full_mask=full_mask,
        intrinsics=intrinsics,
    )
    return metric


def object_mechanics(
    fit: RingdownFit, metric: MetricAmplitude, excitation: Excitation | None, *, frequency_sd_hz: float
) -> Mechanics:
    """Stiffness and mass from the excitation, the metric amplitude and the fitted frequency (with its
    standard uncertainty ``frequency_sd_hz``), or why they are not measured."""
    if excitation is None:
        return Mechanics(
            null_reasons=["no excitation given: stiffness and mass need a held force or an impulse"]
        )
    if metric.amplitude_m is None or metric.amplitude_uncertainty_m is None:
        return Mechanics()
    if excitation.kind == "forced":  # the response between force and motion: forced_mechanics
        return Mechanics(null_reasons=["a forced vibration needs the force's samples and the motion's"])
    return stiffness_and_mass(
        kind=excitation.kind,
        value=excitation.value,
        value_sd=excitation.uncertainty,
        amplitude_m=metric.amplitude_m,
        amplitude_uncertainty_m=metric.amplitude_uncertainty_m,
        natural_frequency_hz=fit.natural_frequency_hz,
        damped_frequency_hz=fit.frequency_hz,
        frequency_sd_hz=frequency_sd_hz,
    )


def _mechanics(
    track: Track,
    release: _Release,
    metric: MetricAmplitude,
    excitation: Excitation | None,
    window: WindowContext,
) -> tuple[Mechanics, Excitation | None]:
    """Stiffness and mass, and the excitation as used: a recorded force taken along the object's motion
    (:func:`~workers.pipeline.mechanics.along_motion`), a forced vibration's response fit, or the held
    force or impulse with the metric amplitude."""
    if excitation is None:
        return object_mechanics(track.fit, metric, None, frequency_sd_hz=frequency_sd_hz(track.fit)), None
    used, across = along_motion(excitation, metric.direction)
    if used is None:
        return Mechanics(null_reasons=across), excitation
    if used.kind == "forced":
        return forced_mechanics(track, release, metric, used, window)
    used = at_frequency(used, frequency_hz=track.fit.frequency_hz)
    return object_mechanics(track.fit, metric, used, frequency_sd_hz=frequency_sd_hz(track.fit)), used


def forced_mechanics(
    track: Track, release: _Release, metric: MetricAmplitude, excitation: Excitation, window: WindowContext
) -> tuple[Mechanics, Excitation]:
    """Stiffness and mass of an object a recorded force kept driving: the response between the force and
    the motion in metres, one degree of freedom (:func:`~workers.pipeline.response.fit_response`), and the
    excitation with a note of the fit (damping, natural frequency, share explained)."""
    from workers.pipeline.response import fit_response

    if metric.amplitude_m is None or metric.amplitude_uncertainty_m is None or release.amp_px <= 0:
        return Mechanics(), excitation
    assert excitation.force_times_s is not None
    assert excitation.force_along_n is not None
    metres_per_px = metric.amplitude_m / release.amp_px
    displacement_px = _integrated(track)
    times = window.buffers.start_s + window.buffers.times_s[: displacement_px.size]
    try:
        fit = fit_response(
            excitation.force_times_s,
            excitation.force_along_n,
            times,
            displacement_px * metres_per_px,
            frequency_hz=track.fit.frequency_hz,
        )
    except ForceError as exc:
        return Mechanics(null_reasons=[str(exc)]), excitation
    rel_scale = metric.amplitude_uncertainty_m / metric.amplitude_m  # the metres per pixel
    k, m = fit.stiffness_n_per_m, fit.mass_kg
    note = (
        f"stiffness and mass from the response between the recorded force and the motion (one degree of "
        f"freedom, {fit.frames} frames): damping {fit.damping_n_s_per_m:.3g} ± "
        f"{fit.damping_uncertainty_n_s_per_m:.2g} N·s/m (ratio {fit.damping_ratio:.3g}), natural frequency "
        f"{fit.natural_frequency_hz:.4g} ± {fit.natural_frequency_uncertainty_hz:.2g} Hz; the force explains "
        f"{fit.explained * 100:.0f} % of the motion"
    )
    mech = Mechanics(
        stiffness_n_per_m=k,
        stiffness_uncertainty_n_per_m=k * math.hypot(fit.stiffness_uncertainty_n_per_m / k, rel_scale),
        mass_kg=m,
        mass_uncertainty_kg=m * math.hypot(fit.mass_uncertainty_kg / m, rel_scale),
    )
    return mech, dataclasses.replace(excitation, notes=(*excitation.notes, note))


def _ringdown(track: Track, window: WindowContext) -> Ringdown | None:
    """The sliding-window amplitude and frequency of the motion after its onset (None when too short)."""
    velocity, onset = track.velocity_px, track.onset
    if len(velocity) - onset < 16:
        return None
    ringdown = sliding_ringdown(
        velocity[onset:], sample_rate_hz=window.sample_rate_hz, frequency_hz=track.fit.frequency_hz
    )
    return Ringdown(
        times_s=ringdown.times_s + float(window.buffers.times_s[onset]),
        amplitude=ringdown.amplitude,
        frequency_hz=ringdown.frequency_hz,
        spectrogram_hz=ringdown.spectrogram_hz,
        spectrogram_power=ringdown.spectrogram_power,
    )


def _regime_reasons(fit: RingdownFit, regime: str) -> list[str]:
    """Why the damping is not measured: a sustained or growing oscillation shows no decay."""
    if regime == "ring_down":
        return []
    grows = "grows" if regime == "growing" else "does not decay"
    return [
        f"damping: the motion {grows} in the analysed window ({math.exp(-fit.decay) * 100:.0f} % of its "
        f"amplitude left after {fit.duration_s:.3g} s): a {regime} vibration, not a ring-down"
    ]


def _integrated(track: Track) -> NDArray[np.float64]:
    """The motion along its axis integrated from the window's first frame, input pixels (N + 1,)."""
    return np.concatenate([[0.0], np.cumsum(track.velocity_px)])


def _displacements(track: Track, release: _Release) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The integrated displacement along the motion's axis and the fitted model's, input pixels (N + 1,),
    the former aligned to the model's mean level after release."""
    n = len(track.velocity_px)
    disp = _integrated(track)
    t = release.times_from_onset[: n + 1]
    model = np.full(n + 1, np.nan)
    after = t >= release.t_rel
    model[after] = track.fit.displacement(t[after])
    if after.any():
        disp = disp - np.nanmean(disp[after] - model[after])
    return disp, model


def _saturated(first_rgb: NDArray[np.uint8], full_mask: NDArray[np.bool_]) -> float:
    """Share of the object's pixels clipped where the sensor's grey level is at its limit: one colour
    channel at 0 (a saturated blue) still carries texture in the others."""
    grey = first_rgb[full_mask].astype(np.float32).mean(axis=1)
    return float(np.mean((grey >= 254) | (grey <= 1))) if grey.size else 0.0


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


__all__ = [
    "Region",
    "WindowContext",
    "assign_excitations",
    "bounding_box",
    "measure_object",
    "object_mechanics",
]
