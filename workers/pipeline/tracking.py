"""An object's motion over the window: the common time course of its pixels' flow (principal components,
so parts in anti-phase do not cancel), and where the object is rigid and textured, its sub-pixel
displacement by registration of its texture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.mechanics import detect_release
from workers.pipeline.registration import register_translation
from workers.pipeline.ringdown import RingdownFit, fit_ringdown
from workers.pipeline.stream import FrameBuffers

#: Objects whose pixels move this coherently are registered as rigid bodies for their amplitude.
RIGID_COHERENCE = 0.7


@dataclass(frozen=True)
class ObjectMotion:
    """The dominant motion of one object.

    Attributes
    ----------
    velocity_px : ndarray of float64, shape (N,)
        Per-frame displacement along the motion axis of a typical pixel of the object, input pixels/frame.
    axis_px : (float, float)
        Unit vector of the motion axis in the image (x right, y down).
    coherence : float
        |mean loading| / mean |loading| in [0, 1]: 1 for a rigid translation, ~0 for parts in anti-phase.
    """

    velocity_px: NDArray[np.float64]
    axis_px: tuple[float, float]
    coherence: float


def object_motion(
    flow: NDArray[np.float32],
    mask: NDArray[np.bool_],
    *,
    pixel_scale: float = 1.0,
    max_pixels: int = 20_000,
    seed: int = 0,
) -> ObjectMotion:
    """Dominant motion of the masked pixels by principal components over time.

    The first principal component of the pixels' signed flow is the common time course; each pixel's
    loading says how far and which way it moves. Parts that move in anti-phase load with opposite signs and
    so reinforce the component instead of cancelling.

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
        Flow on the computation grid.
    mask : ndarray of bool, shape (h, w)
    pixel_scale : float
        Input pixels per grid pixel (1 / flow scale).
    max_pixels : int
        Pixels sampled (seeded) for the decomposition.
    seed : int

    Returns
    -------
    ObjectMotion
    """
    idx = np.flatnonzero(mask.ravel())
    if len(idx) > max_pixels:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_pixels, replace=False))
    n = flow.shape[0]
    sub = flow.reshape(n, -1, 2)[:, idx, :].astype(np.float64)  # (N, P, 2)
    mat = sub.reshape(n, -1)
    gram = mat @ mat.T
    _evals, evecs = np.linalg.eigh(gram)
    u1 = evecs[:, -1]
    loads = (mat.T @ u1).reshape(-1, 2)  # (P, 2): per-pixel amplitude vector for unit time course
    cov = loads.T @ loads
    _, axes = np.linalg.eigh(cov)
    axis = axes[:, -1]
    proj = loads @ axis
    if np.mean(proj) < 0:
        axis, proj = -axis, -proj
    scale_px = float(np.median(np.abs(proj)))
    norms = np.linalg.norm(loads, axis=1)
    coherence = float(np.linalg.norm(loads.mean(axis=0)) / (norms.mean() + 1e-12))
    sign = 1.0 if np.sum(proj) >= 0 else -1.0
    velocity = u1 * scale_px * sign * pixel_scale
    return ObjectMotion(velocity_px=velocity, axis_px=(float(axis[0]), float(axis[1])), coherence=coherence)


def silhouette(
    flow_at_ref: NDArray[np.float32],
    region: NDArray[np.bool_],
    *,
    axis_px: tuple[float, float],
    shape: tuple[int, int],
    level: float = 0.5,
    reach_px: float = 0.0,
) -> NDArray[np.bool_]:
    """The object's outline in one frame: pixels of ``region`` that move with it at that instant.

    The spectral mask covers where the object is over the whole ring-down (for a large motion, the swept
    area); registration needs where it is in one reference frame. In a frame where the object moves fast,
    its own pixels carry its velocity and the uncovered background does not.

    Parameters
    ----------
    flow_at_ref : ndarray of float32, shape (h, w, 2)
        Flow from the reference frame to the next, on the flow grid.
    region : ndarray of bool, shape (h, w)
        The object's spectral mask on the flow grid.
    axis_px : (ux, uy)
        Motion axis.
    shape : (H, W)
        Input frame size; the silhouette is returned at this size.
    level : float
        Fraction of the region's typical speed along the axis a pixel must reach.
    reach_px : float
        How far (grid pixels) the object strays from ``region`` in any frame; the search grows by it.

    Returns
    -------
    ndarray of bool, shape (H, W)
    """
    import cv2

    along = flow_at_ref[..., 0] * axis_px[0] + flow_at_ref[..., 1] * axis_px[1]
    grow = 2 + math.ceil(reach_px)
    grown = cv2.dilate(region.astype(np.uint8), np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)).astype(bool)
    typical = float(np.median(along[region])) if region.any() else 0.0
    if typical < 0:
        along, typical = -along, -typical
    moving = grown & (along > level * typical) if typical > 0 else region
    up = cv2.resize(moving.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    edge = max(2, round(2 * shape[1] / region.shape[1]))
    up = cv2.erode(up, np.ones((2 * edge + 1, 2 * edge + 1), np.uint8))
    return np.asarray(up.astype(bool))


@dataclass(frozen=True)
class Track:
    """How one object moved, and the damped oscillation fitted to it.

    Attributes
    ----------
    velocity_px : ndarray of float64, shape (N,)
        Per-frame displacement along ``axis_px``, input pixels.
    axis_px : (float, float)
        Unit vector of the motion axis in the image.
    source : ``"registration"`` or ``"flow"``
        What measured the motion.
    onset : int
        First flow sample of the motion (the release).
    fit : RingdownFit
        The ring-down fitted from ``onset``.
    shifts_px : ndarray of float64, shape (N + 1, 2) or None
        Where the object is in each frame relative to the reference, input pixels (registration only).
    region : ndarray of bool, shape (h, w)
        The object's pixels in the reference frame, flow grid.
    """

    velocity_px: NDArray[np.float64]
    axis_px: tuple[float, float]
    source: str
    onset: int
    fit: RingdownFit
    shifts_px: NDArray[np.float64] | None
    region: NDArray[np.bool_]


def _outline_grid(outline: NDArray[np.bool_], grid: tuple[int, int]) -> NDArray[np.bool_]:
    import cv2

    small = cv2.resize(outline.astype(np.uint8), (grid[1], grid[0]), interpolation=cv2.INTER_NEAREST)
    return np.asarray(small.astype(bool))


def track_object(
    buffers: FrameBuffers,
    mask: NDArray[np.bool_],
    *,
    full_shape: tuple[int, int],
    fps: float,
    pixel_scale: float,
    frequency_guess_hz: float,
) -> Track:
    """Measure one object's motion and fit its ring-down.

    The flow's principal time course is fitted first; a rigid object (coherence at least
    ``RIGID_COHERENCE``) is then registered frame by frame, and the registration's motion replaces the
    flow's when it follows it (correlation of at least 0.9): flow is biased low by smoothing, while a
    registration that locked onto the wrong texture (very fast or blurred motion) no longer follows it.

    Parameters
    ----------
    buffers : FrameBuffers
        The window's flow, grey frames and camera motion.
    mask : ndarray of bool, shape (h, w)
        The object's spectral mask on the flow grid.
    full_shape : (H, W)
        Input frame size.
    fps : float
        Rate of the flow samples, Hz.
    pixel_scale : float
        Input pixels per grid pixel.
    frequency_guess_hz : float
        Where the fit starts (the object's spectral peak).

    Returns
    -------
    Track
    """

    def fitted(signal: NDArray[np.float64]) -> tuple[int, RingdownFit]:
        start = detect_release(signal)
        return start, fit_ringdown(
            signal,
            fps=fps,
            frequency_guess_hz=frequency_guess_hz,
            start_index=start,
            frame_times_s=buffers.times_s,
        )

    motion = object_motion(buffers.flow, mask, pixel_scale=pixel_scale)
    velocity = motion.velocity_px
    axis = motion.axis_px
    source = "flow"
    onset, fit = fitted(velocity)  # replaced by the registration's when that tracked the object
    shifts: NDArray[np.float64] | None = None  # image displacement per frame vs the reference, input px
    region = mask  # object pixels in the reference frame, grid
    if buffers.gray is not None and motion.coherence >= RIGID_COHERENCE:
        ref = int(np.argmax(np.abs(velocity)))
        position = np.concatenate([[0.0], np.cumsum(velocity)])
        initial = (position - position[ref])[:, None] * np.asarray(axis)[None, :]
        reach = float(np.abs(position - position[ref]).max()) / pixel_scale
        outline = silhouette(buffers.flow[ref], mask, axis_px=axis, shape=full_shape, reach_px=reach)
        camera = np.concatenate([[[0.0, 0.0]], np.cumsum(buffers.camera_px, axis=0)]) * pixel_scale
        camera -= camera[ref]
        disp2d, failed = register_translation(
            buffers.gray, outline, ref_index=ref, initial_px=initial + camera
        )
        disp2d = disp2d - camera  # the object's motion relative to the camera
        if failed <= 0.1:
            centred = disp2d - disp2d.mean(axis=0)
            _, vecs = np.linalg.eigh(centred.T @ centred)
            new_axis = vecs[:, -1] if float(vecs[:, -1] @ np.asarray(axis)) >= 0 else -vecs[:, -1]
            registered = np.diff(disp2d @ new_axis)
            reg_onset, reg_fit = fitted(registered)
            agreement = float(np.corrcoef(registered, velocity)[0, 1]) if np.std(registered) > 0 else 0.0
            if agreement >= 0.9:
                axis = (float(new_axis[0]), float(new_axis[1]))
                velocity, onset, fit = registered, reg_onset, reg_fit
                source = "registration"
                shifts = disp2d + camera  # where the object is in the image (depth maps)
                grid_outline = _outline_grid(outline, mask.shape)
                if grid_outline.sum() >= 16:
                    region = grid_outline
    return Track(
        velocity_px=velocity,
        axis_px=axis,
        source=source,
        onset=onset,
        fit=fit,
        shifts_px=shifts,
        region=region,
    )


__all__ = ["RIGID_COHERENCE", "ObjectMotion", "Track", "object_motion", "silhouette", "track_object"]
