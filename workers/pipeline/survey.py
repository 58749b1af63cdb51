"""A cheap first look at a whole clip: when does something move, and at which frequencies.

A long clip (thousands of frames) cannot be analysed as one buffer of full-resolution flow, and its first
few hundred frames may show nothing but the hand that strikes the object. :func:`survey_motion` streams
the whole clip once on a heavily downscaled grey grid, computes DIS flow between consecutive frames and
keeps only summaries whose size does not depend on the clip's length:

- a Welch-averaged motion spectrum: per-pixel power of signed flow in Hann-windowed segments with 50 %
  overlap, summed over the pixels as power (parts moving in anti-phase add up instead of cancelling),
  also whitened by each pixel's own noise (weak motion spread over many pixels) and at the median pixel
  (what the static background sees: camera shake, flicker and codec pulses are everywhere);
- each segment's summed spectrum, merged pairwise when there are too many, so the time course of each
  frequency is known;
- the motion energy per block of frames, merged the same way;
- the largest per-frame motion, which bounds how many frames may be skipped between flow maps;
- a local spectrum: per bin, the power a small share of the pixels sees (the 99th percentile over the
  pixels of their whitened power, the most over the segments), whose lines are motion that the summed
  spectra hide (a small object, a fast mode of a larger one that rings down within a segment): the stride
  keeps them.

:func:`plan_window` then chooses the main analysis window: from where the strongest ring-down starts,
long enough for enough periods of the lowest confidently seen frequency, within a budget of flow maps,
analysing every k-th frame when every frequency seen is far below the Nyquist rate.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.camera import CAMERA_MOTION_MIN_PX, CameraRing
from workers.pipeline.detection import SURVEY_PEAKS
from workers.pipeline.errors import ParameterError
from workers.pipeline.light import FLICKER_ROWS, block_brightness, flickering_rows
from workers.pipeline.model import BAND_NYQUIST_FRACTION, Survey
from workers.pipeline.peaks import Peak, PeakSpectra, detect_peaks, noise_floor

#: Floats held by the survey's segment buffer (flow of every survey pixel over one Welch segment).
SURVEY_BUFFER_FLOATS = 8_000_000
#: Stored segment spectra and energy blocks; beyond this neighbours are merged pairwise.
MAX_SEGMENTS = 256
MAX_BLOCKS = 2048
#: A peak whose whitened power at the median pixel exceeds this (power over the pixel's own noise) is seen
#: over the static background too: camera motion, flicker or codec pulses rather than an object.
GLOBAL_MEDIAN_SNR = 2.5
#: The local spectrum (see :meth:`_WelchAccumulator.local_spectrum`) is read at this quantile over the
#: survey's pixels: a motion on 1 % of the picture (a small object, one mode of a larger one) shows there
#: even when the summed spectra hide it among the still pixels.
LOCAL_QUANTILE = 0.99
#: A maximum of the local spectrum this far above its running median (dB, over 31 bins) is a local line:
#: the window's stride keeps it below the Nyquist rate (:func:`workers.pipeline.window.plan_window`). Noise
#: of real footage and codecs stood at most 8.6 dB above it (the shared forks and compressor); a cantilever's
#: third mode at a quarter of a pixel, 10.5-13.4 dB.
LOCAL_LINE_DB = 10.0


def survey_factor(height: int, width: int, *, segment_frames: int, width_px: int = 96) -> int:
    """Integer downscale factor from ``height`` x ``width`` frames to the survey grid: about ``width_px``
    wide, fewer pixels when the segment is long, so that the segment buffer holds at most
    ``SURVEY_BUFFER_FLOATS`` floats. (An integer factor keeps area averaging exact and fast.)

    Returns
    -------
    int
        The grid is ``(height // factor, width // factor)``.
    """
    pixels = SURVEY_BUFFER_FLOATS // (2 * max(segment_frames, 1))
    target = min(width_px, math.sqrt(pixels * width / max(height, 1)))
    factor = max(1, math.ceil(width / max(target, 1.0)))
    # Never below 16 x 12 survey pixels (or the frame itself when smaller).
    while factor > 1 and (width // factor < min(16, width) or height // factor < min(12, height)):
        factor -= 1
    return factor


def segment_length(frames: int) -> int:
    """Welch segment length (flow samples) for a clip of ``frames``: a power of two near a quarter of the
    clip, from 64 to 1024, and never more than the clip gives."""
    target = max(frames // 4, 1)
    length = 1 << max(6, math.ceil(math.log2(target)))
    length = min(length, 1024)
    while length > 16 and length > frames - 1:
        length //= 2
    return length


def survey_motion(
    grays: Iterable[NDArray[np.uint8]],
    *,
    fps: float,
    total_frames: int,
    first_frame: int = 0,
    width_px: int = 96,
    segment_frames: int | None = None,
    min_snr_db: float = 6.0,
    band_hz: tuple[float, float] | None = None,
) -> Survey:
    """Stream a clip once and summarise its motion with bounded memory.

    Parameters
    ----------
    grays : iterable of ndarray of uint8, shape (H, W)
        The clip's frames in order, grey (any size; they are area-averaged down to the survey grid).
    fps : float
        Frame rate, Hz.
    total_frames : int
        Frames ``grays`` will yield (sets the Welch segment length); fewer is accepted.
    first_frame : int
        Clip index of the first frame (for ``segment_starts``).
    width_px : int
        Survey grid width at most (fewer for long segments, see :func:`survey_factor`).
    segment_frames : int, optional
        Welch segment length in flow samples; default :func:`segment_length` of ``total_frames``.
    min_snr_db : float
        A peak of the whitened Welch spectrum must stand this far above its running median.
    band_hz : (low, high), optional
        The band the user asked for: peaks in it are sought there on their own as well, so that stronger
        motions elsewhere never crowd them out (the band chooses where to look).

    Returns
    -------
    Survey

    Raises
    ------
    ParameterError
        On a non-positive ``fps``, fewer than 17 frames, or frames that change size.
    """
    length = _checked_length(fps, total_frames, segment_frames)
    iterator = iter(grays)
    try:
        first = next(iterator)
    except StopIteration:
        raise ParameterError("survey: the clip yielded no frames") from None
    height, width = first.shape[:2]
    factor = survey_factor(height, width, segment_frames=length, width_px=width_px)
    flows = _SurveyFlow(first, factor)
    acc = _WelchAccumulator(
        length=length,
        pixels=flows.pixels,
        fps=fps,
        first_frame=first_frame,
        scale=1.0 / factor,
        ring=flows.ring,
    )
    flows.feed(iterator, acc)
    if acc.samples < 16:
        raise ParameterError(f"survey: the clip yielded only {acc.samples + 1} frames; analyse it whole")
    acc.finish()
    return _summary(acc, flows, min_snr_db=min_snr_db, band_hz=band_hz)


def _summary(
    acc: _WelchAccumulator, flows: _SurveyFlow, *, min_snr_db: float, band_hz: tuple[float, float] | None
) -> Survey:
    """The survey from its finished accumulator and flow: the Welch spectra, their peaks, which of those
    are seen over the whole picture or are lighting flicker, and the segments' energy."""
    power, whitened, median_snr, background = acc.averages()
    fps, bin_hz = acc.fps, acc.fps / acc.length
    spectra = (power, background, whitened, median_snr)
    peaks = _survey_peaks(acc.frequencies_hz, spectra, bin_hz=bin_hz, min_snr_db=min_snr_db, band_hz=band_hz)
    starts, span, seg_power = acc.segments_stored()
    flicker = _flicker(np.asarray(flows.brightness, np.float32), fps=fps, peaks=peaks, bin_hz=bin_hz)
    return Survey(
        fps=fps,
        first_frame=acc.first_frame,
        frames=acc.samples + 1,
        grid_shape=flows.shape,
        grid_scale=1.0 / flows.factor,
        segment_frames=acc.length,
        frequencies_hz=acc.frequencies_hz,
        power=power,
        whitened=whitened,
        median_snr=median_snr,
        segments=acc.count,
        segment_starts=starts,
        segment_span=span,
        segment_power=seg_power,
        block_frames=acc.blocks.size,
        block_energy=acc.blocks.values(),
        max_step_px=acc.steps.quantile(0.9),
        peaks=peaks,
        global_peaks_hz=[p.frequency_hz for p in peaks if median_snr[p.bin] > GLOBAL_MEDIAN_SNR],
        flicker_hz=flicker,
        local_lines_hz=_local_lines(acc, median_snr=median_snr, flicker_hz=flicker),
    )


def _local_lines(
    acc: _WelchAccumulator, *, median_snr: NDArray[np.float64], flicker_hz: list[float]
) -> list[float]:
    """Frequencies of the local spectrum's lines (see :data:`LOCAL_LINE_DB`), in the band the survey
    searches, that the still background does not share (its median pixel's whitened power is noise's) and
    that are not lighting flicker or its harmonics."""
    local, freqs = acc.local_spectrum(), acc.frequencies_hz
    if len(local) < 5 or float(local.max()) <= 0:
        return []
    bin_hz = float(freqs[1] - freqs[0])
    stand = local / np.maximum(noise_floor(local, width=31), 1e-30)
    inner = np.arange(1, len(local) - 1)
    is_max = (local[inner] >= local[inner - 1]) & (local[inner] >= local[inner + 1])
    lines = inner[
        is_max
        & (stand[inner] >= 10 ** (LOCAL_LINE_DB / 10))
        & (median_snr[inner] <= GLOBAL_MEDIAN_SNR)
        & (freqs[inner] >= 2 * bin_hz)
        & (freqs[inner] <= BAND_NYQUIST_FRACTION * float(freqs[-1]))
    ]

    def flicker(f: float) -> bool:
        return any(abs(f / g - round(f / g)) * g <= 1.5 * bin_hz for g in flicker_hz if g > 0)

    return [float(freqs[k]) for k in lines if not flicker(float(freqs[k]))]


def _checked_length(fps: float, total_frames: int, segment_frames: int | None) -> int:
    """The Welch segment length, once the rate and the clip's length are known to allow a survey."""
    if not (math.isfinite(fps) and fps > 0):
        raise ParameterError(f"survey: fps={fps} must be a positive number of frames per second")
    if total_frames < 17:
        raise ParameterError(
            f"survey: a clip of {total_frames} frames is too short to survey; analyse it whole"
        )
    length = segment_frames or segment_length(total_frames)
    if length < 16 or length % 2:
        raise ParameterError(f"survey: segment_frames={length} must be an even number >= 16")
    return length


class _SurveyFlow:
    """The survey's flow: each frame area-averaged by an integer ``factor`` onto the survey grid, its
    block brightness kept, and the flow from the frame before (DIS, ultrafast)."""

    def __init__(self, first: NDArray[np.uint8], factor: int) -> None:
        import cv2

        self.size = first.shape[:2]
        self.factor = factor
        self.shape = (self.size[0] // factor, self.size[1] // factor)
        self.pixels = self.shape[0] * self.shape[1]
        self._dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
        self._dis.setFinestScale(0)  # the grid is already coarse: do not skip its finest level
        self._dis.setPatchStride(6)  # ... but sparser patches keep it about as cheap as decoding a frame
        self.ring = CameraRing(self.shape, every=2)
        self._previous = self._small(first)
        self.ring.set_texture(self._previous)
        self.brightness = [block_brightness(self._previous)]

    def _small(self, gray: NDArray[np.uint8]) -> NDArray[np.uint8]:
        import cv2

        height, width = self.size
        if gray.shape[:2] != (height, width):
            raise ParameterError(
                f"survey: a frame is {gray.shape[1]}x{gray.shape[0]}, the clip started at "
                f"{width}x{height}; re-encode the clip at one size"
            )
        if self.factor == 1:
            return np.ascontiguousarray(gray)
        h, w = self.shape
        crop = gray[: h * self.factor, : w * self.factor]
        return np.asarray(cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA), np.uint8)

    def _flow_to(self, gray: NDArray[np.uint8]) -> NDArray[np.float32]:
        nxt = self._small(gray)
        flow = np.asarray(self._dis.calc(self._previous, nxt, None), np.float32)
        self._previous = nxt
        self.brightness.append(block_brightness(nxt))
        return flow

    def feed(self, grays: Iterator[NDArray[np.uint8]], acc: _WelchAccumulator) -> None:
        """The flow of every frame of ``grays`` added to ``acc``, in frame order. Downscaling and flow run
        in one worker thread while this one decodes the next frames and accumulates; OpenCV and the
        decoder release the GIL."""
        pending: deque[Future[NDArray[np.float32]]] = deque()
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="survey") as pool:
            try:
                for gray in grays:
                    pending.append(pool.submit(self._flow_to, gray))
                    if len(pending) >= 3:
                        acc.add(pending.popleft().result())
                while pending:
                    acc.add(pending.popleft().result())
            finally:
                for job in pending:
                    job.cancel()


def _survey_peaks(
    freqs: NDArray[np.float64],
    spectra: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    *,
    bin_hz: float,
    min_snr_db: float,
    band_hz: tuple[float, float] | None,
) -> list[Peak]:
    """The survey's confident peaks in the Welch ``spectra`` (summed power, background, whitened, median
    pixel's whitened): over the whole band, and within the user's band on their own as well, so that
    stronger motions elsewhere never crowd them out (the band chooses where to look)."""
    power, background, whitened, median_snr = spectra
    # Peaks are searched from the first bin so that a low peak's left flank counts for its prominence;
    # those below two bins (unresolved from the mean and slow drift) are dropped afterwards.
    band = (0.5 * bin_hz, BAND_NYQUIST_FRACTION * float(freqs[-1]))
    policy = dataclasses.replace(SURVEY_PEAKS, weak_min_snr_db=min_snr_db)

    def peaks_in(searched: tuple[float, float]) -> list[Peak]:
        return detect_peaks(
            PeakSpectra(
                frequencies_hz=freqs,
                bin_hz=bin_hz,
                summed=power,
                background=background,
                whitened=whitened,
                median_snr=median_snr,
            ),
            band_hz=searched,
            policy=policy,
        )

    peaks = peaks_in(band)
    if band_hz is not None:
        inside = (max(band[0], band_hz[0]), min(band[1], band_hz[1]))
        if inside[1] - inside[0] >= 3 * bin_hz:
            extra = peaks_in(inside)
            peaks += [p for p in extra if all(abs(p.frequency_hz - q.frequency_hz) > bin_hz for q in peaks)]
    return peaks


def _flicker(brightness: NDArray[np.float32], *, fps: float, peaks: list[Peak], bin_hz: float) -> list[float]:
    """The peaks (their frequencies) that are lighting flicker (see :mod:`workers.pipeline.light`): the
    main analysis rejects them, and the window's frame step need not keep them below the Nyquist rate.

    Parameters
    ----------
    brightness : ndarray of float32, shape (T, B, B)
        Mean grey level of B x B blocks of each frame.
    """
    if len(brightness) < 32 or not peaks:
        return []
    n = len(brightness) - 1
    freqs = np.asarray(np.fft.rfftfreq(n, d=1.0 / fps), np.float64)
    change = np.diff(brightness.astype(np.float64), axis=0)
    spec = np.fft.rfft(change - change.mean(axis=0), axis=0)
    return [
        p.frequency_hz
        for p in peaks
        if flickering_rows(spec, freqs, p.frequency_hz, max(1.0, p.width_bins) * bin_hz)[0] >= FLICKER_ROWS
    ]


class _BlockEnergy:
    """Per-frame values averaged over blocks of frames; pairs merge when there are too many blocks."""

    def __init__(self) -> None:
        self.size = 1
        self._done: list[float] = []
        self._sum = 0.0
        self._n = 0

    def add(self, value: float) -> None:
        self._sum += value
        self._n += 1
        if self._n == self.size:
            self._done.append(self._sum / self._n)
            self._sum, self._n = 0.0, 0
            if len(self._done) >= MAX_BLOCKS:
                self._done = [(a + b) / 2 for a, b in zip(self._done[::2], self._done[1::2], strict=True)]
                self.size *= 2

    def values(self) -> NDArray[np.float64]:
        tail = [self._sum / self._n] if self._n else []
        return np.asarray(self._done + tail, np.float64)


class _Quantiles:
    """Quantiles of a stream of positive values from a fixed log-spaced histogram (1e-4 to 1e4)."""

    def __init__(self, bins_per_decade: int = 40) -> None:
        self._edges = np.logspace(-4, 4, 8 * bins_per_decade + 1)
        self._counts = np.zeros(len(self._edges) + 1, np.int64)

    def add(self, value: float) -> None:
        self._counts[int(np.searchsorted(self._edges, value))] += 1

    def quantile(self, q: float) -> float:
        total = int(self._counts.sum())
        if total == 0:
            return 0.0
        i = int(np.searchsorted(np.cumsum(self._counts), q * total))
        return float(self._edges[min(i, len(self._edges) - 1)])


class _WelchAccumulator:
    """Per-pixel Welch spectra of signed flow, kept as sums over pixels and segments."""

    def __init__(
        self, *, length: int, pixels: int, fps: float, first_frame: int, scale: float, ring: CameraRing
    ) -> None:
        self.ring = ring
        self.blocks = _BlockEnergy()
        self.steps = _Quantiles()
        self._stats_done = 0
        self.length = length
        self.hop = length // 2
        self.pixels = pixels
        self.fps = fps
        self.first_frame = first_frame
        self.scale = scale
        self.buffer = np.zeros((length, pixels * 2), np.float32)
        self.camera = np.zeros((length, 2), np.float32)
        self.taper = np.hanning(length + 2)[1:-1].astype(np.float32)
        self.frequencies_hz = np.fft.rfftfreq(length, d=1.0 / fps).astype(np.float64)
        n_freq = len(self.frequencies_hz)
        self.count = 0
        self.samples = 0
        self._power = np.zeros(n_freq)
        self._whitened = np.zeros(n_freq)
        self._median = np.zeros(n_freq)
        self._background = np.zeros(n_freq)
        self._local: NDArray[np.float32] | None = None
        self._starts: list[int] = []
        self._seg: list[NDArray[np.float32]] = []
        self._merge = 1
        self._open = 0

    def add(self, flow: NDArray[np.float32]) -> None:
        """Store one flow map (h, w, 2); statistics run every hop, a segment every hop once full."""
        self.buffer[self.samples % self.length] = flow.ravel()
        self.samples += 1
        if self.samples - self._stats_done >= self.hop:
            self._stats()
        if self.samples >= self.length and (self.samples - self.length) % self.hop == 0:
            self._segment(self.samples - self.length, self.length)

    def _stats(self) -> None:
        """Per-frame camera motion (median of the border ring), motion energy and fastest motion of the
        frames stored since the last call, vectorised over them."""
        n = self.samples - self._stats_done
        if n <= 0:
            return
        order = (np.arange(self._stats_done, self.samples) % self.length).astype(np.intp)
        data = self.buffer[order].reshape(n, self.pixels, 2)
        camera = self.ring.motions(data)
        self.camera[order] = camera
        moved = data - camera[:, None, :]
        sq = moved[..., 0] ** 2 + moved[..., 1] ** 2
        top = max(0, int(0.99 * self.pixels) - 1)
        fastest = np.sqrt(np.partition(sq, top, axis=1)[:, top]) / self.scale
        energy = sq.mean(axis=1) / self.scale**2
        for e, v in zip(energy.tolist(), fastest.tolist(), strict=True):
            self.blocks.add(e)
            self.steps.add(v)
        self._stats_done = self.samples

    def finish(self) -> None:
        """Statistics of the last frames; a clip shorter than one segment is transformed whole."""
        self._stats()
        if self.count == 0:
            n = self.samples - self.samples % 2
            self.length = n
            self.hop = n // 2
            self.taper = np.hanning(n + 2)[1:-1].astype(np.float32)
            self.frequencies_hz = np.fft.rfftfreq(n, d=1.0 / self.fps).astype(np.float64)
            n_freq = len(self.frequencies_hz)
            self._power = np.zeros(n_freq)
            self._whitened = np.zeros(n_freq)
            self._median = np.zeros(n_freq)
            self._background = np.zeros(n_freq)
            self._local = None
            self._segment(0, n)

    def _segment(self, first_sample: int, n: int) -> None:
        from scipy import fft

        order = (np.arange(first_sample, first_sample + n) % self.buffer.shape[0]).astype(np.intp)
        camera = self.camera[order]
        # Remove the camera's motion only when it really moves: subtracting a still camera's jitter
        # would add the border's noise to every pixel.
        moving = self.ring.moves_as_whole(
            self.buffer[order].reshape(n, self.pixels, 2),
            camera,
            min_rms_px=CAMERA_MOTION_MIN_PX * self.scale,
        )
        # Transformed in blocks of pixels (time in order, mean removed, tapered): the complex spectrum
        # of the whole buffer would double it.
        power = np.empty((n // 2 + 1, self.pixels), np.float32)
        chunk = 4096
        taper = self.taper[:, None]
        for c in range(0, 2 * self.pixels, chunk):
            data = self.buffer[order, c : c + chunk]
            if moving:
                data = (data.reshape(n, -1, 2) - camera[:, None, :]).reshape(n, -1)
            data = (data - data.mean(axis=0)) * taper
            spec = fft.rfft(data, axis=0, workers=2)
            power[:, c // 2 : (c + spec.shape[1]) // 2] = (
                (spec.real**2 + spec.imag**2).reshape(len(spec), -1, 2).sum(axis=2)
            )
        freqs = self.frequencies_hz
        band = (freqs >= 2.5 * self.fps / n) & (freqs <= BAND_NYQUIST_FRACTION * self.fps / 2)
        if band.sum() < 3:
            band = freqs > 0
        in_band = np.flatnonzero(band)
        in_band = in_band[:: max(1, len(in_band) // 64)]  # the noise level from at most 64 bins
        median = np.median(power[in_band], axis=0)
        scale = np.where(median > 0, 1.0 / np.maximum(median, 1e-30), 0.0).astype(np.float32)
        summed = power.sum(axis=1, dtype=np.float64)
        self._power += summed
        self._whitened += (power @ scale).astype(np.float64)
        local = np.quantile(power * scale[None, :], LOCAL_QUANTILE, axis=1).astype(np.float32)
        self._local = local if self._local is None else np.maximum(self._local, local)
        step = max(1, power.shape[1] // 1000)
        sample = power[:, ::step]
        self._median += np.median(sample * scale[::step], axis=1) * math.log(2)
        self._background += np.percentile(sample, 20, axis=1) * power.shape[1]
        self.count += 1
        self._add_stored(self.first_frame + first_sample, summed.astype(np.float32))

    def _add_stored(self, start: int, summed: NDArray[np.float32]) -> None:
        """Keep each segment's spectrum; groups of ``_merge`` consecutive segments are added up, and
        when ``MAX_SEGMENTS`` full groups are stored neighbouring pairs merge (the groups double)."""
        if self._seg and self._open < self._merge:
            self._seg[-1] = self._seg[-1] + summed
            self._open += 1
        else:
            self._starts.append(start)
            self._seg.append(summed)
            self._open = 1
        if len(self._seg) >= MAX_SEGMENTS and self._open == self._merge:
            self._starts = self._starts[::2]
            self._seg = [a + b for a, b in zip(self._seg[::2], self._seg[1::2], strict=True)]
            self._merge *= 2
            self._open = self._merge

    def segments_stored(self) -> tuple[NDArray[np.int64], int, NDArray[np.float32]]:
        """(first frame of each stored group, frames a group spans, summed power (S, F))."""
        span = self.length + (self._merge - 1) * self.hop
        power = np.asarray(self._seg, np.float32).reshape(len(self._seg), -1)
        return np.asarray(self._starts, np.int64), span, power

    def local_spectrum(self) -> NDArray[np.float64]:
        """Per bin, the most over the segments of the :data:`LOCAL_QUANTILE` over the pixels of their
        whitened power (F,)."""
        if self._local is None:
            return np.zeros(len(self.frequencies_hz))
        return self._local.astype(np.float64)

    def averages(
        self,
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        m = max(self.count, 1)
        return self._power / m, self._whitened / m, self._median / m, self._background / m


__all__ = [
    "segment_length",
    "survey_factor",
    "survey_motion",
]
