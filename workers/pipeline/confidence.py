"""How well the image constrains optical flow at each pixel, and flow expressed in what the image can show.

Flow is a measurement only where the image has texture: along an edge only its normal component is seen,
and in a flat, saturated or codec-blocked region the estimate is noise (the codec's own, which pulses with
its keyframes). The local structure tensor of a grey image,

    J = G * [[Ix Ix, Ix Iy], [Ix Iy, Iy Iy]]   (G: a box of the flow's patch size),

says how much: a flow error δu changes the brightness a patch predicts by δuᵀ J δu (Lucas–Kanade's
Cramér–Rao bound: the flow's noise covariance is σ² J⁻¹ for image noise σ). So the *constrained flow*

    z = J^(1/2) u

is the brightness change each pixel's motion explains: its noise is about σ wherever there is texture, it
carries only the normal component along an edge, and it is zero in a flat region whatever the flow there
says. Spectra, noise floors and detection statistics of z weigh every pixel by what the image can show
(:mod:`workers.pipeline.significance`); the flow itself (in pixels) stays the measurement of how far an
object moves.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

#: An array of either kind :func:`mixed_pair` turns: real (flow) or complex (spectra).
_Pair = NDArray[np.floating[Any]] | NDArray[np.complexfloating[Any, Any]]

#: Grey levels from which a pixel counts as clipped (saturated white or crushed black).
CLIPPED_LEVELS = (2, 253)
#: A pixel's texture energy at this multiple of the image's noise energy gives it half weight.
NOISE_ENERGY_FACTOR = 4.0
#: Quantile of the texture energy taken as the noise's (the flattest part of almost any picture).
NOISE_QUANTILE = 5.0
#: Texture energy (larger eigenvalue of the tensor) that white image noise of unit variance gives: the
#: Sobel kernel / 8 has a gain of 12 / 64 per component, and the larger eigenvalue of a noise tensor
#: averaged over a small box is about twice one component's mean.
NOISE_ENERGY_PER_VARIANCE = 0.375


@dataclass(frozen=True)
class Confidence:
    """The structure tensor of a grey image on a flow grid, and the weight of each pixel's flow.

    Attributes
    ----------
    jxx, jxy, jyy : ndarray of float32, shape (h, w)
        Structure tensor components, (grey levels per grid pixel)², averaged over the flow's patch.
    weight : ndarray of float32, shape (h, w)
        In [0, 1): ``e / (e + NOISE_ENERGY_FACTOR * e_noise)`` with ``e`` the tensor's larger eigenvalue
        (an edge in any direction constrains the motion across it) and ``e_noise`` what image noise alone
        gives; 0 where the grey level is clipped.
    noise_energy : float
        ``e_noise``.
    """

    jxx: NDArray[np.float32]
    jxy: NDArray[np.float32]
    jyy: NDArray[np.float32]
    weight: NDArray[np.float32]
    noise_energy: float

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.jxx.shape[0]), int(self.jxx.shape[1]))


def structure_tensor(
    gray: NDArray[np.floating] | NDArray[np.uint8], *, radius_px: int = 2
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """The local structure tensor of a grey image.

    Parameters
    ----------
    gray : ndarray, shape (h, w)
        Grey levels (uint8 or float).
    radius_px : int
        Half-side of the averaging box (the flow's patch is about ``2 * radius_px + 1`` wide).

    Returns
    -------
    jxx, jxy, jyy : ndarray of float32, shape (h, w)
    """
    g = np.asarray(gray, np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8
    box = (2 * radius_px + 1, 2 * radius_px + 1)
    jxx = np.asarray(cv2.blur(gx * gx, box), np.float32)
    jxy = np.asarray(cv2.blur(gx * gy, box), np.float32)
    jyy = np.asarray(cv2.blur(gy * gy, box), np.float32)
    return jxx, jxy, jyy


def flow_confidence(
    gray: NDArray[np.floating] | NDArray[np.uint8],
    *,
    radius_px: int = 2,
    frame_noise: float | None = None,
) -> Confidence:
    """The confidence of flow computed on ``gray``'s grid (see the module's description).

    Parameters
    ----------
    gray : ndarray, shape (h, w)
        A representative grey frame on the flow grid: the window's mean frame is best (its own noise
        averages out; a moving object's texture is blurred along its motion only).
    radius_px : int
    frame_noise : float, optional
        Standard deviation of one frame's noise (sensor and codec), grey levels on this grid: the flow
        is computed on single frames, so texture weaker than what that noise gives is none. Without it,
        the noise energy is the :data:`NOISE_QUANTILE` percentile of the picture's texture energy.

    Returns
    -------
    Confidence
    """
    jxx, jxy, jyy = structure_tensor(gray, radius_px=radius_px)
    half_trace = (jxx + jyy) / 2
    larger = half_trace + np.sqrt(((jxx - jyy) / 2) ** 2 + jxy * jxy)
    noise = float(np.percentile(larger, NOISE_QUANTILE)) + 1e-6
    if frame_noise is not None:
        noise = max(noise, NOISE_ENERGY_PER_VARIANCE * frame_noise**2)
    weight = larger / (larger + np.float32(NOISE_ENERGY_FACTOR * noise))
    g = np.asarray(gray, np.float32)
    lo, hi = CLIPPED_LEVELS
    clipped = cv2.dilate(((g <= lo) | (g >= hi)).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    weight[clipped] = 0.0
    return Confidence(jxx=jxx, jxy=jxy, jyy=jyy, weight=weight.astype(np.float32), noise_energy=noise)


def tensor_sqrt(
    conf: Confidence,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """J^(1/2) per pixel, as (a, b, c) of the symmetric matrix [[a, b], [b, c]].

    For a symmetric positive semi-definite 2 x 2 matrix, sqrt(J) = (J + s I) / t with s = sqrt(det J) and
    t = sqrt(trace J + 2 s).
    """
    det = np.maximum(conf.jxx * conf.jyy - conf.jxy * conf.jxy, 0.0)
    s = np.sqrt(det)
    t = np.sqrt(np.maximum(conf.jxx + conf.jyy + 2 * s, 1e-12))
    return (
        np.asarray((conf.jxx + s) / t, np.float32),
        np.asarray(conf.jxy / t, np.float32),
        np.asarray((conf.jyy + s) / t, np.float32),
    )


def mixed_pair(x: _Pair, y: _Pair, a: _Pair, b: _Pair, c: _Pair) -> tuple[_Pair, _Pair]:
    """``(a x + b y, b x + c y)``: each pixel's pair (x, y), its flow (u, v) or their spectra, turned by
    its own symmetric matrix [[a, b], [b, c]] (J^(1/2), :func:`tensor_sqrt`), broadcast elementwise. The
    one place the constrained flow's formula is written (for flow maps, spectra of a window's blocks, and
    per-pixel spectra inside the FFT's blocks)."""
    return a * x + b * y, b * x + c * y


def constrained_flow(
    flow: NDArray[np.float32], conf: Confidence, *, out: NDArray[np.float32] | None = None
) -> NDArray[np.float32]:
    """``z = J^(1/2) u`` for every flow map: the brightness change the motion explains (see above).

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2) or (h, w, 2)
        Flow on the grid of ``conf``, grid pixels per frame.
    conf : Confidence
    out : ndarray of float32, same shape, optional

    Returns
    -------
    ndarray of float32, same shape as ``flow``
        In grey levels per frame.
    """
    if flow.shape[-3:-1] != conf.shape:
        raise ValueError(f"constrained_flow: flow grid {flow.shape[-3:-1]} is not the tensor's {conf.shape}")
    zx, zy = mixed_pair(flow[..., 0], flow[..., 1], *tensor_sqrt(conf))
    result = out if out is not None else np.empty(flow.shape, np.float32)
    result[..., 0] = zx  # both computed first: ``out`` may be ``flow`` itself
    result[..., 1] = zy
    return result


__all__ = [
    "Confidence",
    "constrained_flow",
    "flow_confidence",
    "mixed_pair",
    "structure_tensor",
    "tensor_sqrt",
]
