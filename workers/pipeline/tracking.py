"""An object's motion over the window: the common time course of its pixels' flow (principal components,
so parts in anti-phase do not cancel), and where the object is rigid and textured, its sub-pixel
displacement by registration of its texture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.confidence import Confidence
from workers.pipeline.flow import as_float32, pixel_columns
from workers.pipeline.registration import register_translation
from workers.pipeline.release_fit import FitHints, ReleaseFitter
from workers.pipeline.ringdown import RingdownFit
from workers.pipeline.stream import FrameBuffers

#: Objects whose pixels move this coherently are registered as rigid bodies for their amplitude.
RIGID_COHERENCE = 0.7
#: A registration whose frames failed more often than this share is not used (the flow's motion is).
MAX_FAILED_SHARE = 0.1
#: The coarse grid's motion is followed when its line stands this many times clearer than the fine grid's.
COARSE_ADVANTAGE = 2.0
#: Objects whose motion spans this many grid pixels are also followed through the flow.
FOLLOW_MIN_PX = 2.0


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
    flow: NDArray[np.floating[Any]],
    mask: NDArray[np.bool_],
    *,
    pixel_scale: float = 1.0,
    max_pixels: int = 20_000,
    seed: int = 0,
    frequency_hz: float | None = None,
    sample_rate_hz: float | None = None,
    confidence: Confidence | None = None,
) -> ObjectMotion:
    """Dominant motion of the masked pixels by principal components over time.

    The first principal component of the pixels' signed flow is the common time course; each pixel's
    loading says how far and which way it moves. Parts that move in anti-phase load with opposite signs and
    so reinforce the component instead of cancelling. Given the object's frequency, the component is the
    one that explains most of the motion *near it* (the leading singular vector of the pixels' spectra
    within two lines of it, made real): a weak vibration under broadband noise (a codec's pulses, which
    move every pixel at once) is followed, not the noise. Given the flow's ``confidence``, each pixel's
    flow counts by its weight (flat pixels' flow is noise); and where the pixels' common motion, their
    flow averaged by what the image constrains of it (:func:`_mean_course`), stands out more clearly at
    the frequency than that component, the common motion is the object's (a rigid object whose pixels are
    individually lost in noise).

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
    frequency_hz, sample_rate_hz : float, optional
        The object's frequency and the flow's sample rate: the component is sought near it.
    confidence : Confidence, optional
        Of the grid's flow: each pixel's flow counts by its weight.

    Returns
    -------
    ObjectMotion
    """
    idx = np.flatnonzero(mask.ravel())
    if len(idx) > max_pixels:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_pixels, replace=False))
    # (N, 2P): the pixels' u and v, each column's mean removed (one copy of the masked flow)
    mat = as_float32(pixel_columns(flow, idx))
    mat -= mat.mean(axis=0, dtype=np.float64).astype(np.float32)
    weight = None if confidence is None else confidence.weight
    counts = (
        np.ones(mat.shape[1], np.float32)
        if weight is None
        else np.repeat(np.sqrt(weight.ravel()[idx]), 2).astype(np.float32)
    )
    if frequency_hz is not None and sample_rate_hz is not None:
        tensors = None if confidence is None else _tensors(confidence, idx)
        course = _course_near(mat, counts, tensors, cycles_per_sample=frequency_hz / sample_rate_hz)
    else:
        weighted = mat * counts
        _evals, evecs = np.linalg.eigh((weighted @ weighted.T).astype(np.float64))
        course = _Course(unit=evecs[:, -1], mean=None)
    return _motion_along(mat, course, pixel_scale=pixel_scale)


@dataclass(frozen=True)
class _Course:
    """The time course an object's motion follows.

    Attributes
    ----------
    unit : ndarray of float64, shape (N,)
        Unit time course the pixels' loadings are taken on.
    mean : ndarray of float64, shape (N,) or None
        The pixels' common motion in grid pixels per frame, when it is the object's (see
        :func:`_mean_course`); None when ``unit`` is a principal component.
    """

    unit: NDArray[np.float64]
    mean: NDArray[np.float64] | None


def _course_near(
    mat: NDArray[np.float32],
    counts: NDArray[np.float32],
    tensors: NDArray[np.float64] | None,
    *,
    cycles_per_sample: float,
) -> _Course:
    """The course of the motion near a frequency: the band's leading component of ``mat`` (N, 2P),
    each column weighed by ``counts`` (2P,); or, given the pixels' structure ``tensors`` (P, 2, 2), their
    common motion where that stands out more clearly there (:func:`line_snr`)."""
    n = mat.shape[0]
    nu = cycles_per_sample
    u1 = _band_component(mat, nu, weights=counts)
    mean_course: NDArray[np.float64] | None = None
    if tensors is not None:
        # the course's own mean is removed, so the columns' means make no difference to it
        mean_course = _mean_course(mat.reshape(n, -1, 2), tensors, nu)
    if mean_course is not None and line_snr(mean_course, nu) > line_snr(u1, nu):
        return _Course(unit=mean_course / float(np.linalg.norm(mean_course)), mean=mean_course)
    return _Course(unit=u1, mean=None)


def _motion_along(mat: NDArray[np.float32], course: _Course, *, pixel_scale: float) -> ObjectMotion:
    """The motion of the pixels of ``mat`` (N, 2P) along ``course``: their loadings on it give the axis,
    the typical pixel's amplitude and the coherence (see :class:`ObjectMotion`)."""
    u1 = course.unit
    # (P, 2): per-pixel amplitude vector for unit time course
    loads = (mat.T @ u1.astype(np.float32)).astype(np.float64).reshape(-1, 2)
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
    if course.mean is not None:
        # The mean flow over the pixels is the motion itself (grid pixels per frame), with its sign.
        velocity = course.mean * pixel_scale
        if float(np.dot(course.mean, u1)) < 0:
            velocity = -velocity
    else:
        velocity = u1 * scale_px * sign * pixel_scale
    return ObjectMotion(velocity_px=velocity, axis_px=(float(axis[0]), float(axis[1])), coherence=coherence)


def line_snr(course: NDArray[np.float64], cycles_per_sample: float) -> float:
    """How far a time course's line near a frequency stands over its spectrum's median (Hann window):
    the power within one line of it over the median power of all lines."""
    n = len(course)
    spectrum = np.abs(np.fft.rfft((course - course.mean()) * np.hanning(n))) ** 2
    k = cycles_per_sample * n
    near = spectrum[max(0, math.floor(k - 1)) : math.ceil(k + 1) + 1]
    floor = float(np.median(spectrum[1:])) if len(spectrum) > 2 else 0.0
    return float(near.max()) / floor if near.size and floor > 0 else 0.0


def _tensors(confidence: Confidence, idx: NDArray[np.intp]) -> NDArray[np.float64]:
    """The structure tensors (P, 2, 2) of the grid pixels ``idx``, weighed by their confidence (clipped
    pixels count for nothing)."""
    w = confidence.weight.ravel()[idx].astype(np.float64)
    jxx, jxy, jyy = (
        np.asarray(a, np.float64).ravel()[idx] * w for a in (confidence.jxx, confidence.jxy, confidence.jyy)
    )
    return np.stack([np.stack([jxx, jxy], axis=1), np.stack([jxy, jyy], axis=1)], axis=1)


def _mean_course(
    flow: NDArray[np.float32], tensors: NDArray[np.float64], cycles_per_sample: float
) -> NDArray[np.float64] | None:
    """The time course (N,) of the pixels' common motion along the direction in which it moves most near
    a frequency, in the flow's units: a rigid object's motion, whose pixels move together while their
    noise does not (a thin edge moving a fifth of a pixel under a codec's noise, where the pixels'
    individual spectra are noise and a decomposition of them follows it).

    The common motion of pixels with flows u_p (N, P, 2) and structure tensors J_p is the least-squares
    m = (sum J_p)^-1 sum J_p u_p: along an edge only the component across it counts (the one the image
    shows). None when the tensors constrain no direction.
    """
    total = tensors.sum(axis=0)
    if np.linalg.det(total) <= 1e-12 * max(float(np.trace(total)) ** 2, 1e-30):
        return None
    n, p = flow.shape[:2]
    # sum_p J_p u_p as one matrix product: (N, 2P) @ (2P, 2), the rows of J_p^T stacked per pixel
    stacked = np.ascontiguousarray(tensors.transpose(0, 2, 1).reshape(2 * p, 2), dtype=flow.dtype)
    summed = (flow.reshape(n, 2 * p) @ stacked).astype(np.float64)
    mean = summed @ np.linalg.inv(total).T  # (N, 2)
    mean = mean - mean.mean(axis=0)
    lines_at = np.arange(n // 2 + 1) / n
    near = np.flatnonzero(np.abs(lines_at - cycles_per_sample) <= 1.0 / n)
    if near.size == 0:
        return None
    basis = np.exp(-2j * np.pi * np.outer(lines_at[near], np.arange(n)))
    spectra = basis @ mean  # (K, 2)
    _, vecs = np.linalg.eigh((spectra.conj().T @ spectra).real)
    return np.asarray(mean @ vecs[:, -1], np.float64)


def _band_component(
    mat: NDArray[np.floating[Any]],
    cycles_per_sample: float,
    *,
    lines: float = 2.0,
    weights: NDArray[np.float32] | None = None,
) -> NDArray[np.float64]:
    """The unit time course (N,) of the spatial pattern that explains most of ``mat``'s (N, C) motion
    within ``lines`` lines of a frequency: the leading right singular vector of the columns' spectra
    there, its phase turned to make it as real as possible. With ``weights`` (C,), of ``mat`` with each
    column scaled by its weight (applied to the spectra and the pattern: no weighted copy of ``mat``)."""
    n = mat.shape[0]
    lines_at = np.arange(n // 2 + 1) / n
    near = np.flatnonzero(np.abs(lines_at - cycles_per_sample) <= lines / n)
    if near.size == 0:
        near = np.array([int(np.argmin(np.abs(lines_at - cycles_per_sample)))])
    t = np.arange(n)
    phase = 2 * np.pi * np.outer(lines_at[near], t)  # (K, N)
    # two real products: a complex one would first copy the whole of mat as complex numbers
    spectra = np.cos(phase).astype(mat.dtype) @ mat - 1j * (np.sin(phase).astype(mat.dtype) @ mat)
    if weights is not None:
        spectra *= weights[None, :]
    _, _, vh = np.linalg.svd(spectra, full_matrices=False)
    pattern = vh[0].conj()
    pattern = pattern * np.exp(-0.5j * np.angle(np.sum(pattern * pattern)))  # most nearly real
    real = pattern.real if weights is None else pattern.real * weights
    course = np.asarray(mat @ real.astype(mat.dtype), np.float64)
    norm = float(np.linalg.norm(course))
    return course / norm if norm > 0 else course


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
class CoarseView:
    """The object on another, coarser grid of the same flow maps: its flow, where it moves there and that
    grid's confidence (:func:`track_object` follows whichever grid shows its motion more clearly).

    Attributes
    ----------
    flow : ndarray of float32 or float16, shape (N, h, w, 2)
    region : ndarray of bool, shape (h, w)
    confidence : Confidence
    pixel_scale : float
        Input pixels per pixel of this grid.
    """

    flow: NDArray[np.float32] | NDArray[np.float16]
    region: NDArray[np.bool_]
    confidence: Confidence
    pixel_scale: float


@dataclass(frozen=True)
class Track:
    """How one object moved, and the damped oscillation fitted to it.

    Attributes
    ----------
    velocity_px : ndarray of float64, shape (N,)
        Per-frame displacement along ``axis_px``, input pixels.
    axis_px : (float, float)
        Unit vector of the motion axis in the image.
    source : ``"registration"``, ``"tracked"`` or ``"flow"``
        What measured the motion: registration of its texture, its pixels followed through the flow
        (a large swing), or the flow where it is.
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


def follow_region(
    flow: NDArray[np.float32],
    seed: NDArray[np.bool_],
    *,
    ref_index: int,
    max_points: int = 1500,
    seed_rng: int = 0,
) -> NDArray[np.float64]:
    """Where a region is in every frame, by carrying its pixels along the flow from a reference frame.

    Forward, each point moves by the flow at its position (bilinear); backward, by the flow that brought
    it to where it is. The region's displacement is the median of its points' (robust to the few that
    slip onto the background at its edges).

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
        Flow maps, map k from frame k to k + 1, grid pixels.
    seed : ndarray of bool, shape (h, w)
        The region's pixels in frame ``ref_index``.
    ref_index : int
    max_points : int
        Points followed (a seeded sample of the region's pixels).

    Returns
    -------
    ndarray of float64, shape (N + 1, 2)
        (dx, dy) of the region in each frame relative to the reference, grid pixels.
    """
    import cv2

    ys, xs = np.nonzero(seed)
    if len(xs) > max_points:
        pick = np.sort(np.random.default_rng(seed_rng).choice(len(xs), max_points, replace=False))
        ys, xs = ys[pick], xs[pick]
    n = len(flow)
    points = np.empty((n + 1, len(xs), 2), np.float32)
    points[ref_index, :, 0], points[ref_index, :, 1] = xs, ys

    def at(k: int, where: NDArray[np.float32]) -> NDArray[np.float32]:
        mx = np.ascontiguousarray(where[:, 0:1])
        my = np.ascontiguousarray(where[:, 1:2])
        sampled = cv2.remap(flow[k], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return np.asarray(sampled, np.float32).reshape(-1, 2)

    for k in range(ref_index, n):
        points[k + 1] = points[k] + at(k, points[k])
    for k in range(ref_index - 1, -1, -1):
        points[k] = points[k + 1] - at(k, points[k + 1])
    return np.asarray(np.median(points - points[ref_index], axis=1), np.float64)


def second_motion(
    flow: NDArray[np.float32],
    mask: NDArray[np.bool_],
    *,
    frequency_hz: float,
    sample_rate_hz: float,
    lines: float = 3.0,
    max_pixels: int = 4000,
    seed: int = 0,
) -> float:
    """How strong a second, independent motion near ``frequency_hz`` is in a region, relative to the
    first: 0 when one motion explains the region (however its parts' phases differ), near the weaker's
    share of the power when two unresolved oscillations share it.

    Near its frequency a region's flow spectra are one pattern over the pixels times one line shape
    over the frequency bins (rank one), for a ring-down as for a steady tone, rigid or not. Two
    oscillations a line or two apart make it rank two. The second eigenvalue counts only where it stands
    clearly above the rest (the noise).

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
    mask : ndarray of bool, shape (h, w)
    frequency_hz, sample_rate_hz : float
    lines : float
        Half-width of the band examined, in lines of the window (fps / N).
    max_pixels : int
        Pixels sampled (seeded).

    Returns
    -------
    float
        The second eigenvalue over the first, or 0.
    """
    idx = np.flatnonzero(mask.ravel())
    if idx.size < 4:
        return 0.0
    if idx.size > max_pixels:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_pixels, replace=False))
    n = flow.shape[0]
    bins = np.arange(n // 2 + 1) / n * sample_rate_hz  # the window's own lines: independent of each other
    near = np.flatnonzero(np.abs(bins - frequency_hz) <= lines * sample_rate_hz / n)
    if near.size < 4:
        return 0.0
    t = np.arange(n)
    phase = 2 * np.pi * np.outer(bins[near] / sample_rate_hz, t)  # (K, N)
    cos, sin = np.cos(phase), np.sin(phase)
    spectra = np.empty((len(near), 2 * idx.size), np.complex128)  # (K, 2P)
    # a block of pixels at a time: a float64 copy of all of them was 26 MiB of the 1000-frame fork's
    # measurement, at its peak memory (and beside the modes' own copy)
    for first in range(0, idx.size, _COHERENCE_BLOCK):
        data = pixel_columns(flow, idx[first : first + _COHERENCE_BLOCK]).astype(np.float64)
        data -= data.mean(axis=0)
        # two real products: a complex one would first copy the flow as complex numbers
        spectra[:, 2 * first : 2 * first + data.shape[1]] = cos @ data - 1j * (sin @ data)
    values = np.sort(np.linalg.eigvalsh(spectra @ spectra.conj().T).real)[::-1]
    if values[0] <= 0:
        return 0.0
    noise = float(np.median(values[2:])) if values.size > 2 else 0.0
    return float(values[1] / values[0]) if values[1] >= 5 * noise else 0.0


#: Pixels whose spectra :func:`second_motion` computes at a time.
_COHERENCE_BLOCK = 512


def _outline_grid(outline: NDArray[np.bool_], grid: tuple[int, int]) -> NDArray[np.bool_]:
    import cv2

    small = cv2.resize(outline.astype(np.uint8), (grid[1], grid[0]), interpolation=cv2.INTER_NEAREST)
    return np.asarray(small.astype(bool))


def track_object(
    buffers: FrameBuffers,
    mask: NDArray[np.bool_],
    *,
    sample_rate_hz: float,
    pixel_scale: float,
    hints: FitHints,
    confidence: Confidence | None = None,
    coarse: CoarseView | None = None,
) -> Track:
    """Measure one object's motion and fit its ring-down.

    The flow's principal time course is fitted first; a rigid object (coherence at least
    ``RIGID_COHERENCE``) is then registered frame by frame, and the registration's motion replaces the
    flow's when it follows it (correlation of at least 0.9): flow is biased low by smoothing, while a
    registration that locked onto the wrong texture (very fast or blurred motion) no longer follows it.
    Otherwise an object whose motion spans ``FOLLOW_MIN_PX`` grid pixels or more is followed through the
    flow, and that motion is kept when its fit stands more than 1 dB clearer.

    Parameters
    ----------
    buffers : FrameBuffers
        The window's flow, grey frames and camera motion.
    mask : ndarray of bool, shape (h, w)
        The object's spectral mask on the flow grid.
    sample_rate_hz : float
        Rate of the flow samples, Hz.
    pixel_scale : float
        Input pixels per grid pixel.
    hints : FitHints
        Where the fit starts from: the frequency's guess, the band, and when the object is free.
    confidence : Confidence, optional
        Of the grid's flow (see :func:`object_motion`).
    coarse : CoarseView, optional
        The object on a coarser grid of the same maps: its motion there is followed when it stands out
        more clearly at the frequency (:func:`line_snr`) than on this grid's (a codec's noise, averaged
        away over a coarse pixel, can bury a sub-pixel motion at full resolution).

    Returns
    -------
    Track
    """
    fitter = ReleaseFitter(sample_rate_hz=sample_rate_hz, hints=hints, times_s=buffers.times_s)
    motion = _clearest_motion(
        buffers.flow,
        mask,
        frequency_hz=hints.frequency_guess_hz,
        sample_rate_hz=sample_rate_hz,
        pixel_scale=pixel_scale,
        confidence=confidence,
        coarse=coarse,
    )
    onset, fit = fitter(motion.velocity_px)  # replaced by the registration's when that tracked the object
    flow_track = Track(
        velocity_px=motion.velocity_px,
        axis_px=motion.axis_px,
        source="flow",
        onset=onset,
        fit=fit,
        shifts_px=None,
        region=mask,
    )
    if buffers.gray is not None and motion.coherence >= RIGID_COHERENCE:
        registered = _registered_track(flow_track, buffers, fitter, pixel_scale=pixel_scale)
        if registered is not None:
            return registered
    followed = _followed_track(flow_track, buffers.flow, fitter, pixel_scale=pixel_scale)
    return flow_track if followed is None else followed


def _clearest_motion(
    flow: NDArray[np.floating[Any]],
    mask: NDArray[np.bool_],
    *,
    frequency_hz: float,
    sample_rate_hz: float,
    pixel_scale: float,
    confidence: Confidence | None,
    coarse: CoarseView | None,
) -> ObjectMotion:
    """The object's motion on the grid of ``flow`` (N, h, w, 2), or on the ``coarse`` grid when its line
    stands ``COARSE_ADVANTAGE`` times clearer there at ``frequency_hz`` (:func:`line_snr`)."""
    motion = object_motion(
        flow,
        mask,
        pixel_scale=pixel_scale,
        frequency_hz=frequency_hz,
        sample_rate_hz=sample_rate_hz,
        confidence=confidence,
    )
    if coarse is not None and coarse.region.any():
        seen = object_motion(
            coarse.flow,
            coarse.region,
            pixel_scale=coarse.pixel_scale,
            frequency_hz=frequency_hz,
            sample_rate_hz=sample_rate_hz,
            confidence=coarse.confidence,
        )
        nu = frequency_hz / sample_rate_hz
        if line_snr(seen.velocity_px, nu) > COARSE_ADVANTAGE * line_snr(motion.velocity_px, nu):
            return seen
    return motion


def _registered_track(
    flow_track: Track, buffers: FrameBuffers, fitter: ReleaseFitter, *, pixel_scale: float
) -> Track | None:
    """The object's motion by registration of its texture in the grey frames (a rigid object), or None
    when the registration failed too often or does not follow the flow's motion (correlation below 0.9).

    Parameters
    ----------
    flow_track : Track
        The motion the flow measured (its velocity, axis and region guide the registration).
    buffers : FrameBuffers
        The window's flow, grey frames (not None) and camera motion.
    fitter : ReleaseFitter
    pixel_scale : float
        Input pixels per grid pixel.

    Returns
    -------
    Track or None
        With ``source`` ``"registration"`` and the object's image ``shifts_px``.
    """
    assert buffers.gray is not None
    velocity, axis, mask = flow_track.velocity_px, flow_track.axis_px, flow_track.region
    ref = int(np.argmax(np.abs(velocity)))
    position = np.concatenate([[0.0], np.cumsum(velocity)])
    initial = (position - position[ref])[:, None] * np.asarray(axis)[None, :]
    reach = float(np.abs(position - position[ref]).max()) / pixel_scale
    gray_shape = (int(buffers.gray.shape[1]), int(buffers.gray.shape[2]))
    outline = silhouette(buffers.flow[ref], mask, axis_px=axis, shape=gray_shape, reach_px=reach)
    camera = np.concatenate([[[0.0, 0.0]], np.cumsum(buffers.camera_px, axis=0)]) * pixel_scale
    camera -= camera[ref]
    scale = buffers.gray_pixel_scale  # input pixels per pixel of the grey frames
    disp2d, failed = register_translation(
        buffers.gray,
        outline,
        ref_index=ref,
        initial_px=(initial + camera) / scale,
        max_failed=MAX_FAILED_SHARE,
    )
    disp2d = disp2d * scale - camera  # the object's motion relative to the camera, input pixels
    if not failed <= MAX_FAILED_SHARE:
        return None
    new_axis, registered = _principal_motion(disp2d, axis)
    onset, fit = fitter(registered)
    agreement = float(np.corrcoef(registered, velocity)[0, 1]) if np.std(registered) > 0 else 0.0
    if not agreement >= 0.9:
        return None
    grid_outline = _outline_grid(outline, mask.shape)
    return Track(
        velocity_px=registered,
        axis_px=(float(new_axis[0]), float(new_axis[1])),
        source="registration",
        onset=onset,
        fit=fit,
        shifts_px=disp2d + camera,  # where the object is in the image (depth maps)
        region=grid_outline if grid_outline.sum() >= 16 else mask,
    )


def _principal_motion(
    path: NDArray[np.float64], axis: tuple[float, float]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The principal axis of a path (T, 2) of positions, turned to agree with ``axis``, and the
    per-frame motion along it, shape (T - 1,)."""
    centred = path - path.mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    along = vecs[:, -1] if float(vecs[:, -1] @ np.asarray(axis)) >= 0 else -vecs[:, -1]
    return along, np.diff(path @ along)


def _followed_track(
    flow_track: Track, flow: NDArray[np.float32], fitter: ReleaseFitter, *, pixel_scale: float
) -> Track | None:
    """The object's motion by following its pixels through the ``flow`` (N, h, w, 2), or None when its
    motion spans less than ``FOLLOW_MIN_PX`` grid pixels, too few pixels move with it, or the fit to the
    followed motion stands no more than 1 dB clearer than ``flow_track``'s.

    A large motion (a pendulum's swing) sweeps the object over pixels that are background most of the
    time: their flow at a fixed place is a pulse, not the object's motion.
    """
    velocity, axis, mask = flow_track.velocity_px, flow_track.axis_px, flow_track.region
    position = np.concatenate([[0.0], np.cumsum(velocity)]) / pixel_scale
    reach = float(np.ptp(position))
    if not reach >= FOLLOW_MIN_PX:
        return None
    ref = int(np.argmax(np.abs(velocity)))
    seed = silhouette(flow[ref], mask, axis_px=axis, shape=mask.shape, reach_px=reach)
    if int(seed.sum()) < 16:
        return None
    path = follow_region(flow, seed, ref_index=ref) * pixel_scale
    along, followed = _principal_motion(path, axis)
    onset, fit = fitter(followed)
    if not fit.snr_db > flow_track.fit.snr_db + 1.0:
        return None
    return Track(
        velocity_px=followed,
        axis_px=(float(along[0]), float(along[1])),
        source="tracked",
        onset=onset,
        fit=fit,
        shifts_px=None,
        region=seed,
    )


__all__ = [
    "RIGID_COHERENCE",
    "CoarseView",
    "ObjectMotion",
    "Track",
    "follow_region",
    "object_motion",
    "second_motion",
    "silhouette",
    "track_object",
]
