"""What the whole picture says about a window, before any object is measured: the scan statistic, the
significant peaks with the regions they move, and the evidence of the camera, the light and the codec.

:func:`front_of_look` makes it from the first pass (:mod:`workers.pipeline.look`, a coarse grid over the
whole frame); :func:`front_of_buffers` from a window's own whole-frame flow (a live stream, which computes
its flow as frames arrive). Either way one :class:`Front` goes to
:func:`workers.pipeline.analysis.analyze_window`, which measures the candidates on the fine grid.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.artefacts import WindowEvidence
from workers.pipeline.camera import CameraRing
from workers.pipeline.codec import flow_level
from workers.pipeline.confidence import Confidence, flow_confidence
from workers.pipeline.detection import Candidates, find_candidates
from workers.pipeline.errors import AnalysisError
from workers.pipeline.flow import as_float32, pixel_columns, to_float16
from workers.pipeline.look import LOOK_WIDTH_PX, Look, frame_noise
from workers.pipeline.roi import Roi
from workers.pipeline.significance import MAX_FALSE_ALARM, MIN_BINS, MotionScan, motion_scan
from workers.pipeline.spectra import PixelSpectra, pixel_spectra
from workers.pipeline.stream import FrameBuffers
from workers.pipeline.tracking import CoarseView
from workers.pipeline.window import default_band


@dataclass(frozen=True)
class Front:
    """The whole picture's findings about a window.

    Attributes
    ----------
    band_hz : (low, high)
    scan : MotionScan
    candidates : Candidates
    evidence : WindowEvidence
        On the scan's grid.
    ring : CameraRing
        The picture's border on that grid.
    grid_factor : float
        Input pixels per pixel of that grid.
    scan_confidence : Confidence
        Of that grid.
    flow : ndarray of float32 or float16, shape (N, h', w', 2)
        The picture's flow on that grid (area-averaging lowers a codec's noise: a thin object moving a
        fraction of a pixel may stand out more clearly here than at full resolution): of the whole
        picture (float32), or of the box :meth:`keeping_flow_of` kept (float16).
    flow_origin : (row, column)
        Where ``flow``'s first pixel lies on the grid.
    ring_flow : ndarray of float16, shape (N, R, 2), or None
        The flow of the ring's pixels (``ring.pixels``), kept with the box (None while ``flow`` is the
        whole picture's).
    """

    band_hz: tuple[float, float]
    scan: MotionScan
    candidates: Candidates
    evidence: WindowEvidence
    ring: CameraRing
    grid_factor: float
    scan_confidence: Confidence
    flow: NDArray[np.float32] | NDArray[np.float16]
    flow_origin: tuple[int, int] = (0, 0)
    ring_flow: NDArray[np.float16] | None = None

    @functools.cached_property
    def spectra(self) -> PixelSpectra:
        """Per-pixel spectra of the whole picture's flow on the scan's grid (what a still window's result
        shows): computed on first use, and only before :meth:`keeping_flow_of` (a window with candidates
        needs the powers of a few pixels only, :meth:`band_powers`)."""
        if self.ring_flow is not None:
            raise ValueError("Front.spectra: the whole picture's flow was let go (keeping_flow_of)")
        return pixel_spectra(np.asarray(self.flow, np.float32), sample_rate_hz=self.scan.sample_rate_hz)

    def keeping_flow_of(self, roi: Roi) -> Front:
        """This front with its flow kept over ``roi``'s box only (rounded out to the grid): once the region
        that moves is chosen, the rest of the picture's flow is never read again (a 1000-frame window's
        coarse flow is 128 MiB at 640 x 420), and every object measured lies in the box."""
        f = self.grid_factor
        h, w = self.flow.shape[1:3]
        y0, x0 = int(roi.y // f), int(roi.x // f)
        y1 = min(h, math.ceil((roi.y + roi.height) / f))
        x1 = min(w, math.ceil((roi.x + roi.width) / f))
        if roi.whole_frame:
            y0, x0, y1, x1 = 0, 0, h, w
        # copies in half precision (rounding 2^-11 of a value, far below the flow's noise): the whole
        # picture's flow can be let go, and a 1000-frame window's box holds 37 MiB instead of 74 (the
        # whole picture of a 3000-frame window 192 instead of 384)
        kept = to_float16(self.flow[:, y0:y1, x0:x1])
        ring = to_float16(pixel_columns(self.flow, self.ring.pixels)).reshape(len(self.flow), -1, 2)
        return replace(self, flow=kept, flow_origin=(y0, x0), ring_flow=ring)

    def coarse_view(self, region: NDArray[np.bool_]) -> CoarseView:
        """An object on this grid (``region``, a mask of the whole grid) for
        :func:`~workers.pipeline.tracking.track_object`: the kept flow, the region and the confidence
        over the kept box."""
        y0, x0 = self.flow_origin
        h, w = self.flow.shape[1:3]
        rows, cols = slice(y0, y0 + h), slice(x0, x0 + w)
        c = self.scan_confidence
        box = Confidence(
            c.jxx[rows, cols], c.jxy[rows, cols], c.jyy[rows, cols], c.weight[rows, cols], c.noise_energy
        )
        return CoarseView(self.flow, region[rows, cols], box, self.grid_factor)

    def band_powers(
        self, frequency_hz: float, width_bins: float, region: NDArray[np.bool_]
    ) -> tuple[float, NDArray[np.float32]]:
        """The region's median band power at a peak, and the ring pixels' (the camera evidence's inputs),
        on the scan's grid (a region's pixels outside the kept flow's box do not count)."""
        n = len(self.flow)
        y0, x0 = self.flow_origin
        h, w = self.flow.shape[1:3]
        inside = region[y0 : y0 + h, x0 : x0 + w]
        ring: NDArray[np.floating[Any]]
        if self.ring_flow is not None:
            ring = self.ring_flow
        else:
            ring = pixel_columns(self.flow, self.ring.pixels).reshape(n, -1, 2)
        own = pixel_columns(self.flow, np.flatnonzero(inside.ravel())).reshape(n, -1, 2)
        half_width, rate = max(1.5, width_bins), self.scan.sample_rate_hz
        power = _band_power(own, frequency_hz, half_width, rate)
        region_power = float(np.median(power)) if power.size else 0.0
        return region_power, np.asarray(_band_power(ring, frequency_hz, half_width, rate), np.float32)

    def detection(self) -> dict[str, float]:
        """The calibration's figures for the result."""
        cal = self.scan.calibration
        return {
            "location": cal.location,
            "scale": cal.scale,
            "bins_fitted": float(cal.bins_fitted),
            "bins_searched": float(cal.bins_searched),
            "max_false_alarm": MAX_FALSE_ALARM,
        }


def _band_power(
    series: NDArray[np.floating[Any]], frequency_hz: float, half_width_bins: float, sample_rate_hz: float
) -> NDArray[np.float64]:
    """Each pixel's power (u and v summed) in the bins of its mean-removed spectrum (zero-padded to the
    fast length, as :func:`~workers.pipeline.spectra.pixel_spectra` takes it) within ``half_width_bins``
    of ``frequency_hz``, summed: (P,) from ``series`` (N, P, 2), by a direct transform at those bins only
    (a few of the window's hundreds)."""
    from workers.pipeline.fft import fast_length

    n = len(series)
    nfft = fast_length(n)
    freqs = np.fft.rfftfreq(nfft, d=1.0 / sample_rate_hz)
    bins = np.flatnonzero(np.abs(freqs - frequency_hz) <= half_width_bins * sample_rate_hz / nfft)
    flat = as_float32(series.reshape(n, -1))  # BLAS: float32 (the kept flow is float16)
    if flat.shape[1] == 0 or bins.size == 0:
        return np.zeros(flat.shape[1] // 2)
    phase = 2 * np.pi * np.outer(np.arange(n), bins) / nfft
    mean = flat.mean(axis=0, dtype=np.float64)
    power = np.zeros(flat.shape[1])
    for basis in (np.cos(phase), np.sin(phase)):
        part = flat.T @ basis.astype(np.float32) - np.outer(mean, basis.sum(axis=0))
        power += (part**2).sum(axis=1)
    return np.asarray(power.reshape(-1, 2).sum(axis=1), np.float64)


@dataclass(frozen=True)
class _Picture:
    """The whole picture's series on one grid: its flow, mean grey frame and border ring, block
    brightness and its change, the border's motion in the grid's pixels, whether the camera's motion was
    removed, and the input pixels per grid pixel."""

    flow: NDArray[np.float32]
    mean_gray: NDArray[np.float32]
    ring: CameraRing
    brightness: NDArray[np.float32] | None
    frame_change: NDArray[np.float32] | None
    border_px: NDArray[np.float32] | None
    camera_removed: bool
    grid_factor: float


def _front(
    picture: _Picture,
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    max_objects: int,
    asserted: int = 0,
) -> Front:
    """The findings from the whole ``picture``: the artefact evidence and the scan."""
    from workers.pipeline.fft import fast_length

    flow = picture.flow
    nfft = fast_length(len(flow))
    evidence = WindowEvidence(
        frequencies_hz=np.fft.rfftfreq(nfft, d=1.0 / sample_rate_hz).astype(np.float64),
        nfft=nfft,
        brightness=picture.brightness,
        frame_change=picture.frame_change,
        border_px=picture.border_px,
        camera_removed=picture.camera_removed,
        ring_pixels=picture.ring.pixels,
        ring_textured=picture.ring.textured,
    )
    change = picture.frame_change if picture.frame_change is not None else np.zeros((0, 1, 1), np.float32)
    confidence = flow_confidence(picture.mean_gray, frame_noise=frame_noise(change))
    scanned = _scanned_band(len(flow), sample_rate_hz=sample_rate_hz, band_hz=band_hz)
    scan = motion_scan(flow, confidence, sample_rate_hz=sample_rate_hz, band_hz=scanned, search_hz=band_hz)
    candidates = find_candidates(scan, band_hz=band_hz, max_objects=max_objects, asserted=asserted)
    if evidence.flow_level is None:
        evidence.flow_level = still_flow_level(flow, confidence, candidates)
    return Front(band_hz, scan, candidates, evidence, picture.ring, picture.grid_factor, confidence, flow)


def _scanned_band(
    samples: int, *, sample_rate_hz: float, band_hz: tuple[float, float]
) -> tuple[float, float]:
    """The band the scan covers: the band the user narrowed is searched, the whole band a window of
    ``samples`` flow maps shows calibrates the statistic; a short window (a live stream that stopped
    early) calibrates on every frequency it holds."""
    default_lo, default_hi = default_band(sample_rate_hz, samples)
    scanned = (min(band_hz[0], default_lo), max(band_hz[1], default_hi))
    window_hz = np.fft.rfftfreq(samples, d=1.0 / sample_rate_hz)[1:]
    if np.count_nonzero((window_hz >= scanned[0]) & (window_hz <= scanned[1])) >= MIN_BINS:
        return scanned
    if len(window_hz) < MIN_BINS:
        raise AnalysisError(
            f"the window of {samples} flow maps is too short to tell motion from noise (it holds "
            f"{len(window_hz)} frequencies, the detection needs {MIN_BINS}); analyse more frames"
        )
    return (float(window_hz[0]), float(window_hz[-1]))


def still_flow_level(
    flow: NDArray[np.float32], confidence: Confidence, candidates: Candidates
) -> NDArray[np.float32] | None:
    """The level of the flow's noise in each map over the picture's still, textured parts (away from every
    candidate's region): where a codec's cycle of frame types shows, and an object's own motion does not
    (:func:`workers.pipeline.codec.frame_pattern_period`). None when too little of the picture is
    still and textured (a surface filling it)."""
    moving = np.zeros(confidence.shape, np.uint8)
    for region in candidates.regions:
        moving |= region.astype(np.uint8)
    moving = cv2.dilate(moving, np.ones((5, 5), np.uint8))
    textured = confidence.weight >= 0.5
    still = textured & (moving == 0)
    if still.sum() < STILL_SHARE * max(int(textured.sum()), 1):
        return None
    return flow_level(flow, still)


#: The flow noise's level is measured where at least this share of the textured picture is still.
STILL_SHARE = 0.2


def front_of_look(
    look: Look,
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    max_objects: int,
    asserted: int = 0,
) -> Front:
    """The whole picture's findings from the first pass.

    Parameters
    ----------
    look : Look
    sample_rate_hz : float
        Rate of the look's flow maps.
    band_hz : (low, high)
    max_objects : int
    asserted : int
        How many objects the user's excitations name (see
        :func:`~workers.pipeline.detection.find_candidates`).
    """
    picture = _Picture(
        flow=look.flow,
        mean_gray=look.mean_gray,
        ring=look.ring,
        brightness=look.brightness,
        frame_change=look.frame_change,
        border_px=look.border_px,
        camera_removed=look.camera_removed,
        grid_factor=look.input_px_per_grid_px,
    )
    return _front(
        picture, sample_rate_hz=sample_rate_hz, band_hz=band_hz, max_objects=max_objects, asserted=asserted
    )


def front_of_buffers(
    buffers: FrameBuffers,
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    max_objects: int,
    asserted: int = 0,
) -> Front:
    """The whole picture's findings from a window's own whole-frame flow (a live stream's).

    Parameters
    ----------
    buffers : FrameBuffers
        Flow over the whole frame (``roi`` None), with the grey frames when kept.
    sample_rate_hz : float
    band_hz : (low, high)
    max_objects : int
    asserted : int
        How many objects the user's excitations name (see
        :func:`~workers.pipeline.detection.find_candidates`).
    """
    flow, factor = _on_look_grid(buffers)
    h, w = flow.shape[1:3]
    if buffers.gray is not None:
        sampled = buffers.gray[:: max(1, len(buffers.gray) // 32)]
        mean_full = np.zeros(buffers.gray.shape[1:], np.float32)
        for frame in sampled:  # summed in place: no float copy of the frames
            cv2.accumulate(frame, mean_full)
        mean_full /= np.float32(len(sampled))
        mean = np.asarray(cv2.resize(mean_full, (w, h), interpolation=cv2.INTER_AREA), np.float32)
    else:
        mean = cv2.cvtColor(buffers.first_rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
        mean = np.asarray(cv2.resize(mean, (w, h), interpolation=cv2.INTER_AREA), np.float32)
    ring = CameraRing((h, w))
    ring.set_texture(np.clip(mean, 0, 255).astype(np.uint8))
    border = None if buffers.border_px is None else buffers.border_px / np.float32(factor)
    picture = _Picture(
        flow=flow,
        mean_gray=mean,
        ring=ring,
        brightness=buffers.brightness,
        frame_change=buffers.frame_change,
        border_px=border,
        camera_removed=buffers.camera_removed,
        grid_factor=buffers.first_rgb.shape[1] / w,
    )
    return _front(
        picture, sample_rate_hz=sample_rate_hz, band_hz=band_hz, max_objects=max_objects, asserted=asserted
    )


def look_factor(grid_width: int) -> int:
    """The integer factor that brings a flow grid ``grid_width`` wide to about
    :data:`~workers.pipeline.look.LOOK_WIDTH_PX` wide: the first pass's grid, where a codec's and a
    sensor's noise average down and the scan costs a factor squared less (a live stream's final analysis
    scanned its 320 px flow grid: 1 s of its latency)."""
    return max(1, grid_width // LOOK_WIDTH_PX)


def pool_map(flow_map: NDArray[np.float32], factor: int, *, out: NDArray[np.float32]) -> None:
    """One flow map (h, w, 2) area-averaged by ``factor`` into ``out`` (h // factor, w // factor, 2), in
    the pooled grid's pixels."""
    hh, ww = out.shape[:2]
    cv2.resize(flow_map[: hh * factor, : ww * factor], (ww, hh), dst=out, interpolation=cv2.INTER_AREA)
    out /= np.float32(factor)


def _on_look_grid(buffers: FrameBuffers) -> tuple[NDArray[np.float32], int]:
    """The window's flow on the look's grid (:func:`look_factor`, :func:`pool_map`) and the factor: the
    buffers' ``pooled_flow`` when the stream pooled each map as it arrived."""
    flow = buffers.flow
    n, h, w = flow.shape[:3]
    factor = look_factor(w)
    if factor == 1:
        return flow, 1
    if buffers.pooled_flow is not None:
        return buffers.pooled_flow, factor
    out = np.empty((n, h // factor, w // factor, 2), np.float32)
    for i in range(n):
        pool_map(flow[i], factor, out=out[i])
    return out, factor


def coarse_share(front: Front, mask_frame: NDArray[np.bool_]) -> NDArray[np.float32]:
    """The share of each pixel of the front's grid that a mask of the whole frame holds (as floats: a
    uint8 mask would be rounded, a grid pixel in only where most of its pixels are, and a thin object one
    or two input pixels wide nowhere)."""
    h, w = front.scan.grid_shape
    small = cv2.resize(mask_frame.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return np.asarray(small, np.float32)


def coarse_region(front: Front, mask_frame: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """A mask of the whole frame on the front's grid (a pixel is in when any of its input pixels is)."""
    return np.asarray(coarse_share(front, mask_frame) > 0, bool)


__all__ = [
    "Front",
    "coarse_region",
    "coarse_share",
    "front_of_buffers",
    "front_of_look",
    "look_factor",
    "pool_map",
    "still_flow_level",
]
