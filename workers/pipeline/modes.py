"""Modes of one object: the narrow-band components of its pixels' motion, each with its frequency,
damping, share of the motion and shape, and which of them are harmonics of another.

An object is the region that moves; a mode is a narrow-band component found on its pixels. The image
shows each pixel's motion (x and y, flow in pixels per sample). A mode's *shape* is the complex amplitude
of every pixel's motion at the mode's frequency (the window's tapered DFT there), so that pixels moving
in anti-phase (either side of a node) have opposite signs. Shapes decide what a peak is:

- a peak at an integer multiple of a stronger one whose shape is the same (MAC near 1) is a *harmonic*:
  the object's motion is periodic but not sinusoidal (a rigid object's pixels share one time course);
- a peak whose shape differs (a node, a sign change: low MAC) is a *mode*.

Each mode's modal coordinate is taken by a modal filter (the least-squares projection of the pixels'
motion on every mode's real shape at once, so that one mode's motion does not leak into another's fit)
and fitted as a damped oscillation (:func:`workers.pipeline.ringdown.fit_ringdown`), which gives its
frequency and damping with their uncertainties.

MAC (modal assurance criterion) between shapes a and b: |a^H b|^2 / ((a^H a)(b^H b)), 1 for shapes
equal up to a complex factor, 0 for orthogonal ones.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.errors import ParameterError
from workers.pipeline.flow import pixel_columns
from workers.pipeline.peaks import interpolate_peak, nanmedian_over_time, noise_floor
from workers.pipeline.ringdown import RingdownFit, damping_sd, fit_ringdown, frequency_sd_hz, regime_of_fit
from workers.pipeline.roi import Roi
from workers.pipeline.significance import tukey

#: A peak of the object's summed spectrum is a candidate mode when it stands this far above the
#: spectrum's running median (its floor), dB.
MIN_MODE_DB = 10.0
#: ... and holds at least this share of the strongest peak's power (weaker lines are leakage and noise).
MIN_MODE_SHARE = 0.01
#: A line at a whole multiple of a stronger mode is a mode only when its modal coordinate is fitted with
#: at least this signal-to-residual ratio per sample, dB (the bending modes of the rendered cantilevers:
#: 10.8-20 dB; a distortion product at twice the first mode's frequency, -4 dB, its shape's MAC with the
#: first 0.75 from noise alone).
MIN_MODE_FIT_DB = 0.0
#: Running-median width of the floor, bins (odd).
FLOOR_WIDTH_BINS = 31
#: A peak at n times a stronger one (within this relative tolerance, or 1.5 bins) whose shape has a MAC
#: of at least :data:`HARMONIC_MAC` with it is that one's harmonic, not a mode.
HARMONIC_TOLERANCE = 0.02
HARMONIC_MAC = 0.8
#: Harmonic orders considered.
MAX_HARMONIC_ORDER = 10
#: The window is tapered by a Tukey window with this fraction in cosine lobes: a Hann window would all
#: but hide a fast mode that has rung down in the first tenth of the window.
TAPER_ALPHA = 0.2
#: The modal coordinate is fitted within this many bins of its peak (its band).
FIT_HALF_WIDTH_BINS = 6.0


@dataclass(frozen=True)
class Mode:
    """One mode of an object.

    Attributes
    ----------
    frequency_hz : float
        Damped frequency, Hz (from the fit of its modal coordinate).
    frequency_uncertainty_hz : float
        Its standard uncertainty (the fit's own with the systematic floors of an object's), Hz.
    damping_ratio, damping_ratio_uncertainty : float or None
        None when the mode does not decay in the window (its regime is not ``ring_down``).
    energy_share : float
        Share of the object's motion energy (its pixels' summed power over the band) in this mode's line.
    regime : str
        ``ring_down``, ``steady`` or ``growing`` (:func:`workers.pipeline.ringdown.regime_of_fit`).
    shape : ndarray of complex128, shape (P, 2)
        Complex amplitude of each pixel's motion (x, y) at the mode's frequency, flow units, phase-aligned
        so that its largest real part is positive and its imaginary part is as small as can be.
    fit : RingdownFit
        The damped oscillation fitted to the modal coordinate.
    """

    frequency_hz: float
    frequency_uncertainty_hz: float
    damping_ratio: float | None
    damping_ratio_uncertainty: float | None
    energy_share: float
    regime: str
    shape: NDArray[np.complex128]
    fit: RingdownFit

    @property
    def complexity(self) -> float:
        """How far the shape is from a real (standing) one: the imaginary part's share of its norm, 0 for
        a real mode (light, proportional damping), up to 1 for a travelling wave."""
        norm = float(np.sum(np.abs(self.shape) ** 2))
        return float(np.sum(self.shape.imag**2) / norm) if norm > 0 else 0.0


@dataclass(frozen=True)
class Harmonic:
    """A peak that is an overtone of a mode (same shape at an integer multiple of its frequency).

    Attributes
    ----------
    frequency_hz : float
    fundamental_hz : float
        The mode's frequency.
    order : int
    mac : float
        MAC between the peak's shape and the mode's (the evidence).
    """

    frequency_hz: float
    fundamental_hz: float
    order: int
    mac: float


@dataclass(frozen=True)
class ObjectModes:
    """What :func:`find_modes` found on one object.

    Attributes
    ----------
    modes : list of Mode
        Strongest (largest energy share) first.
    harmonics : list of Harmonic
    mac : ndarray of float64, shape (M, M)
        MAC between the modes' shapes (1 on the diagonal).
    """

    modes: list[Mode]
    harmonics: list[Harmonic] = field(default_factory=list)
    mac: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0)))


def mac(
    a: NDArray[np.complexfloating] | NDArray[np.floating],
    b: NDArray[np.complexfloating] | NDArray[np.floating],
) -> float:
    """The modal assurance criterion of two shapes (any shape, flattened): |a^H b|^2 / ((a^H a)(b^H b)).

    Returns
    -------
    float
        In [0, 1]; 0 when either shape is zero.
    """
    x = np.asarray(a, np.complex128).ravel()
    y = np.asarray(b, np.complex128).ravel()
    if x.shape != y.shape:
        raise ParameterError(f"mac: shapes of {x.size} and {y.size} values cannot be compared")
    den = float(np.vdot(x, x).real * np.vdot(y, y).real)
    return float(abs(np.vdot(x, y)) ** 2 / den) if den > 0 else 0.0


def mac_matrix(shapes: list[NDArray[np.complex128]]) -> NDArray[np.float64]:
    """MAC between every pair of ``shapes``, (M, M)."""
    out = np.ones((len(shapes), len(shapes)))
    for i in range(len(shapes)):
        for j in range(i + 1, len(shapes)):
            out[i, j] = out[j, i] = mac(shapes[i], shapes[j])
    return out


def align_phase(shape: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """``shape`` times the unit factor that makes it as real as it can be (the angle that maximises the
    real part's energy: half the angle of the sum of its squares), its largest real component positive."""
    z = np.asarray(shape, np.complex128)
    return np.asarray(z * _alignment(z), np.complex128)


def _alignment(z: NDArray[np.complex128]) -> complex:
    """The unit factor of :func:`align_phase` for ``z``."""
    factor = complex(np.exp(-0.5j * float(np.angle(np.sum(z**2)))))
    flat = (z * factor).real.ravel()
    if flat.size and flat[int(np.argmax(np.abs(flat)))] < 0:
        factor = -factor
    return factor


def find_modes(
    motion: NDArray[np.floating],
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    max_modes: int = 6,
    start_index: int = 0,
) -> ObjectModes:
    """The modes of one object from its pixels' motion.

    Parameters
    ----------
    motion : ndarray of float, shape (N, P, 2)
        Each of the object's P pixels' motion per sample (flow, x and y), N samples at
        ``sample_rate_hz``; the camera's motion removed.
    sample_rate_hz : float
    band_hz : (low, high)
        Modes are sought in this band.
    max_modes : int
        At most this many modes (the strongest), harmonics not counted.
    start_index : int
        First sample of the motion (the release): the modal coordinates are fitted from there.

    Returns
    -------
    ObjectModes

    Raises
    ------
    ParameterError
        On a motion array of the wrong shape, a non-positive rate, or a window too short to fit.
    """
    return _modes_of(
        _series(motion, sample_rate_hz),
        sample_rate_hz=sample_rate_hz,
        band_hz=band_hz,
        max_modes=max_modes,
        start_index=start_index,
    )


def _modes_of(
    x: NDArray[np.float64],
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    max_modes: int,
    start_index: int,
) -> ObjectModes:
    """:func:`find_modes` of the checked (N, 2P) columns ``x`` (see :func:`_series`), which it changes."""
    x -= x.mean(axis=0)
    n = len(x)
    taper = tukey(n, TAPER_ALPHA).astype(np.float64)
    power = _summed_power(x, taper)
    freqs = np.asarray(np.fft.rfftfreq(n, d=1.0 / sample_rate_hz), np.float64)
    bin_hz = sample_rate_hz / n
    lines = _lines(power, freqs, band_hz=band_hz)
    shapes = [align_phase(s) for s in _dfts(x, taper, [f / sample_rate_hz for f, _ in lines])]
    modal, harmonics = _sort_out(lines, shapes, bin_hz=bin_hz)
    modal = modal[:max_modes]
    if not modal:
        return ObjectModes(modes=[], harmonics=harmonics)
    in_band = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    total = float(power[in_band].sum()) or 1.0
    coords = _modal_coordinates(x, [shapes[i] for i in modal])
    modes = [
        _fit_mode(
            coords[:, k],
            shapes[i],
            lines[i],
            sample_rate_hz=sample_rate_hz,
            bin_hz=bin_hz,
            start_index=start_index,
            share=_line_power(power, freqs, lines[i][0], bin_hz) / total,
        )
        for k, i in enumerate(modal)
    ]
    modes, noisy = _noisy_overtones(modes, bin_hz=bin_hz)
    harmonics += noisy
    modes.sort(key=lambda m: -m.energy_share)
    return ObjectModes(modes=modes, harmonics=harmonics, mac=mac_matrix([m.shape for m in modes]))


#: Modes are sought on at most this many of an object's pixels (evenly spread over it); every pixel's
#: shape is then taken at the modes' frequencies.
MAX_MODE_PIXELS = 2048


@dataclass(frozen=True)
class ModeDepth:
    """What depth tells of an object's modes, for their shapes in metres.

    Attributes
    ----------
    depth_m : ndarray of float32, shape (P,)
        Each of the mask's pixels' depth (median over the window), metres; NaN without a reading.
    fx, fy : float
        Focal lengths, input pixels.
    line_of_sight : ndarray of complex64, shape (M, P), or None
        Each mode's complex amplitude of each pixel's depth change per sample (metres), phase-aligned
        with the mode's shape; None with one depth for the whole clip (no series to read it from).
    """

    depth_m: NDArray[np.float32]
    fx: float
    fy: float
    line_of_sight: NDArray[np.complex64] | None = None


@dataclass(frozen=True)
class GridDepth:
    """The object's distance on the flow grid, for its mode shapes in metres.

    Attributes
    ----------
    depth : ndarray of float32, shape (N + 1, h, w), or float
        Depth on the grid (metres, NaN invalid), or one distance for the whole clip (then nothing along
        the line of sight).
    focal_px : (fx, fy)
        Focal lengths, input pixels.
    """

    depth: NDArray[np.float32] | float
    focal_px: tuple[float, float]


@dataclass(frozen=True)
class ObjectModeShapes:
    """An object's modes with their shapes over every pixel of its mask.

    Attributes
    ----------
    found : ObjectModes
        The modes (their ``shape`` on the pixels they were sought on).
    pixels : ndarray of intp, shape (P,)
        Flat indices of the mask's pixels on the flow grid.
    shapes : ndarray of complex64, shape (M, P, 2)
        Each mode's complex amplitude (x, y, flow units) at every pixel of the mask, phase-aligned.
    """

    found: ObjectModes
    pixels: NDArray[np.intp]
    shapes: NDArray[np.complex64]
    roi: Roi | None = None
    depth: ModeDepth | None = None

    def frame_shapes_m(self, full_mask: NDArray[np.bool_]) -> NDArray[np.float32] | None:
        """The modes' real shapes in metres over the whole frame (M, H, W, 3): x and y across the line of
        sight (input pixels times each pixel's depth over the focal length) and z along it (the depth's
        own oscillation at the mode's frequency, positive away from the camera; NaN without a depth
        series), NaN off the object or where depth has no reading; None without depth or intrinsics."""
        if self.depth is None or self.roi is None:
            return None
        lateral = self.frame_shapes(full_mask)
        grid_depth = self._grid(self.depth.depth_m[None, :].astype(np.complex64))[0]
        depth = np.asarray(self.roi.to_frame(grid_depth, fill=np.nan), np.float32)
        out = np.full((*lateral.shape[:-1], 3), np.nan, np.float32)
        out[..., 0] = lateral[..., 0] * depth / np.float32(self.depth.fx)
        out[..., 1] = lateral[..., 1] * depth / np.float32(self.depth.fy)
        if self.depth.line_of_sight is not None:
            along = self._grid(self.depth.line_of_sight)
            for m, mode in enumerate(self.found.modes):
                out[m, ..., 2] = self.roi.to_frame(
                    along[m] * np.float32(abs(mode.fit.amplitude)), fill=np.nan
                )
        out[:, ~full_mask, :] = np.nan
        return out

    def _grid(self, values: NDArray[np.complex64]) -> NDArray[np.float32]:
        """Per-pixel values (M, P) as real images of the grid (M, h, w), NaN off the mask."""
        assert self.roi is not None
        out = np.full((len(values), self.roi.grid_shape[0] * self.roi.grid_shape[1]), np.nan, np.float32)
        out[:, self.pixels] = values.real
        return out.reshape(len(values), *self.roi.grid_shape)

    def frame_shapes(self, full_mask: NDArray[np.bool_], *, imaginary: bool = False) -> NDArray[np.float32]:
        """The modes' real shapes as displacement in input pixels over the whole frame (M, H, W, 2), NaN
        off the object (``full_mask``, (H, W)): each pixel's share of the mode (its real, phase-aligned
        shape) times the modal coordinate's fitted amplitude at the motion's start (the modal filter's
        basis is that same shape, so the product is the pixel's displacement whatever the shape's scale),
        times the input pixels per grid pixel, placed in the box the grid covers (``roi``). With
        ``imaginary``, the shapes' imaginary parts on the same scale (a complex mode's quadrature part)."""
        if self.roi is None:
            raise ParameterError("frame_shapes: the shapes were found without the box their grid covers")
        grid = self.images(self.roi.grid_shape, imaginary=imaginary)
        out = np.full((len(self.found.modes), *full_mask.shape, 2), np.nan, np.float32)
        for m, mode in enumerate(self.found.modes):
            gain = self.roi.pixel_scale * abs(mode.fit.amplitude)
            for c in range(2):
                out[m, ..., c] = self.roi.to_frame(grid[m, ..., c] * np.float32(gain), fill=np.nan)
        out[:, ~full_mask, :] = np.nan
        return out

    def images(self, grid_shape: tuple[int, int], *, imaginary: bool = False) -> NDArray[np.float32]:
        """The modes' real (or imaginary) shapes on the grid, (M, h, w, 2), NaN outside the mask."""
        out = np.full((len(self.found.modes), grid_shape[0] * grid_shape[1], 2), np.nan, np.float32)
        out[:, self.pixels, :] = self.shapes.imag if imaginary else self.shapes.real
        return out.reshape(len(self.found.modes), *grid_shape, 2)


def object_modes(
    flow: NDArray[np.floating],
    mask: NDArray[np.bool_],
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    start_index: int = 0,
    max_modes: int = 6,
    roi: Roi | None = None,
    depth: GridDepth | None = None,
) -> ObjectModeShapes:
    """The modes of the object on ``mask`` in a window's ``flow``, with their shapes on all its pixels.

    Parameters
    ----------
    flow : ndarray of float16 or float32, shape (N, h, w, 2)
    mask : ndarray of bool, shape (h, w)
    sample_rate_hz : float
    band_hz : (low, high)
    start_index : int
        First sample of the motion.
    max_modes : int
    roi : Roi, optional
        The box of the frame the grid covers (for :meth:`ObjectModeShapes.frame_shapes`).
    depth : GridDepth, optional
        The object's distance and the focal lengths: the shapes are also given in metres
        (:meth:`ObjectModeShapes.frame_shapes_m`).

    Returns
    -------
    ObjectModeShapes
    """
    pixels = np.flatnonzero(mask.ravel())
    flat = flow.reshape(len(flow), -1, flow.shape[-1])
    sample = pixels
    if len(pixels) > MAX_MODE_PIXELS:
        sample = pixels[np.linspace(0, len(pixels) - 1, MAX_MODE_PIXELS).astype(np.intp)]
    # the sampled pixels' columns in float64, without their flow-precision copy alive beside them while the
    # modes are sought (13 MiB of the 1000-frame fork's 2048 pixels, at the measurement's peak)
    x = _series(pixel_columns(flat, sample).reshape(len(flat), -1, flat.shape[-1]), sample_rate_hz)
    found = _modes_of(
        x, sample_rate_hz=sample_rate_hz, band_hz=band_hz, max_modes=max_modes, start_index=start_index
    )
    del x
    cycles = [m.frequency_hz / sample_rate_hz for m in found.modes]
    shapes, factors = _shapes_at(flat, pixels, cycles)
    seen = (
        None if depth is None else _mode_depth(depth.depth, pixels, cycles, factors, focal_px=depth.focal_px)
    )
    return ObjectModeShapes(found=found, pixels=pixels, shapes=shapes, roi=roi, depth=seen)


def _mode_depth(
    depth: NDArray[np.float32] | float,
    pixels: NDArray[np.intp],
    cycles_per_sample: list[float],
    factors: NDArray[np.complex64],
    *,
    focal_px: tuple[float, float],
) -> ModeDepth:
    """Each pixel's depth and, from a depth series, each mode's line-of-sight shape: the tapered DFT of
    the pixel's depth change per sample (the flow's own units, so that the modal coordinate's amplitude
    scales both alike), turned by the mode's phase factor."""
    if np.ndim(depth) == 0:
        return ModeDepth(np.full(len(pixels), float(depth), np.float32), *focal_px)
    depth = np.asarray(depth, np.float32)
    rows, cols = np.unravel_index(pixels, depth.shape[1:])
    series = depth[:, rows, cols]  # the pixels only (the depth may be a view of a larger window's)
    median = nanmedian_over_time(series)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        spread = np.nanmax(series, axis=0) - np.nanmin(series, axis=0)
    filled = np.where(np.isfinite(series), series, median[None, :])
    change = np.nan_to_num(np.diff(filled, axis=0))[:, :, None]
    along, _ = _shapes_at(change, np.arange(len(pixels)), cycles_per_sample, factors=factors)
    # A pixel on the object's edge sees the object and the background in turn: its depth jumps by their
    # distance, which is no motion along the line of sight.
    mixed = ~(spread <= np.maximum(MAX_DEPTH_SPREAD_M, MAX_DEPTH_SPREAD * median))
    along[:, mixed, :] = np.nan
    return ModeDepth(median, *focal_px, line_of_sight=along[..., 0])


def _shapes_at(
    flat: NDArray[np.floating],
    pixels: NDArray[np.intp],
    cycles_per_sample: list[float],
    *,
    factors: NDArray[np.complex64] | None = None,
) -> tuple[NDArray[np.complex64], NDArray[np.complex64]]:
    """Each pixel's tapered DFT (C components: x and y) at each frequency, phase-aligned per frequency,
    (M, P, C), and the phase factors applied (M,): the given ``factors``, or those that align each
    frequency's shape (:func:`align_phase`). Taken a block of pixels at a time, in single precision (a
    large object's whole window would not fit twice)."""
    n, channels = len(flat), flat.shape[-1]
    out = np.zeros((len(cycles_per_sample), len(pixels), channels), np.complex64)
    if not cycles_per_sample:
        return out, np.ones(0, np.complex64)
    taper = tukey(n, TAPER_ALPHA).astype(np.float64)
    phase = -2 * np.pi * np.outer(cycles_per_sample, np.arange(n))
    # Real and imaginary parts as two real products (a complex kernel would copy each block as complex).
    cosine, sine = (taper * np.cos(phase)).astype(np.float32), (taper * np.sin(phase)).astype(np.float32)
    for first in range(0, len(pixels), _SHAPE_BLOCK):
        block = pixel_columns(flat, pixels[first : first + _SHAPE_BLOCK]).astype(np.float32)
        block -= block.mean(axis=0, dtype=np.float64).astype(np.float32)
        values = (cosine @ block) + 1j * (sine @ block)
        out[:, first : first + _SHAPE_BLOCK, :] = values.reshape(len(cycles_per_sample), -1, channels)
    if factors is None:
        factors = np.array([_alignment(out[m].astype(np.complex128)) for m in range(len(out))], np.complex64)
    return out * factors[:, None, None], factors


#: A pixel whose depth spans more than this over the window (metres, or this share of its depth,
#: whichever is more) saw the object and what lies behind it in turn: its depth
#: series tells nothing of the motion along the line of sight.
MAX_DEPTH_SPREAD_M = 0.05
MAX_DEPTH_SPREAD = 0.05

#: Pixels per block of :func:`_shapes_at` (a block of a 1000-sample window is 8 MB in single precision).
_SHAPE_BLOCK = 1024
#: Columns per block of :func:`_summed_power`.
_SPECTRUM_COLUMNS = 512


def _summed_power(x: NDArray[np.float64], taper: NDArray[np.float64]) -> NDArray[np.float64]:
    """The tapered power spectrum of ``x``'s (N, C) columns summed over them, (N // 2 + 1,): a block of
    columns at a time (the whole spectrum of a 1000-sample window of 2048 pixels is 33 MB)."""
    power = np.zeros(len(x) // 2 + 1)
    for first in range(0, x.shape[1], _SPECTRUM_COLUMNS):
        spectra = np.fft.rfft(x[:, first : first + _SPECTRUM_COLUMNS] * taper[:, None], axis=0)
        power += (spectra.real**2 + spectra.imag**2).sum(axis=1)
    return power


def _series(motion: NDArray[np.floating], sample_rate_hz: float) -> NDArray[np.float64]:
    """``motion`` (N, P, 2) as (N, 2P) float64 columns, checked (a copy: the caller's array is left as it
    is)."""
    arr = np.asarray(motion)
    if arr.ndim != 3 or arr.shape[2] != 2:
        raise ParameterError(f"find_modes: motion must be (samples, pixels, 2), got {arr.shape}")
    if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise ParameterError(f"find_modes: sample_rate_hz={sample_rate_hz} must be positive")
    if arr.shape[0] < 16 or arr.shape[1] < 1:
        raise ParameterError(
            f"find_modes: {arr.shape[0]} samples of {arr.shape[1]} pixels are too few; give at least 16 "
            "samples of one pixel"
        )
    return np.array(arr.reshape(arr.shape[0], -1), dtype=np.float64)


def _lines(
    power: NDArray[np.float64], freqs: NDArray[np.float64], *, band_hz: tuple[float, float]
) -> list[tuple[float, float]]:
    """The narrow-band lines of the summed spectrum in the band: (frequency, power), strongest first.
    A line is a local maximum :data:`MIN_MODE_DB` above the running median, holding at least
    :data:`MIN_MODE_SHARE` of the strongest line's power."""
    floor = noise_floor(power, width=FLOOR_WIDTH_BINS)
    ratio = power / np.maximum(floor, 1e-300)
    found: list[tuple[float, float]] = []
    for k in range(1, len(power) - 1):
        if not (band_hz[0] <= freqs[k] <= band_hz[1]):
            continue
        if power[k] < power[k - 1] or power[k] < power[k + 1]:
            continue
        if 10 * math.log10(max(ratio[k], 1e-300)) < MIN_MODE_DB:
            continue
        found.append((float(freqs[1]) * interpolate_peak(power, k), float(power[k])))
    found.sort(key=lambda line: -line[1])
    strongest = found[0][1] if found else 0.0
    return [line for line in found if line[1] >= MIN_MODE_SHARE * strongest]


def _dfts(
    x: NDArray[np.float64], taper: NDArray[np.float64], cycles_per_sample: list[float]
) -> list[NDArray[np.complex128]]:
    """Each column's tapered DFT at each of ``cycles_per_sample``, as (P, 2) complex each, of ``x``
    (N, 2P) with its columns' means removed: two real products for every frequency at once (a complex
    kernel times real columns would first copy them as complex)."""
    if not cycles_per_sample:
        return []
    phase = -2 * np.pi * np.outer(cycles_per_sample, np.arange(len(x)))
    values = (taper * np.cos(phase)) @ x + 1j * ((taper * np.sin(phase)) @ x)
    return [np.asarray(v.reshape(-1, 2), np.complex128) for v in values]


def _sort_out(
    lines: list[tuple[float, float]], shapes: list[NDArray[np.complex128]], *, bin_hz: float
) -> tuple[list[int], list[Harmonic]]:
    """Which lines are modes (their indices, strongest first) and which are harmonics of a stronger mode
    (an integer multiple with the same shape)."""
    modal: list[int] = []
    harmonics: list[Harmonic] = []
    for i, (f, _) in enumerate(lines):
        found = None
        for j in modal:
            f0 = lines[j][0]
            order = _order(f, f0, bin_hz)
            if order is None:
                continue
            similarity = mac(shapes[i], shapes[j])
            if similarity >= HARMONIC_MAC:
                found = Harmonic(frequency_hz=f, fundamental_hz=f0, order=order, mac=similarity)
                break
        if found is None:
            modal.append(i)
        else:
            harmonics.append(found)
    return modal, harmonics


def _noisy_overtones(modes: list[Mode], *, bin_hz: float) -> tuple[list[Mode], list[Harmonic]]:
    """The modes, and those moved to the harmonics: a line at a whole multiple of a stronger mode whose
    modal coordinate the damped oscillation does not explain (noise outweighs it, per sample) is that
    mode's faint overtone (a distortion product), its shape too noisy for the MAC to show it."""
    kept: list[Mode] = []
    moved: list[Harmonic] = []
    for mode in sorted(modes, key=lambda m: -m.energy_share):
        base = next((k for k in kept if _order(mode.frequency_hz, k.frequency_hz, bin_hz) is not None), None)
        if base is None or mode.fit.snr_db >= MIN_MODE_FIT_DB:
            kept.append(mode)
            continue
        order = _order(mode.frequency_hz, base.frequency_hz, bin_hz)
        assert order is not None
        moved.append(Harmonic(mode.frequency_hz, base.frequency_hz, order, mac(mode.shape, base.shape)))
    return kept, moved


def _order(f: float, f0: float, bin_hz: float) -> int | None:
    """The harmonic order of ``f`` over ``f0`` (2 to :data:`MAX_HARMONIC_ORDER`, within the tolerance),
    or None."""
    order = round(f / f0)
    if not 2 <= order <= MAX_HARMONIC_ORDER:
        return None
    return order if abs(f - order * f0) <= max(HARMONIC_TOLERANCE * f, 1.5 * bin_hz) else None


def _modal_coordinates(x: NDArray[np.float64], shapes: list[NDArray[np.complex128]]) -> NDArray[np.float64]:
    """The modal filter: each sample's motion ``x`` (N, 2P, columns' means removed) projected on the
    modes' real shapes at once (least squares), (N, M)."""
    basis = np.stack([s.real.ravel() for s in shapes], axis=1)  # (2P, M)
    # The same least squares through the basis's QR factors: Q^T x^T is one product on x as it lies (a
    # solver given x^T itself would copy the whole window), R is M x M.
    q, r = np.linalg.qr(basis)
    coords, *_ = np.linalg.lstsq(r, q.T @ x.T, rcond=None)
    return np.asarray(coords.T, np.float64)


def _line_power(power: NDArray[np.float64], freqs: NDArray[np.float64], f: float, bin_hz: float) -> float:
    """The summed spectrum's power within two bins of ``f``."""
    near = np.abs(freqs - f) <= 2 * bin_hz
    return float(power[near].sum())


def _fit_mode(
    coord: NDArray[np.float64],
    shape: NDArray[np.complex128],
    line: tuple[float, float],
    *,
    sample_rate_hz: float,
    bin_hz: float,
    start_index: int,
    share: float,
) -> Mode:
    """One mode: its modal coordinate fitted as a damped oscillation near its line."""
    f = line[0]
    half = FIT_HALF_WIDTH_BINS * bin_hz
    fit = fit_ringdown(
        coord,
        sample_rate_hz=sample_rate_hz,
        frequency_guess_hz=f,
        start_index=start_index,
        band_hz=(max(f - half, 0.5 * bin_hz), f + half),
    )
    ringing = regime_of_fit(fit) == "ring_down"
    return Mode(
        frequency_hz=fit.frequency_hz,
        frequency_uncertainty_hz=frequency_sd_hz(fit),
        damping_ratio=fit.damping_ratio if ringing else None,
        damping_ratio_uncertainty=damping_sd(fit) if ringing else None,
        energy_share=min(share, 1.0),
        regime=regime_of_fit(fit),
        shape=shape,
        fit=fit,
    )


__all__ = [
    "HARMONIC_MAC",
    "MAX_MODE_PIXELS",
    "MIN_MODE_DB",
    "Harmonic",
    "Mode",
    "ModeDepth",
    "ObjectModeShapes",
    "ObjectModes",
    "align_phase",
    "find_modes",
    "mac",
    "mac_matrix",
    "object_modes",
]
