"""An object's amplitude in metres: its image displacement scaled by its distance and the focal length,
plus its motion along the line of sight measured from depth, with the uncertainty of each part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import Intrinsics
from workers.pipeline.peaks import nanmedian_over_time
from workers.pipeline.ringdown import RingdownFit

#: Relative standard uncertainty of flow-measured amplitudes (dense flow is biased low near edges).
FLOW_AMPLITUDE_REL_SD = 0.03
#: ... of registration-measured amplitudes (texture interpolation, residual non-rigidity).
REGISTRATION_REL_SD = 0.004
#: ... of a live estimate's amplitude: the mean dense flow over the moving region, which DIS smooths at
#: the object's edges (5-10 % low on ground truth; the full analysis registers the texture).
MEAN_FLOW_AMPLITUDE_REL_SD = 0.08
#: The systematic uncertainty of each source of an image amplitude (:attr:`ImageAmplitude.source`).
SOURCE_REL_SD = {
    "registration": REGISTRATION_REL_SD,
    "tracked": FLOW_AMPLITUDE_REL_SD,
    "flow": FLOW_AMPLITUDE_REL_SD,
    "mean_flow": MEAN_FLOW_AMPLITUDE_REL_SD,
}
#: Relative systematic uncertainty of a depth sensor's distance (calibration, plane fit).
DEPTH_REL_SD = 0.004
#: Relative uncertainty per unit of line-of-sight motion (|z| / amplitude), measured on ground truth.
OUT_OF_PLANE_REL_SD = 0.015
#: Relative uncertainty assumed for a user-given constant distance (depth_m).
DEPTH_OVERRIDE_REL_SD = 0.02


def depth_track(
    depth: NDArray[np.float32],
    region: NDArray[np.bool_],
    *,
    shifts_px: NDArray[np.float64] | None = None,
    erode_px: int = 2,
) -> NDArray[np.float64]:
    """The object's distance from the camera in every frame.

    Parameters
    ----------
    depth : ndarray of float32, shape (T, h, w)
        Depth in metres on the flow grid, NaN where invalid.
    region : ndarray of bool, shape (h, w)
        The object's pixels in the reference frame.
    shifts_px : ndarray of float64, shape (T, 2), optional
        The object's image displacement in each frame relative to the reference, grid pixels; the
        region is moved with it so that it always samples the object's own surface.
    erode_px : int
        Margin removed from the region's edge.

    Returns
    -------
    ndarray of float64, shape (T,)
        Median depth over the (moved) region, metres; NaN where no pixel had a reading.
    """
    import cv2

    core = region.astype(np.uint8)
    if erode_px > 0:
        eroded = cv2.erode(core, np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8))
        if eroded.sum() >= 16:
            core = eroded
    ys, xs = np.nonzero(core)
    t_count, h, w = depth.shape
    out = np.full(t_count, np.nan)
    if ys.size == 0:
        return out
    step = max(1, TRACK_BLOCK_VALUES // ys.size)
    for first in range(0, t_count, step):
        frames = np.arange(first, min(first + step, t_count))
        if shifts_px is None:
            values = depth[frames[:, None], ys, xs]
        else:
            d = np.rint(shifts_px[frames]).astype(np.intp)
            yy, xx = ys + d[:, 1:2], xs + d[:, 0:1]
            ok = (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
            inside = depth[frames[:, None], np.clip(yy, 0, h - 1), np.clip(xx, 0, w - 1)]
            values = np.where(ok, inside, np.nan)
        # each frame's median of its finite readings (the frames along the second axis)
        out[frames] = nanmedian_over_time(np.where(np.isfinite(values), values, np.nan).T)
    return out


#: Depth readings a block of :func:`depth_track`'s frames holds at most (its memory stays flat in the
#: clip's length).
TRACK_BLOCK_VALUES = 1 << 20


def fit_component(
    positions: NDArray[np.float64],
    times_s: NDArray[np.float64],
    fit: RingdownFit,
    *,
    start_index: int,
) -> tuple[float, float, float]:
    """Amplitude and phase of a second displacement signal that rings with a fitted ring-down.

    With ω and σ fixed by ``fit``, x(t) = c + a e^{-σt} cos ωt + b e^{-σt} sin ωt is linear in (c, a, b).

    Parameters
    ----------
    positions : ndarray of float64, shape (T,)
        Displacement per frame (NaN samples are ignored).
    times_s : ndarray of float64, shape (T,)
        Frame times relative to the fit's first sample.
    fit : RingdownFit
    start_index : int
        First frame used (the release).

    Returns
    -------
    amplitude : float
        Signed envelope amplitude at the fit start: positive when in phase with ``fit``.
    amplitude_sd : float
        Its standard uncertainty.
    phase_offset_rad : float
        Phase relative to ``fit``.
    """
    t = times_s[start_index:]
    x = positions[start_index:]
    ok = np.isfinite(x)
    t, x = t[ok], x[ok]
    if len(x) < 5:
        return 0.0, float("inf"), 0.0
    omega = 2 * math.pi * fit.frequency_hz
    env = np.exp(-fit.decay_per_s * t)
    basis = np.stack([np.ones_like(t), env * np.cos(omega * t), env * np.sin(omega * t)], axis=1)
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    res = x - basis @ coef
    dof = max(len(x) - 3, 1)
    s2 = float(res @ res) / dof
    try:
        cov = np.linalg.inv(basis.T @ basis) * s2
        sd = math.sqrt(max(float(cov[1, 1] + cov[2, 2]) / 2, 0.0))
    except np.linalg.LinAlgError:
        sd = float("inf")
    a, b = float(coef[1]), float(coef[2])
    amplitude = math.hypot(a, b)
    phase = math.atan2(-b, a)
    offset = (phase - fit.phase_rad + math.pi) % (2 * math.pi) - math.pi
    sign = 1.0 if abs(offset) <= math.pi / 2 else -1.0
    return sign * amplitude, sd, offset


def object_depth(depth: NDArray[np.float32] | None, mask: NDArray[np.bool_]) -> float | None:
    """Median depth over the interior of a mask and every frame, metres (None without readings).

    Parameters
    ----------
    depth : ndarray of float32, shape (T, h, w), or None
        Depth on the grid of ``mask``, metres, NaN invalid.
    mask : ndarray of bool, shape (h, w)
    """
    if depth is None:
        return None
    # Interior of the mask: erode so edge pixels that sometimes see the background do not count.
    import cv2

    core = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    if core.sum() < 10:
        core = mask
    values = depth[:, core]
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    return float(np.median(values))


@dataclass
class MetricAmplitude:
    """An object's amplitude at release in metres, or why it could not be measured.

    Attributes
    ----------
    amplitude_m, amplitude_uncertainty_m : float or None
    depth_m : float or None
        The object's distance (median over the window), metres.
    direction : (x, y, z) or None
        Unit motion direction in camera coordinates, its largest component positive.
    null_reasons, notes : list of str
    """

    amplitude_m: float | None = None
    amplitude_uncertainty_m: float | None = None
    depth_m: float | None = None
    direction: tuple[float, float, float] | None = None
    null_reasons: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class ImageAmplitude:
    """An object's motion as the image shows it: the ring-down fitted to it and its amplitude at release.

    Attributes
    ----------
    fit : RingdownFit
        The object's fitted ring-down (image pixels).
    amplitude_px, amplitude_sd_px : float
        Amplitude at release and its uncertainty, input pixels.
    axis_px : (float, float)
        Unit vector of the motion axis in the image (x right, y down).
    source : ``"registration"``, ``"tracked"``, ``"flow"`` or ``"mean_flow"``
        What measured the motion (sets the systematic uncertainty, :data:`SOURCE_REL_SD`): registration of
        its texture, its pixels followed through the flow, the flow where it is, or (a live estimate) the
        mean flow of the moving region.
    """

    fit: RingdownFit
    amplitude_px: float
    amplitude_sd_px: float
    axis_px: tuple[float, float]
    source: str


@dataclass(frozen=True)
class DepthContext:
    """What the window knows of the object's distance: its depth maps and where the object is on them,
    or a user-given constant distance.

    Attributes
    ----------
    depth : ndarray of float32, shape (N + 1, h, w), or None
        Depth on the flow grid, metres, NaN invalid.
    region : ndarray of bool, shape (h, w)
        The object's pixels in the reference frame, flow grid.
    shifts_grid_px : ndarray of float64, shape (N + 1, 2), or None
        The object's displacement per frame, grid pixels (the region follows it over the depth maps).
    times_from_onset_s : ndarray of float64, shape (N + 1,)
        Frame times relative to the fit's first sample.
    onset : int
        First frame of the motion (the release).
    override_m : float or None
        A user-given constant distance for clips without depth.
    """

    depth: NDArray[np.float32] | None
    region: NDArray[np.bool_]
    shifts_grid_px: NDArray[np.float64] | None
    times_from_onset_s: NDArray[np.float64]
    onset: int
    override_m: float | None = None


def metric_amplitude(
    image: ImageAmplitude,
    depth: DepthContext,
    *,
    full_mask: NDArray[np.bool_],
    intrinsics: Intrinsics | None,
) -> MetricAmplitude:
    """Amplitude at release in metres, from the image amplitude, the depth track and the intrinsics.

    Pinhole: u = fx X / Z + cx, so dX = du Z / fx + (u - cx) dZ / fx (likewise for y); the motion along
    the line of sight (dZ) is the depth track's component that rings with ``image.fit``.

    Parameters
    ----------
    image : ImageAmplitude
        The object's fitted ring-down, amplitude at release (input pixels), axis and source.
    depth : DepthContext
        The depth maps and the object's region and shifts on them, or a constant distance.
    full_mask : ndarray of bool, shape (H, W)
        The object's mask at input resolution (its centroid).
    intrinsics : Intrinsics or None

    Returns
    -------
    MetricAmplitude
    """
    out = MetricAmplitude()
    distance = _distance(depth, image.fit)
    out.depth_m = distance.depth_m
    if distance.depth_m is None:
        out.null_reasons.append("no depth: give a clip with depth, or depth_m with the intrinsics")
        return out
    if intrinsics is None:
        out.null_reasons.append("no camera intrinsics: give fx, fy (and cx, cy) for metric amplitude")
        return out
    motion = _camera_motion(image, distance, full_mask=full_mask, intrinsics=intrinsics)
    a_img, z_amp, z_sd = image.fit.amplitude, distance.z_amp, distance.z_sd
    vec = np.array([motion.dx, motion.dy, z_amp])
    a3 = float(np.linalg.norm(vec))
    if not (a3 > 0 and a_img > 0):
        out.null_reasons.append("amplitude is zero: the object did not move measurably")
        return out
    amp_m = image.amplitude_px * a3 / a_img
    # An oscillation's axis has no sign: report it with its largest component positive.
    unit = vec / a3 * (1.0 if vec[int(np.argmax(np.abs(vec)))] >= 0 else -1.0)
    direction = (float(unit[0]), float(unit[1]), float(unit[2]))
    sys_rel = SOURCE_REL_SD.get(image.source, FLOW_AMPLITUDE_REL_SD)
    a_xy = math.hypot(motion.dx, motion.dy)
    rel_xy = math.sqrt(
        (image.amplitude_sd_px / max(image.amplitude_px, 1e-12)) ** 2 + sys_rel**2 + distance.rel_sd**2
    )
    var = (a_xy / a3) ** 2 * (a_xy * rel_xy) ** 2 + (abs(z_amp) / a3) ** 2 * z_sd**2
    # Motion along the line of sight also scales the image; the residual coupling of scale into the
    # registered displacement is not modelled, so it is carried as uncertainty.
    var += (OUT_OF_PLANE_REL_SD * abs(z_amp)) ** 2
    out.amplitude_m = amp_m
    out.amplitude_uncertainty_m = amp_m * math.sqrt(var) / a3
    out.direction = direction
    if abs(direction[2]) >= 0.05:
        out.notes.append(
            f"motion has a component along the line of sight ({abs(direction[2]) * 100:.0f} %), "
            "measured from depth"
        )
    return out


@dataclass(frozen=True)
class _Distance:
    """The object's distance and its motion along the line of sight.

    Attributes
    ----------
    depth_m : float or None
        Median distance over the window (or the user's), metres; None when unknown.
    rel_sd : float
        Its relative standard uncertainty.
    z_amp, z_sd : float
        Signed amplitude of the motion along the line of sight at the fit start and its uncertainty,
        metres (both 0 when not significant or without depth maps).
    """

    depth_m: float | None
    rel_sd: float = 0.0
    z_amp: float = 0.0
    z_sd: float = 0.0


def _distance(depth: DepthContext, fit: RingdownFit) -> _Distance:
    """The object's distance from its depth track (the override's without one) and the track's
    component that rings with ``fit``."""
    if depth.depth is not None:
        z_track = depth_track(depth.depth, depth.region, shifts_px=depth.shifts_grid_px)
        finite = z_track[np.isfinite(z_track)]
        if finite.size:
            depth_m = float(np.median(finite))
            spread = float(np.median(np.abs(finite - depth_m))) * 1.4826 / math.sqrt(finite.size)
            depth_rel_sd = math.hypot(spread / depth_m, DEPTH_REL_SD)
            z_amp, z_sd, _ = fit_component(z_track, depth.times_from_onset_s, fit, start_index=depth.onset)
            if not (math.isfinite(z_sd) and abs(z_amp) > 2.5 * z_sd):
                z_amp, z_sd = 0.0, 0.0
            return _Distance(depth_m=depth_m, rel_sd=depth_rel_sd, z_amp=z_amp, z_sd=z_sd)
    if depth.override_m is not None:
        return _Distance(depth_m=depth.override_m, rel_sd=DEPTH_OVERRIDE_REL_SD)
    return _Distance(depth_m=None)


@dataclass(frozen=True)
class _CameraMotion:
    """The in-plane components (camera x and y, metres) of the envelope amplitude at the fit start."""

    dx: float
    dy: float


def _camera_motion(
    image: ImageAmplitude, distance: _Distance, *, full_mask: NDArray[np.bool_], intrinsics: Intrinsics
) -> _CameraMotion:
    """The pinhole's dX and dY of the image amplitude (along the axis) and the line-of-sight motion, at
    the mask's centroid (the principal point for an empty mask)."""
    assert distance.depth_m is not None
    depth_m, z_amp = distance.depth_m, distance.z_amp
    a_img = image.fit.amplitude
    ax, ay = image.axis_px
    ys, xs = np.nonzero(full_mask)
    u = float(xs.mean()) if len(xs) else intrinsics.cx
    v = float(ys.mean()) if len(ys) else intrinsics.cy
    dx = a_img * ax * depth_m / intrinsics.fx + (u - intrinsics.cx) * z_amp / intrinsics.fx
    dy = a_img * ay * depth_m / intrinsics.fy + (v - intrinsics.cy) * z_amp / intrinsics.fy
    return _CameraMotion(dx=dx, dy=dy)


__all__ = [
    "DepthContext",
    "ImageAmplitude",
    "MetricAmplitude",
    "depth_track",
    "fit_component",
    "metric_amplitude",
    "object_depth",
]
