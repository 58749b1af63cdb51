"""Image registration of an object's texture: where a rigid object is in every frame, to a few hundredths
of a pixel, by the masked correlation coefficient (ECC) with a reference frame.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray


class MaskedFit:
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
        grad -= grad.mean(axis=1, keepdims=True)  # zero-mean, as the template is
        self._inverse_hessian = np.linalg.inv(grad @ grad.T)
        # One product per iteration gives every sum it needs (see __call__): the template, the gradients
        # and a row of ones against the sampled values.
        self._basis = np.vstack([self._template, grad, np.ones(len(self._idx))])
        self._grad_template = grad @ self._template

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
        self, frame: NDArray[np.uint8], start: NDArray[np.float64], *, strict: bool = False
    ) -> tuple[float, NDArray[np.float64]] | None:
        """``(correlation, warp)``: the reference's masked pixel p is the frame's ``warp @ (p, 1)``;
        None when the fit diverges or the frame is flat there.

        Parameters
        ----------
        frame : ndarray of uint8, shape (H, W)
        start : ndarray of float64, shape (2,) or (2, 3)
            Initial shift (dx, dy), or initial warp.
        strict : bool
            Also None when the fit has not converged within ``max_iterations`` (where the texture
            cannot hold some of the warp's parameters, a flat bar's scale along itself, they wander).

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
        count = len(self._idx)
        for _ in range(self._max_iterations):
            values = self._smooth(self._sample(frame, warp)).ravel().take(self._idx).astype(np.float64)
            # With v the values less their mean, and template T and gradients G of zero mean:
            # T.v = T.values, G.v = G.values, v.v = values.values - count mean^2.
            sums, square = self._basis @ values, float(values @ values)
            power = square - sums[-1] * sums[-1] / count
            if power <= 1e-9 * square:  # flat (to rounding)
                return None
            overlap = float(sums[0])
            rho = overlap / (self._template_norm * math.sqrt(power))
            # The frame, scaled to the template by least squares, against the reference moved by the
            # update: frame(W(p)) ~ reference(D(p)), so the new warp is W composed with D's inverse;
            # G.((overlap / power) v - T) is the gradient of the residual.
            delta = self._inverse_hessian @ ((overlap / power) * sums[1:-1] - self._grad_template)
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
        else:
            if strict:
                return None
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
    max_failed: float = 1.0,
) -> tuple[NDArray[np.float64], float]:
    """Sub-pixel displacement of a rigid object in every frame, relative to a reference frame, by
    registration of the object's texture.

    Dense flow is smoothed at object boundaries and biased low for small and for very large motions;
    registering the object's texture (a translation that maximises the masked correlation coefficient with
    the reference, the ECC criterion, fitted by :class:`MaskedFit` and started from the flow's
    estimate, then from the last registered position, then from phase correlation) measures the
    displacement to a few hundredths of a pixel.

    Parameters
    ----------
    grays : ndarray of uint8, shape (T, H, W)
        Grey frames at input resolution.
    ref_mask : ndarray of bool, shape (H, W)
        The object's pixels in the reference frame (see :func:`workers.pipeline.tracking.silhouette`).
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
    max_failed : float
        Stop once more than this share of the frames failed: a caller that discards a registration
        failing that often gains nothing from the rest (a blurred fork's tines failed 90 % of 256 frames,
        each after three starts of up to 60 iterations: 1.5 s). The share returned then exceeds it.

    Returns
    -------
    displacement : ndarray of float64, shape (T, 2)
        (dx, dy) of the object (the outline's centroid) in frame k relative to the reference frame,
        input pixels.
    failed_fraction : float
        Frames where registration did not converge (their flow estimate is kept).
    """
    if np.count_nonzero(ref_mask) < 64:
        return initial_px.copy(), 1.0
    tracker = _Registration(
        grays,
        ref_mask,
        ref_index=ref_index,
        initial_px=initial_px,
        max_iterations=max_iterations,
        max_failures=math.floor(max_failed * max(len(grays) - 1, 1)),
    )
    if tracker.translation is None:
        return initial_px.copy(), 1.0
    return tracker.run(affine=affine)


class _Registration:
    """One object's registration over a clip: the reference crop, its fitters, and the displacement of each
    frame as it is registered (``out``; ``converged`` names the frames registered rather than kept from
    the flow)."""

    def __init__(
        self,
        grays: NDArray[np.uint8],
        ref_mask: NDArray[np.bool_],
        *,
        ref_index: int,
        initial_px: NDArray[np.float64],
        max_iterations: int,
        max_failures: int,
    ) -> None:
        import cv2

        self.grays = grays
        self.ref_index = ref_index
        self.initial = initial_px
        self.max_iterations = max_iterations
        t_count, self.height, self.width = grays.shape
        self.t_count = t_count
        reach = float(np.abs(initial_px).max()) if initial_px.size else 0.0
        core = ref_mask.astype(np.uint8)
        ys, xs = np.nonzero(core)
        pad = math.ceil(1.3 * reach) + 8
        x0, x1 = max(0, xs.min() - pad), min(self.width, xs.max() + pad + 1)
        y0, y1 = max(0, ys.min() - pad), min(self.height, ys.max() + pad + 1)
        self.box = (int(x0), int(y0), int(x1), int(y1))
        self.ref = grays[ref_index, y0:y1, x0:x1].astype(np.float32)
        self.mask_crop = core[y0:y1, x0:x1]
        self.hann = cv2.createHanningWindow((self.ref.shape[1], self.ref.shape[0]), cv2.CV_32F)
        self.out = initial_px.astype(np.float64).copy()
        self.converged: set[int] = set()
        self.max_failures = max_failures
        self.failures = 0  # over both chains
        self.translation = self.fitter(self.mask_crop)
        self.affine_fit: MaskedFit | None = None

    def crop(self, k: int) -> NDArray[np.float32]:
        x0, y0, x1, y1 = self.box
        return self.grays[k, y0:y1, x0:x1].astype(np.float32)

    def fitter(self, mask_crop: NDArray[np.uint8], *, affine: bool = False) -> MaskedFit | None:
        x0, y0, x1, y1 = self.box
        full = np.zeros((self.height, self.width), bool)
        full[y0:y1, x0:x1] = mask_crop > 0
        try:
            if affine:
                return MaskedFit(self.grays[self.ref_index], full, affine=True, max_iterations=25)
            return MaskedFit(self.grays[self.ref_index], full, max_iterations=self.max_iterations)
        except np.linalg.LinAlgError:  # a textureless outline: nothing to register on
            return None

    def fit(self, k: int, start: NDArray[np.float64]) -> tuple[float, NDArray[np.float64]] | None:
        assert self.translation is not None
        found = self.translation(self.grays[k], start)
        return None if found is None else (found[0], found[1][:, 2])

    def consistent_outline(self) -> NDArray[np.uint8]:
        """The outline without the pixels that stay put while the object moves.

        Flow smears motion a few pixels past the object's trailing edge, so the outline taken from it
        holds a strip of static background, which pulls the registered displacement low. In the frames
        most displaced from the reference, a pixel of the object matches the reference once the object's
        shift is undone; a background pixel matches it where it is.
        """
        import cv2

        initial_px, ref, ref_mask_crop = self.initial, self.ref, self.mask_crop
        distance = np.hypot(initial_px[:, 0], initial_px[:, 1])
        keep = np.ones(ref_mask_crop.shape, bool)
        votes = 0
        probes = [int(k) for k in np.argsort(distance)[::-1][:OUTLINE_PROBE_FRAMES] if distance[k] >= 1.0]
        for k in probes:
            found = self.fit(k, initial_px[k])
            if found is None or found[0] < 0.5:
                continue
            cur = self.crop(k)
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

    def refine_affine(self, k: int) -> tuple[NDArray[np.float64], float] | None:
        """Displacement of the outline's centroid in frame k from an affine fit, and the fit's scale
        (square root of the determinant of the map from the frame to the reference), or None."""
        assert self.affine_fit is not None
        found = self.affine_fit(self.grays[k], self.out[k], strict=True)
        if found is None:
            return None
        warp = found[1]
        det = 1.0 / float(np.linalg.det(warp[:, :2]))
        if not math.isfinite(det) or abs(det - 1) >= 0.3:
            return None
        # The reference's centroid p sits at W p in frame k.
        p = self.affine_fit.centre
        return warp[:, :2] @ p + warp[:, 2] - p, math.sqrt(det)

    def _failed(self) -> bool:
        """Count a failed frame; whether the failures are now more than the caller keeps."""
        self.failures += 1
        return self.failures > self.max_failures

    def track_chain(self, order: range) -> None:
        """Register the frames of ``order`` (running outward from the reference) in turn, each started
        from the one before."""
        import cv2

        initial_px, ref_index = self.initial, self.ref_index
        previous, last = np.zeros(2), ref_index
        for k in order:
            if self.failures > self.max_failures:
                return
            # Starts, nearest first: the last registered position moved by the flow's step (the flow's
            # own estimate is biased low, and a fit started there walked off for up to 60 iterations
            # before the next start: 13 iterations a frame on average, against 3 from this one); the
            # flow's estimate; phase correlation (wide basin, for motions the flow underestimates).
            starts = [previous + (initial_px[k] - initial_px[last]), initial_px[k]]
            best: tuple[float, NDArray[np.float64]] | None = None
            for attempt in range(3):
                if attempt == 2:
                    (sx, sy), _ = cv2.phaseCorrelate(self.ref, self.crop(k), self.hann)
                    starts.append(np.array([sx, sy]))
                found = self.fit(k, starts[attempt])
                if found is not None and (best is None or found[0] > best[0]):
                    best = found
                if best is not None and best[0] > 0.9:
                    break
            last = k
            if best is None or best[0] < 0.5:
                if self._failed():
                    return
                previous = previous + (initial_px[k] - initial_px[k - 1 if k > ref_index else k + 1])
                continue
            self.out[k] = best[1]
            self.converged.add(k)
            previous = best[1]

    def run(self, *, affine: bool) -> tuple[NDArray[np.float64], float]:
        """Register every frame, in two chains running outward from the reference; (displacement per
        frame, fraction of frames that failed). In the calling thread: a fit is many small steps, and
        two threads sharing the frames only fought over the interpreter (the registration of 256 frames
        of 640 x 480 took 0.12 s on two, 0.08 s on one)."""
        outline = self.consistent_outline()
        if outline is not self.mask_crop:
            self.mask_crop = outline
            self.translation = self.fitter(outline) or self.translation
        large = np.count_nonzero(self.mask_crop) >= AFFINE_MIN_PIXELS
        self.affine_fit = self.fitter(self.mask_crop, affine=True) if affine and large else None
        self.out[self.ref_index] = 0.0
        self.track_chain(range(self.ref_index + 1, self.t_count))
        self.track_chain(range(self.ref_index - 1, -1, -1))
        # Six affine parameters need many textured pixels; on a small outline they only add noise.
        if self.affine_fit is not None and self.converged and self.failures <= self.max_failures:
            _refine_where_scale_matters(
                self.out, sorted(self.converged), self.refine_affine, radius_px=self.affine_fit.radius
            )
        return self.out, self.failures / max(self.t_count - 1, 1)


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
    refined = {k: refine(k) for k in probe}
    scales = [r[1] for r in refined.values() if r is not None]
    if len(scales) < 4:
        return
    bias_px = (max(scales) - min(scales)) * radius_px
    if bias_px < max(AFFINE_MIN_BIAS * float(np.ptp(along)), 0.01):
        return
    rest = [k for k in frames if k not in refined]
    refined.update((k, refine(k)) for k in rest)
    for k, found in refined.items():
        if found is not None:
            out[k] = found[0]


__all__ = ["MaskedFit", "register_translation"]
