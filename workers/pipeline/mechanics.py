"""Mechanics: an object's motion signal from its flow, the release instant, its amplitude in metres, and
stiffness and mass from the excitation.

Physics: ω = 2πf; spring-mass ω_n² = k/m. Held by force F then released: A = F/k. Struck by impulse J:
v0 = J/m and A = v0/ω_d.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.spectrum import RingdownFit


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


class _MaskedFit:
    """The warp of a frame onto a masked reference that maximises their correlation coefficient (the ECC
    criterion), by inverse-compositional Gauss-Newton: a translation, or an affine map.

    The reference's gradients, and so the normal equations, are computed once; each iteration samples the
    frame at the current warp and solves a 2x2 (6x6) system. OpenCV's ``findTransformECC`` recomputes and
    warps the frame's gradients at every iteration (several times the cost) and quantises a translation to
    1/32 px; here a translation is sampled in floating point.

    Parameters
    ----------
    reference : ndarray of uint8, shape (H, W)
        The reference frame.
    mask : ndarray of bool, shape (H, W)
        The reference's pixels to match.
    affine : bool
        Fit an affine map instead of a translation.
    max_iterations : int
    blur : int
        Gaussian kernel size applied to both images (3 as in OpenCV's ECC); 0 for none.

    Attributes
    ----------
    centre : ndarray of float64, shape (2,)
        The mask's centroid (x, y), frame pixels; affine parameters act about it.
    radius : float
        The mask's RMS distance from ``centre``, pixels.

    Raises
    ------
    numpy.linalg.LinAlgError
        The masked reference has too little texture (singular normal equations).
    """

    #: Convergence: the last update moved no masked pixel (to first order) further than this (px).
    TOLERANCE_PX = 1e-3

    def __init__(
        self,
        reference: NDArray[np.uint8],
        mask: NDArray[np.bool_],
        *,
        affine: bool = False,
        max_iterations: int = 60,
        blur: int = 3,
    ) -> None:
        import cv2

        ys, xs = np.nonzero(mask)
        height, width = reference.shape
        # Two pixels of context around the mask for the blur and the central differences.
        x0, x1 = max(0, int(xs.min()) - 2), min(width, int(xs.max()) + 3)
        y0, y1 = max(0, int(ys.min()) - 2), min(height, int(ys.max()) + 3)
        self._box = (x0, y0, x1 - x0, y1 - y0)
        self._affine = affine
        self._max_iterations = max_iterations
        self._blur = blur
        ref = self._smooth(reference[y0:y1, x0:x1].astype(np.float32))
        kernel = np.array([[-0.5, 0.0, 0.5]], np.float32)
        self._idx = np.flatnonzero(mask[y0:y1, x0:x1])
        gx = cv2.filter2D(ref, -1, kernel).ravel()[self._idx].astype(np.float64)
        gy = cv2.filter2D(ref, -1, kernel.T).ravel()[self._idx].astype(np.float64)
        template = ref.ravel()[self._idx].astype(np.float64)
        self._template = template - template.mean()
        self._template_norm = float(np.sqrt(self._template @ self._template))
        # Affine parameters act about the mask's centroid (full-frame coordinates), which keeps the
        # normal equations well conditioned.
        self.centre = np.array([xs.mean(), ys.mean()], np.float64)
        by, bx = np.divmod(self._idx, x1 - x0)
        u = bx + x0 - self.centre[0]
        v = by + y0 - self.centre[1]
        self.radius = float(np.sqrt(np.mean(u * u + v * v)))
        grad = np.stack([gx * u, gx * v, gy * u, gy * v, gx, gy] if affine else [gx, gy])
        self._grad = grad - grad.mean(axis=1, keepdims=True)  # zero-mean, as the template is
        self._inverse_hessian = np.linalg.inv(self._grad @ self._grad.T)

    def _smooth(self, image: NDArray[np.float32]) -> NDArray[np.float32]:
        import cv2

        if not self._blur:
            return image
        return np.asarray(cv2.GaussianBlur(image, (self._blur, self._blur), 0), np.float32)

    def _sample(self, frame: NDArray[np.uint8], warp: NDArray[np.float64]) -> NDArray[np.float32]:
        """The frame at ``warp`` (2x3, reference pixel -> frame pixel) of the box's pixels."""
        import cv2

        x0, y0, w, h = self._box
        if not self._affine:
            centre = (x0 + warp[0, 2] + (w - 1) / 2, y0 + warp[1, 2] + (h - 1) / 2)
            return np.asarray(cv2.getRectSubPix(frame, (w, h), centre, patchType=cv2.CV_32F))
        box = warp.copy()
        box[:, 2] += warp[:, :2] @ np.array([x0, y0], np.float64)
        return np.asarray(
            cv2.warpAffine(
                frame,
                box,
                (w, h),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            ),
            np.float32,
        )

    def __call__(
        self, frame: NDArray[np.uint8], start: NDArray[np.float64]
    ) -> tuple[float, NDArray[np.float64]] | None:
        """``(correlation, warp)``: the reference's masked pixel p is the frame's ``warp @ (p, 1)``;
        None when the fit diverges or the frame is flat there.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W)
        start : ndarray of float64, shape (2,) or (2, 3)
            Initial shift (dx, dy), or initial warp.

        Returns
        -------
        (float, ndarray of float64, shape (2, 3)) or None
            A translation's warp is ``[[1, 0, dx], [0, 1, dy]]``.
        """
        warp = np.eye(2, 3)
        if np.shape(start) == (2,):
            warp[:, 2] = start
        else:
            warp[:] = start
        rho = -1.0
        for _ in range(self._max_iterations):
            values = self._smooth(self._sample(frame, warp)).ravel()[self._idx].astype(np.float64)
            values -= values.mean()
            power = float(values @ values)
            if power <= 0.0:
                return None
            overlap = float(self._template @ values)
            rho = overlap / (self._template_norm * math.sqrt(power))
            # The frame, scaled to the template by least squares, against the reference moved by the
            # update: frame(W(p)) ~ reference(D(p)), so the new warp is W composed with D's inverse.
            residual = (overlap / power) * values - self._template
            delta = self._inverse_hessian @ (self._grad @ residual)
            if self._affine:
                step = np.eye(3)
                step[:2, :2] += delta[:4].reshape(2, 2)
                step[:2, 2] = delta[4:] + self.centre - step[:2, :2] @ self.centre
                try:
                    warp = (np.vstack([warp, [0.0, 0.0, 1.0]]) @ np.linalg.inv(step))[:2]
                except np.linalg.LinAlgError:
                    return None
                moved = math.hypot(*delta[4:]) + self.radius * float(np.linalg.norm(delta[:4]))
            else:
                warp[:, 2] -= delta
                moved = math.hypot(*delta)
            if not np.all(np.isfinite(warp)):
                return None
            if moved < self.TOLERANCE_PX:
                break
        return rho, warp


#: Frames (the most displaced) on which the outline is checked against the object's motion.
OUTLINE_PROBE_FRAMES = 4
#: Outline size (input pixels) from which the affine refinement is used.
AFFINE_MIN_PIXELS = 1500


def register_translation(
    grays: NDArray[np.uint8],
    ref_mask: NDArray[np.bool_],
    *,
    ref_index: int,
    initial_px: NDArray[np.float64],
    max_iterations: int = 60,
    affine: bool = True,
) -> tuple[NDArray[np.float64], float]:
    """Sub-pixel displacement of a rigid object in every frame, relative to a reference frame, by
    registration of the object's texture.

    Dense flow is smoothed at object boundaries and biased low for small and for very large motions;
    registering the object's texture (a translation that maximises the masked correlation coefficient with
    the reference, the ECC criterion, fitted by :class:`_MaskedFit` and started from the flow's
    estimate, then from the last registered position, then from phase correlation) measures the
    displacement to a few hundredths of a pixel.

    Parameters
    ----------
    grays : ndarray of uint8, shape (T, H, W)
        Grey frames at input resolution.
    ref_mask : ndarray of bool, shape (H, W)
        The object's pixels in the reference frame (see :func:`silhouette`).
    ref_index : int
        The reference frame.
    initial_px : ndarray of float64, shape (T, 2)
        Starting displacement (dx, dy) per frame relative to the reference, from flow.
    max_iterations : int
    affine : bool
        Where the object changes scale, refine each translation with an affine fit and report the
        displacement of the outline's centroid: an object moving along the line of sight also changes
        scale, and a translation-only fit of an outline that is not centred on the object would mix
        scale into displacement. Whether scale matters is measured on the most displaced frames first
        (see :func:`_refine_where_scale_matters`).

    Returns
    -------
    displacement : ndarray of float64, shape (T, 2)
        (dx, dy) of the object (the outline's centroid) in frame k relative to the reference frame,
        input pixels.
    failed_fraction : float
        Frames where registration did not converge (their flow estimate is kept).
    """
    import cv2

    t_count, height, width = grays.shape
    reach = float(np.abs(initial_px).max()) if initial_px.size else 0.0
    core = ref_mask.astype(np.uint8)
    ys, xs = np.nonzero(core)
    if len(xs) < 64:
        return initial_px.copy(), 1.0
    pad = math.ceil(1.3 * reach) + 8
    x0, x1 = max(0, xs.min() - pad), min(width, xs.max() + pad + 1)
    y0, y1 = max(0, ys.min() - pad), min(height, ys.max() + pad + 1)
    ref = grays[ref_index, y0:y1, x0:x1].astype(np.float32)
    ref_mask_crop = core[y0:y1, x0:x1]
    hann = cv2.createHanningWindow((ref.shape[1], ref.shape[0]), cv2.CV_32F)
    out = initial_px.astype(np.float64).copy()
    converged: set[int] = set()  # frames whose translation in ``out`` is registered, not the flow's

    def crop(k: int) -> NDArray[np.float32]:
        return grays[k, y0:y1, x0:x1].astype(np.float32)

    def fitter(mask_crop: NDArray[np.uint8], *, affine: bool = False) -> _MaskedFit | None:
        full = np.zeros((height, width), bool)
        full[y0:y1, x0:x1] = mask_crop > 0
        try:
            if affine:
                return _MaskedFit(grays[ref_index], full, affine=True, max_iterations=25)
            return _MaskedFit(grays[ref_index], full, max_iterations=max_iterations)
        except np.linalg.LinAlgError:  # a textureless outline: nothing to register on
            return None

    translation = fitter(ref_mask_crop)
    if translation is None:
        return initial_px.copy(), 1.0

    def fit(k: int, start: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]] | None:
        assert translation is not None
        found = translation(grays[k], start)
        return None if found is None else (found[0], found[1][:, 2])

    def consistent_outline() -> NDArray[np.uint8]:
        """The outline without the pixels that stay put while the object moves.

        Flow smears motion a few pixels past the object's trailing edge, so the outline taken from it
        holds a strip of static background, which pulls the registered displacement low. In the frames
        most displaced from the reference, a pixel of the object matches the reference once the object's
        shift is undone; a background pixel matches it where it is.
        """
        distance = np.hypot(initial_px[:, 0], initial_px[:, 1])
        keep = np.ones(ref_mask_crop.shape, bool)
        votes = 0
        for k in np.argsort(distance)[::-1][:OUTLINE_PROBE_FRAMES]:
            if distance[k] < 1.0:
                break
            found = fit(int(k), initial_px[k])
            if found is None or found[0] < 0.5:
                continue
            cur = crop(int(k))
            shift = np.array([[1, 0, found[1][0]], [0, 1, found[1][1]]], np.float32)
            aligned = cv2.warpAffine(
                cur,
                shift,
                (cur.shape[1], cur.shape[0]),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_REPLICATE,
            )
            moved = cv2.blur(np.abs(aligned - ref), (5, 5))
            stayed = cv2.blur(np.abs(cur - ref), (5, 5))
            # Flat pixels match either way: keep them unless the object's shift clearly misfits.
            tolerance = 2.0 * float(np.median(moved[ref_mask_crop > 0]))
            keep &= (moved <= stayed) | (moved <= tolerance)
            votes += 1
        refined = (ref_mask_crop > 0) & keep
        if votes == 0 or refined.sum() < max(64, 0.5 * np.count_nonzero(ref_mask_crop)):
            return ref_mask_crop
        return refined.astype(np.uint8)

    outline = consistent_outline()
    if outline is not ref_mask_crop:
        ref_mask_crop = outline
        translation = fitter(outline) or translation
    large = np.count_nonzero(ref_mask_crop) >= AFFINE_MIN_PIXELS
    affine_fit = fitter(ref_mask_crop, affine=True) if affine and large else None

    def refine_affine(k: int) -> tuple[NDArray[np.float64], float] | None:
        """Displacement of the outline's centroid in frame k from an affine fit, and the fit's scale
        (square root of the determinant of the map from the frame to the reference), or None."""
        assert affine_fit is not None
        found = affine_fit(grays[k], out[k])
        if found is None:
            return None
        warp = found[1]
        det = 1.0 / float(np.linalg.det(warp[:, :2]))
        if not math.isfinite(det) or abs(det - 1) >= 0.3:
            return None
        # The reference's centroid p sits at W p in frame k.
        p = affine_fit.centre
        return warp[:, :2] @ p + warp[:, 2] - p, math.sqrt(det)

    def track(segments: list[tuple[range, int]]) -> int:
        return sum(track_segment(order, last) for order, last in segments)

    def track_segment(order: range, last: int) -> int:
        """Register the frames of ``order`` in turn, each started from the one before; ``last`` is the
        frame next to the first on the reference's side, whose flow estimate seeds the chain."""
        failures = 0
        previous = np.zeros(2) if last == ref_index else initial_px[last].astype(np.float64)
        for k in order:
            # Starts, cheapest first: the flow's estimate; the last registered position moved by the
            # flow's step; phase correlation (wide basin, for motions the flow underestimates).
            starts = [initial_px[k], previous + (initial_px[k] - initial_px[last])]
            best: tuple[float, NDArray[np.float64]] | None = None
            for attempt in range(3):
                if attempt == 2:
                    (sx, sy), _ = cv2.phaseCorrelate(ref, crop(k), hann)
                    starts.append(np.array([sx, sy]))
                found = fit(k, starts[attempt])
                if found is not None and (best is None or found[0] > best[0]):
                    best = found
                if best is not None and best[0] > 0.9:
                    break
            last = k
            if best is None or best[0] < 0.5:
                failures += 1
                previous = previous + (initial_px[k] - initial_px[k - 1 if k > ref_index else k + 1])
                continue
            out[k] = best[1]
            converged.add(k)
            previous = best[1]
        return failures

    out[ref_index] = 0.0
    # Chains of frames are independent: two threads share them evenly (OpenCV drops the GIL).
    with ThreadPoolExecutor(max_workers=2, thread_name_prefix="ecc") as pool:
        jobs = [pool.submit(track, share) for share in _tracking_shares(ref_index, t_count)]
        failures = sum(job.result() for job in jobs)
        # Six affine parameters need many textured pixels; on a small outline they only add noise.
        if affine_fit is not None and converged:
            _refine_where_scale_matters(
                out, sorted(converged), refine_affine, pool, radius_px=affine_fit.radius
            )
    return out, failures / max(t_count - 1, 1)


def _tracking_shares(ref_index: int, t_count: int) -> tuple[list[tuple[range, int]], list[tuple[range, int]]]:
    """Two equal shares of the frames to register, as chains ``(frames, seed)`` that run outward from the
    reference (``seed`` is the frame next to a chain's first one, towards the reference).

    The reference is often near one end of the clip (the largest motion follows the release), so
    "forward" and "backward" alone would leave one thread with nearly all the work; the longer side is
    cut in two instead.
    """
    forward, backward = t_count - 1 - ref_index, ref_index
    half = (forward + backward + 1) // 2
    if forward >= backward:
        cut = ref_index + half  # the first share: ref+1 .. cut; the second: the backward side and the rest
        first = [(range(ref_index + 1, cut + 1), ref_index)]
        second = [(range(ref_index - 1, -1, -1), ref_index), (range(cut + 1, t_count), cut)]
    else:
        cut = ref_index - half
        first = [(range(ref_index - 1, cut - 1, -1), ref_index)]
        second = [(range(ref_index + 1, t_count), ref_index), (range(cut - 1, -1, -1), cut)]
    return first, [(order, seed) for order, seed in second if len(order)]


#: Frames the affine refinement is first tried on, to see whether the object changes scale at all.
AFFINE_PROBE_FRAMES = 12
#: Bound on the bias (scale range x outline radius), as a fraction of the displacement range, from which
#: every frame is refined with an affine fit. The bound overstates the real bias several times, and the
#: affine scale's own scatter reaches 1 % of it for motion in the image plane (0.5 % on DIS "medium"
#: flow, 1.2 % on "fine"), while 45 degrees out of the plane gives 8.5 %.
AFFINE_MIN_BIAS = 0.03


def _refine_where_scale_matters(
    out: NDArray[np.float64],
    frames: list[int],
    refine: Callable[[int], tuple[NDArray[np.float64], float] | None],
    pool: Executor,
    *,
    radius_px: float,
) -> None:
    """Replace translations in ``out`` by the affine fit's centroid displacement where scale matters.

    An object moving along the line of sight changes scale in step with its motion, and a translation
    fit of an outline not centred on its texture then reads part of that scale as displacement: at most
    the scale change times the outline's radius. The affine fit (three times the cost, and itself
    disturbed by background left in the outline) is first run on the most displaced frames; every frame
    is refined only if their scale changes could bias the displacement by ``AFFINE_MIN_BIAS`` of its
    range (and at least a hundredth of a pixel).
    """
    idx = np.asarray(frames)
    centred = out[idx] - out[idx].mean(axis=0)
    _, vecs = np.linalg.eigh(centred.T @ centred)
    along = centred @ vecs[:, -1]
    order = np.argsort(along)
    half = AFFINE_PROBE_FRAMES // 2
    probe = sorted({int(idx[i]) for i in (*order[:half], *order[-half:])})
    refined = dict(zip(probe, pool.map(refine, probe), strict=True))
    scales = [r[1] for r in refined.values() if r is not None]
    if len(scales) < 4:
        return
    bias_px = (max(scales) - min(scales)) * radius_px
    if bias_px < max(AFFINE_MIN_BIAS * float(np.ptp(along)), 0.01):
        return
    rest = [k for k in frames if k not in refined]
    refined.update(zip(rest, pool.map(refine, rest), strict=True))
    for k, found in refined.items():
        if found is not None:
            out[k] = found[0]


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


def release_instant(fit: RingdownFit, *, fps: float, excitation: str | None) -> float:
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
    t_max = 1.0 / fps
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
    stiffness_sd: float | None = None
    mass_kg: float | None = None
    mass_sd: float | None = None
    null_reasons: list[str] = field(default_factory=list)


def stiffness_and_mass(
    *,
    kind: Literal["step_release", "impulse"],
    value: float,
    value_sd: float,
    amplitude_m: float,
    amplitude_sd_m: float,
    natural_frequency_hz: float,
    damped_frequency_hz: float,
    frequency_sd_hz: float,
) -> Mechanics:
    """k and m from the excitation, the release amplitude and the frequency.

    Parameters
    ----------
    kind : ``"step_release"`` (value = held force F, N) or ``"impulse"`` (value = impulse J, N·s)
    value, value_sd : float
    amplitude_m, amplitude_sd_m : float
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
    rel_a = amplitude_sd_m / amplitude_m
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
    return Mechanics(stiffness_n_per_m=k, stiffness_sd=k * rel_k, mass_kg=m, mass_sd=m * rel_m)


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
    for k in range(t_count):
        if shifts_px is not None:
            dx, dy = np.rint(shifts_px[k]).astype(int)
            yy, xx = ys + dy, xs + dx
            ok = (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
            values = depth[k, yy[ok], xx[ok]]
        else:
            values = depth[k, ys, xs]
        values = values[np.isfinite(values)]
        if values.size:
            out[k] = float(np.median(values))
    return out


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
