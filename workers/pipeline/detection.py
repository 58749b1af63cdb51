"""Which motions are objects, and why the others are not: the one place that decides.

An object is a spatially coherent region whose motion has a narrow spectral peak standing clearly above
its noise. How it moves is a finding, not a filter: its **regime** is ``ring_down`` (it decays in the
window, so its damping is measured), ``steady`` (a sustained or forced vibration: a motor, a shaker), or
``growing``. A peak is dropped only for a stated reason:

- positive evidence that it is an artefact of the camera or the light (:class:`WindowEvidence`):
  ``camera_motion`` (the picture's border moves rigidly at that frequency and the region no more than
  it), ``illumination_flicker`` (brightness oscillates at that frequency in phase along the picture's
  rows, also where nothing moves), ``codec_keyframes`` (the picture changes in pulses every K frames and
  the peak is a multiple of fps / K);
- ``harmonic``: an overtone of an object already reported, possibly folded back below the Nyquist rate
  (decided with the peaks, in :mod:`workers.pipeline.peaks` and :mod:`workers.pipeline.segmentation`);
- ``incoherent``: the region's motion is no single oscillation (narrow-band noise, a wandering
  frequency): neither does one damped oscillation explain most of its motion, nor most of its motion
  near the peak over many samples (:func:`oscillation_verdict`);
- ``uncertain`` / ``out_of_band``: its frequency is not known to a quarter of itself, or lies outside
  the analysed band (the band is law).

Every drop becomes a :class:`~workers.pipeline.model.RejectedPeak` and a quality note.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.light import FLICKER_ROWS, FLICKER_SNR, flickering_rows, floor_of
from workers.pipeline.model import ObjectMeasurement, QualityNote, RejectedPeak
from workers.pipeline.peaks import Peak, PeakPolicy, detect_peaks, find_peaks
from workers.pipeline.segmentation import Segmentation, band_mask
from workers.pipeline.spectra import PixelSpectra, background_spectrum, whitened_spectrum

if TYPE_CHECKING:
    from workers.pipeline.survey import Survey

#: The evidence that a peak is an artefact of the camera or the light (rather than no object).
ARTEFACT_EVIDENCE = ("camera_motion", "illumination_flicker", "codec_keyframes")
#: A region whose motion one damped oscillation explains this well per sample (dB) is coherent ...
MIN_RINGDOWN_SNR_DB = 3.0
#: ... as is one whose oscillation explains this fraction of its motion near the peak ...
MIN_CONCENTRATION = 0.8
#: ... with this much energy over the noise's variance (dB) summed over the window.
MIN_DETECTION_DB = 15.0
#: No object is reported whose frequency's standard uncertainty is this fraction of it or more.
MAX_RELATIVE_SD = 0.25
#: A decay over the fitted span of at least this (nepers: 5 % of the amplitude), three standard
#: uncertainties clear of zero, makes a ring-down; less is steady.
MIN_DECAY = 0.05
#: An envelope that grows by this factor over the window, clearly, is ``growing``.
MIN_GROWTH = 1.25
#: Keyframe evidence: pulses every K frames stand this many robust deviations above the typical change
#: of the whole picture ...
KEYFRAME_Z = 8.0
#: ... and (at half that) in this fraction of its blocks.
KEYFRAME_BLOCKS = 0.6
#: Camera evidence: the border's motion at the peak stands this far above its own floor ...
CAMERA_SNR = 10.0
#: ... and the region moves (in power) less than this multiple of the border's.
CAMERA_RATIO = 4.0
#: An overtone of the camera's shake left by the flow moves less than this fraction of the shake's power.
CAMERA_OVERTONE_POWER = 0.1


#: The analysis window's detectors.
WINDOW_PEAKS = PeakPolicy(
    strong_min_snr_db=10.0,
    weak_min_snr_db=3.0,
    weak_floor_bins=15,
    weak_floor_fraction=6,
    median_pixel=False,
    min_separation_bins=1.5,
    max_order=3,
    min_bins=0.0,
    peaks_per_object=2,
)
#: A survey's detectors (Welch-averaged spectra: less noisy, so a weak peak must stand higher; adjacent
#: bins of different detectors are two components, since a Hann window resolves about two).
SURVEY_PEAKS = PeakPolicy(
    strong_min_snr_db=10.0,
    weak_min_snr_db=6.0,
    weak_floor_bins=9,
    weak_floor_fraction=8,
    median_pixel=True,
    min_separation_bins=1.0,
    max_order=1_000_000,
    min_bins=2.0,
    peaks_per_object=1,
)


def candidate_peaks(
    spectra: PixelSpectra, *, band_hz: tuple[float, float], max_peaks: int
) -> tuple[list[Peak], NDArray[np.float64], NDArray[np.float64]]:
    """Peaks of the window's spectra that may be objects (:func:`detect_peaks` with
    :data:`WINDOW_PEAKS`), strongest first, harmonics folded in.

    Returns
    -------
    peaks : list of Peak
    summed : ndarray of float64, shape (F,)
        The spectrum summed over pixels.
    noise : ndarray of float64, shape (F,)
        What the summed spectrum would be over static background.
    """
    summed = spectra.power.sum(axis=1, dtype=np.float64)
    noise = background_spectrum(spectra)
    whitened, _ = whitened_spectrum(spectra, band_hz=band_hz)
    peaks = detect_peaks(
        spectra.frequencies_hz,
        summed=summed,
        background=noise,
        whitened=whitened,
        band_hz=band_hz,
        bin_hz=spectra.bin_hz,
        max_objects=max_peaks,
        policy=WINDOW_PEAKS,
    )
    return peaks, summed, noise


def _spectrum_of(series: NDArray[np.floating], nfft: int) -> NDArray[np.complex128]:
    """Complex spectrum of each column of ``series`` (time along axis 0), mean removed, zero-padded."""
    data = np.asarray(series, np.float64)
    return np.asarray(np.fft.rfft(data - data.mean(axis=0), n=nfft, axis=0))


@dataclass
class WindowEvidence:
    """What the whole picture did during the window, to tell the camera and the light from objects.

    Parameters
    ----------
    frequencies_hz : ndarray of float64, shape (F,)
        The spectra's frequencies (their transform length ``nfft``).
    nfft : int
    brightness : ndarray of float32, shape (N + 1, B, B), or None
        Mean grey level of B x B blocks of each frame.
    frame_change : ndarray of float32, shape (N, B, B), or None
        Mean absolute grey-level change of each block between consecutive frames.
    border_px : ndarray of float32, shape (N, 2), or None
        Median motion of the picture's border in each flow map (before any removal), grid pixels.
    camera_removed : bool
        Whether that motion was removed from the flow as the camera's.
    ring_pixels : ndarray of intp, shape (R,), or None
        The border's pixels on the flow grid (flattened), and ``ring_textured`` which of them have
        texture.
    """

    frequencies_hz: NDArray[np.float64]
    nfft: int
    brightness: NDArray[np.float32] | None = None
    frame_change: NDArray[np.float32] | None = None
    border_px: NDArray[np.float32] | None = None
    camera_removed: bool = False
    ring_pixels: NDArray[np.intp] | None = None
    ring_textured: NDArray[np.bool_] | None = None
    _cache: dict[str, object] = field(default_factory=dict, repr=False)

    @property
    def sample_rate_hz(self) -> float:
        """Rate of the samples the spectra are of, Hz."""
        return self.bin_hz * self.nfft

    @property
    def bin_hz(self) -> float:
        return float(self.frequencies_hz[1] - self.frequencies_hz[0]) if len(self.frequencies_hz) > 1 else 1.0

    def _bins(self, peak: Peak) -> NDArray[np.bool_]:
        return band_mask(self.frequencies_hz, peak, bin_hz=self.bin_hz, band_bins=max(1.5, peak.width_bins))

    def _near(self, frequency_hz: float, width_bins: float) -> NDArray[np.bool_]:
        return np.abs(self.frequencies_hz - frequency_hz) <= max(1.5, width_bins) * self.bin_hz

    # -- the light ---------------------------------------------------------------------------------
    def _brightness_spectra(self) -> tuple[NDArray[np.complex128], NDArray[np.float64]] | None:
        if self.brightness is None or len(self.brightness) < 9:
            return None
        if "brightness" not in self._cache:
            # Frame-to-frame change, aligned with the flow maps (and free of slow lighting drift).
            change = np.diff(self.brightness.astype(np.float64), axis=0)
            self._cache["brightness"] = (_spectrum_of(change, self.nfft), self.brightness.mean(axis=0))
        found = self._cache["brightness"]
        assert isinstance(found, tuple)
        return found

    def flicker(self, frequency_hz: float, width_bins: float, coverage: NDArray[np.float64]) -> str | None:
        """Why a peak is illumination flicker, or None.

        Most rows of the picture's blocks brighten and darken in phase at the peak (see
        :mod:`workers.pipeline.light`); where the region leaves part of the picture out, the brightness
        must oscillate there too: brightness that oscillates where nothing moves.

        Parameters
        ----------
        frequency_hz, width_bins : float
            The peak.
        coverage : ndarray of float64, shape (B, B)
            Fraction of each brightness block covered by the region.
        """
        spectra = self._brightness_spectra()
        if spectra is None:
            return None
        spec, level = spectra
        half_width = max(1.5, width_bins) * self.bin_hz
        rows, k = flickering_rows(spec, self.frequencies_hz, frequency_hz, half_width)
        if rows < FLICKER_ROWS:
            return None
        near = self._near(frequency_hz, width_bins)
        outside = coverage < 0.1
        where = " across the whole picture"
        if outside.sum() >= 8:
            block_power = np.abs(spec) ** 2
            block_snr = block_power[near].max(axis=0) / floor_of(block_power)[near].max(axis=0)
            if float(np.median(block_snr[outside])) < FLICKER_SNR:
                return None  # the brightness changes only where the region moves: its own texture
            where = ", also over the static background"
        frames = 0 if self.brightness is None else len(self.brightness) - 1
        # The spectrum is of frame-to-frame changes: a sine of amplitude a changes by 2 a sin(pi f / fs).
        gain = 2 * abs(math.sin(math.pi * float(self.frequencies_hz[k]) / self.sample_rate_hz))
        amplitude = 2 * float(np.abs(spec[k].mean(axis=1)).mean()) / max(frames, 1) / max(gain, 1e-6)
        relative = amplitude / max(float(level.mean()), 1e-9)
        return (
            f"{frequency_hz:.4g} Hz is illumination flicker: the picture's brightness oscillates at it in "
            f"phase along {rows * 100:.0f} % of its rows (by {relative * 100:.2g} % of the mean "
            f"level){where}, without motion of its own"
        )

    # -- the codec ---------------------------------------------------------------------------------
    def keyframe_period(self) -> int | None:
        """The period K (frames) of pulses in the frame-to-frame change of the whole picture, or None.

        A codec's keyframes (and some cameras' exposure steps) change the whole picture every K frames:
        the change between consecutive frames then stands out at one phase modulo K, in most blocks of
        the picture at once (a fast vibration makes the change pulse too, but only where it moves).
        """
        if "keyframes" in self._cache:
            found = self._cache["keyframes"]
            return found if isinstance(found, int) and found > 0 else None
        period: int | None = None
        blocks = None if self.frame_change is None else np.asarray(self.frame_change, np.float64)
        if blocks is not None and len(blocks) >= 24:
            series = blocks.reshape(len(blocks), -1)
            scores = {
                k: z
                for k in range(2, len(series) // 3 + 1)
                if (z := _pulse_score(series.mean(axis=1), k)) > 0
            }
            if scores:
                # Every multiple of the period folds the pulses as well: the period is the shortest that
                # does nearly as well as the best.
                best = max(scores.values())
                k = min(k for k, z in scores.items() if z >= 0.8 * best)
                everywhere = np.mean(
                    [_pulse_score(series[:, j], k, z_min=KEYFRAME_Z / 2) > 0 for j in range(series.shape[1])]
                )
                if everywhere >= KEYFRAME_BLOCKS:
                    period = k
        self._cache["keyframes"] = period if period is not None else 0
        return period

    def keyframes(self, frequency_hz: float, width_bins: float, fps: float) -> str | None:
        """Why a peak is a codec keyframe pulse (a multiple of fps / K), or None."""
        period = self.keyframe_period()
        if period is None:
            return None
        base = fps / period
        slack = max(1.5, width_bins) * self.bin_hz
        order = max(1, round(frequency_hz / base))
        if base < 3 * slack or abs(frequency_hz - order * base) > slack:
            return None  # not on the comb, or its teeth too close to tell
        return (
            f"{frequency_hz:.4g} Hz is a codec keyframe pulse: the whole picture changes every {period} "
            f"frames ({base:.4g} Hz), and this is {'it' if order == 1 else f'its {order}th multiple'}"
        )

    # -- the camera --------------------------------------------------------------------------------
    def _border_power(self) -> NDArray[np.float64] | None:
        """Power spectrum of the border's median motion (u and v summed), or None."""
        if self.border_px is None or len(self.border_px) < 9:
            return None
        if "border" not in self._cache:
            spec = _spectrum_of(self.border_px, self.nfft)
            self._cache["border"] = (np.abs(spec) ** 2).sum(axis=1)
        power = self._cache["border"]
        assert isinstance(power, np.ndarray)
        return power

    def camera_frequencies(self) -> list[tuple[float, float]]:
        """Frequencies at which the border moves (its own clear peaks), with their band power, strongest
        first: the camera's shake when the border moved as a whole."""
        power = self._border_power()
        if power is None:
            return []
        if "camera_peaks" not in self._cache:
            band = (self.frequencies_hz[1], self.frequencies_hz[-1])
            found = find_peaks(
                self.frequencies_hz, power, band_hz=band, noise=floor_of(power), min_snr_db=10.0
            )
            self._cache["camera_peaks"] = [
                (p.frequency_hz, float(power[self._near(p.frequency_hz, p.width_bins)].sum())) for p in found
            ]
        peaks = self._cache["camera_peaks"]
        assert isinstance(peaks, list)
        return peaks

    def camera(
        self,
        frequency_hz: float,
        width_bins: float,
        *,
        region_power: float,
        ring_power: NDArray[np.float32] | None,
        fps: float,
    ) -> str | None:
        """Why a peak is the camera's own motion, or None.

        The camera moving at the peak's frequency moves the picture's border rigidly. That is evidence
        against an object only if the region moves no more than the border does (``CAMERA_RATIO`` in
        power): a compressor shaking the floor shakes the camera too, but its own parts move more. The
        overtones of a camera's shake (the second and third, also folded back below the Nyquist rate)
        that the flow leaves behind where it was removed are its motion too, when the region moves far
        less than the camera did (``CAMERA_OVERTONE_POWER`` of its power).

        Parameters
        ----------
        region_power : float
            The region's typical (median) band power at the peak, after any removal of the camera's
            motion (the same units as the per-pixel spectra).
        ring_power : ndarray of float32, shape (R,), or None
            Band power of each border pixel at the peak (before removal it shows whether the border
            moved as a whole; after removal it is what is left).
        fps : float
            Rate of the samples, Hz.
        """
        power = self._border_power()
        if power is None:
            return None
        near = self._near(frequency_hz, width_bins)
        camera = float(power[near].sum())
        floor = float(floor_of(power)[near].max()) * max(int(near.sum()), 1)
        if camera < CAMERA_SNR * floor:
            return self._camera_overtone(frequency_hz, width_bins, region_power=region_power, fps=fps)
        if not self.camera_removed:
            # The border's median moved at the peak; did the whole border move, or an object in it?
            if ring_power is None or self.ring_textured is None:
                return None
            textured = ring_power[self.ring_textured] if self.ring_textured.any() else ring_power
            if float(np.mean(textured >= 0.5 * camera)) < 0.85:
                return None
            moved_more = region_power >= CAMERA_RATIO * camera
        else:
            # The camera's motion was removed: the region's power is what it moved relative to the scene.
            moved_more = region_power >= camera / CAMERA_RATIO
        if moved_more:
            return None
        n = len(self.border_px) if self.border_px is not None else 1
        amplitude = 2 * math.sqrt(camera) / n
        return (
            f"{frequency_hz:.4g} Hz is camera motion: the picture's border moves rigidly at it "
            f"({amplitude:.2g} px per frame) and the region no more than the border"
        )

    def _camera_overtone(
        self, frequency_hz: float, width_bins: float, *, region_power: float, fps: float
    ) -> str | None:
        if not self.camera_removed:
            return None
        slack = self.bin_hz
        for shake_hz, shake_power in self.camera_frequencies():
            for order in range(2, 4):
                multiple = order * shake_hz
                image = abs(multiple - fps * round(multiple / fps))
                if abs(image - frequency_hz) <= slack and region_power < CAMERA_OVERTONE_POWER * shake_power:
                    folded = "" if image == multiple else f" (folded back from {multiple:.4g} Hz)"
                    return (
                        f"{frequency_hz:.4g} Hz is camera motion: overtone {order} of the camera's shake at "
                        f"{shake_hz:.4g} Hz{folded}, left where that shake was removed, weaker than it"
                    )
        return None


def _pulse_score(change: NDArray[np.float64], period: int, *, z_min: float = KEYFRAME_Z) -> float:
    """How far the pulses of ``change`` every ``period`` samples stand out (robust deviations above its
    median), or 0 when they do not all stand out (a few large changes sharing a phase by chance)."""
    median = float(np.median(change))
    mad = 1.4826 * float(np.median(np.abs(change - median))) + 1e-9
    usable = len(change) - len(change) % period
    folded = change[:usable].reshape(-1, period)
    pulses = folded[:, int(np.argmax(folded.mean(axis=0)))]
    z = (float(np.median(pulses)) - median) / mad
    if z >= z_min and float(np.mean(pulses > median + 3 * mad)) >= 0.8:
        return z
    return 0.0


def block_coverage(labels: NDArray[np.integer], label: int, blocks: int) -> NDArray[np.float64]:
    """Fraction of each of ``blocks`` x ``blocks`` blocks of the picture covered by ``label``.

    Returns
    -------
    ndarray of float64, shape (blocks, blocks)
    """
    import cv2

    mask = (labels == label).astype(np.float32)
    return np.asarray(cv2.resize(mask, (blocks, blocks), interpolation=cv2.INTER_AREA), np.float64)


def reject_artefacts(
    seg: Segmentation,
    spectra: PixelSpectra,
    evidence: WindowEvidence,
    *,
    band_hz: tuple[float, float],
) -> tuple[Segmentation, list[RejectedPeak]]:
    """Drop the peaks with positive evidence of being the camera's or the light's (see
    :class:`WindowEvidence`); the remaining objects are relabelled 1, 2, ...

    Returns
    -------
    Segmentation
    list of RejectedPeak
    """
    if not seg.peaks:
        return seg, []
    keep: list[int] = []
    rejected: list[RejectedPeak] = []
    blocks = 0 if evidence.brightness is None else evidence.brightness.shape[1]
    for i, peak in enumerate(seg.peaks):
        region = (seg.labels == i + 1).ravel()
        band_power = seg.band_power[i].ravel()
        region_power = float(np.median(band_power[region])) if region.any() else 0.0
        ring_power = None if evidence.ring_pixels is None else band_power[evidence.ring_pixels]
        width = peak.width_bins
        found: tuple[str, str] | None = None
        if blocks:
            why = evidence.flicker(peak.frequency_hz, width, block_coverage(seg.labels, i + 1, blocks))
            if why:
                found = ("illumination_flicker", why)
        if found is None:
            why = evidence.keyframes(peak.frequency_hz, width, spectra.fps)
            if why:
                found = ("codec_keyframes", why)
        if found is None:
            why = evidence.camera(
                peak.frequency_hz, width, region_power=region_power, ring_power=ring_power, fps=spectra.fps
            )
            if why:
                found = ("camera_motion", why)
        if found is None:
            keep.append(i)
        else:
            rejected.append(RejectedPeak(peak.frequency_hz, found[1], found[0]))
    if len(keep) == len(seg.peaks):
        return seg, rejected
    labels = np.zeros_like(seg.labels)
    for new, old in enumerate(keep, start=1):
        labels[seg.labels == old + 1] = new
    return (
        Segmentation(
            labels=labels,
            peaks=[seg.peaks[i] for i in keep],
            band_power=seg.band_power[keep],
            noise_power=seg.noise_power[keep],
        ),
        rejected,
    )


def oscillation_verdict(obj: ObjectMeasurement, *, band_hz: tuple[float, float]) -> RejectedPeak | None:
    """Why a measured region is not reported as an object, or None when it is one.

    It is one when its motion is a single coherent oscillation: one damped oscillation explains
    ``MIN_RINGDOWN_SNR_DB`` more than the rest per sample (a clear ring-down), or it explains
    ``MIN_CONCENTRATION`` of the motion near the peak with ``MIN_DETECTION_DB`` over the noise across the
    window (a weak but steady vibration, or a slow swing of few periods); its frequency must lie inside
    the band and be known to better than ``MAX_RELATIVE_SD`` of itself.
    """
    f = obj.eigenfrequency_hz
    snr = obj.snr_db if obj.snr_db is not None else -math.inf
    detection = obj.detection_db if obj.detection_db is not None else -math.inf
    concentration = obj.concentration if obj.concentration is not None else 0.0
    if not (band_hz[0] <= f <= band_hz[1]):
        return RejectedPeak(
            f,
            f"{f:.4g} Hz lies outside the analysed band [{band_hz[0]:.3g}, {band_hz[1]:.3g}] Hz",
            "out_of_band",
        )
    sustained = concentration >= MIN_CONCENTRATION and detection >= MIN_DETECTION_DB
    if snr < MIN_RINGDOWN_SNR_DB and not sustained:
        return RejectedPeak(
            f,
            f"{f:.4g} Hz: the region's motion is no single coherent oscillation (one oscillation explains "
            f"{concentration * 100:.0f} % of its motion near the peak, {snr:.1f} dB per sample, "
            f"{detection:.1f} dB over the window)",
            "incoherent",
        )
    sd = obj.eigenfrequency_sd_hz
    if sd is None or not math.isfinite(sd) or sd >= MAX_RELATIVE_SD * f:
        return RejectedPeak(
            f,
            f"{f:.4g} Hz is too uncertain to report (± {sd:.3g} Hz, a quarter of itself or more)",
            "uncertain",
        )
    return None


def judge_objects(
    objects: list[ObjectMeasurement],
    seg: Segmentation,
    *,
    band_hz: tuple[float, float],
    fps: float,
    bin_hz: float,
    harmonic_tolerance: float = 0.02,
    shared_power: float = 0.25,
    max_order: int = 10,
    max_folded_order: int = 5,
) -> dict[int, RejectedPeak]:
    """The objects (by id) that are not reported, and why: :func:`oscillation_verdict`, or an overtone of
    a stronger object on the same pixels.

    A region ringing at n times (n up to ``max_order``; or, folded back below the Nyquist rate, at
    |n f - m fps| for n up to ``max_folded_order``) the frequency of a stronger object, whose pixels
    also move at that object's own frequency with at least ``shared_power`` of their power at their own,
    is its overtone. Two objects an octave apart (two strings) ring on pixels of their own and are both
    kept; a neighbour's spectral leakage is far weaker than that.

    Parameters
    ----------
    objects : list of ObjectMeasurement
        Strongest first; ``objects[i].id`` is label ``i + 1`` of ``seg``.
    seg : Segmentation
        Their labels and band powers on the flow grid.
    band_hz : (low, high)
    fps, bin_hz : float
        Rate of the samples and width of one bin, Hz.
    harmonic_tolerance : float
        Relative tolerance of an overtone's frequency (or a bin and a half, whichever is wider).
    shared_power, max_order, max_folded_order : float, int, int

    Returns
    -------
    dict of int to RejectedPeak
    """
    out: dict[int, RejectedPeak] = {}
    kept: list[ObjectMeasurement] = []
    for obj in objects:
        verdict = oscillation_verdict(obj, band_hz=band_hz)
        if verdict is None:
            verdict = _overtone(
                obj,
                kept,
                seg,
                fps=fps,
                bin_hz=bin_hz,
                tolerance=harmonic_tolerance,
                shared_power=shared_power,
                orders=(max_order, max_folded_order),
            )
        if verdict is None:
            kept.append(obj)
        else:
            out[obj.id] = verdict
    return out


def _overtone(
    obj: ObjectMeasurement,
    stronger: list[ObjectMeasurement],
    seg: Segmentation,
    *,
    fps: float,
    bin_hz: float,
    tolerance: float,
    shared_power: float,
    orders: tuple[int, int],
) -> RejectedPeak | None:
    f = obj.eigenfrequency_hz
    region = seg.labels == obj.id
    own = obj.id - 1
    if not region.any() or not 0 <= own < len(seg.peaks):
        return None
    own_power = float(np.median(seg.band_power[own][region]))
    slack = max(tolerance * f, 1.5 * bin_hz)
    for base in stronger:
        index = base.id - 1
        if not 0 <= index < len(seg.peaks):
            continue
        f0 = base.eigenfrequency_hz
        for order in range(2, orders[0] + 1):
            multiple = order * f0
            folded = abs(multiple - fps * round(multiple / fps))
            if folded != multiple and order > orders[1]:
                continue
            if abs(f - folded) > slack:
                continue
            if float(np.median(seg.band_power[index][region])) < shared_power * own_power:
                continue  # its pixels do not move at the stronger object's frequency: an object of its own
            how = "" if folded == multiple else f", folded back below the Nyquist rate from {multiple:.4g} Hz"
            return RejectedPeak(
                f,
                f"{f:.4g} Hz is overtone {order} of the object at {f0:.4g} Hz, on the same pixels{how}",
                "harmonic",
            )
    return None


def folded_image(
    survey: Survey, frequency_hz: float, *, sample_rate_hz: float, tolerance_hz: float
) -> float | None:
    """The survey peak above the Nyquist rate of ``sample_rate_hz`` (a window analysed every k-th frame)
    whose image folds back onto ``frequency_hz``, or None.

    Parameters
    ----------
    frequency_hz : float
        A frequency seen in the strided window.
    sample_rate_hz : float
        The window's sample rate (the clip's rate over its frame step).
    tolerance_hz : float
        How close the image must fall.
    """
    nyquist = sample_rate_hz / 2
    for peak in survey.peaks:
        f = peak.frequency_hz
        if f <= nyquist:
            continue
        image = abs(f - sample_rate_hz * round(f / sample_rate_hz))
        if abs(image - frequency_hz) <= tolerance_hz:
            return f
    return None


def folded_verdicts(
    objects: list[ObjectMeasurement], survey: Survey | None, *, sample_rate_hz: float, frame_step: int
) -> dict[int, RejectedPeak]:
    """Objects of a window analysed every k-th frame that are only the folded image of a faster motion
    the survey of the whole clip saw (and no motion the survey saw at the object's own frequency)."""
    if survey is None or frame_step <= 1:
        return {}
    out: dict[int, RejectedPeak] = {}
    tolerance = 1.5 * survey.bin_hz
    for obj in objects:
        f = obj.eigenfrequency_hz
        if any(abs(p.frequency_hz - f) <= tolerance for p in survey.peaks):
            continue
        source = folded_image(survey, f, sample_rate_hz=sample_rate_hz, tolerance_hz=tolerance)
        if source is not None:
            out[obj.id] = RejectedPeak(
                f,
                f"{f:.4g} Hz is the image of the {source:.4g} Hz motion the survey of the whole clip saw, "
                f"folded back because every {frame_step}th frame was analysed; give start_frame and frames "
                "to analyse it at the full rate",
                "harmonic",
            )
    return out


def clip_regime(obj: ObjectMeasurement, survey: Survey | None, *, clip_s: float) -> str | None:
    """A steady-looking object's regime over the whole clip: a lightly damped ring-down (a struck fork)
    decays too little within the analysed window to measure, but the survey of the whole clip sees its
    energy fall. Sets the object's damping from that decay and returns ``"ring_down"``; None when the
    survey shows no clear decay (or cannot tell, another peak being too close).

    Parameters
    ----------
    clip_s : float
        Seconds the survey spanned.
    """
    if survey is None or obj.regime != "steady":
        return None
    found = survey.decay_at(obj.eigenfrequency_hz)
    if found is None:
        return None
    sigma, sigma_sd = found
    if not (sigma * clip_s >= 2 * MIN_DECAY and sigma >= 3 * sigma_sd):
        return None
    omega = 2 * math.pi * obj.eigenfrequency_hz
    obj.damping_ratio = sigma / omega
    obj.damping_ratio_sd = sigma_sd / omega
    obj.null_reasons = [r for r in obj.null_reasons if not r.startswith("damping:")]
    obj.notes.append(
        "damping from the decay of its energy over the whole clip "
        f"({math.exp(-sigma * clip_s) * 100:.0f} % of the amplitude left after {clip_s:.3g} s): the "
        "analysed window shows too little of it"
    )
    obj.regime = "ring_down"
    return obj.regime


def regime_of(obj: ObjectMeasurement, *, decay: float, decay_sd: float) -> str:
    """``ring_down``, ``steady`` or ``growing``: how the object's oscillation evolved over the window.

    Parameters
    ----------
    obj : ObjectMeasurement
        With its sliding-window ``ringdown`` when it has one (for growth).
    decay, decay_sd : float
        The fitted envelope's decay over the fitted span and its standard uncertainty, nepers.
    """
    if decay >= MIN_DECAY and decay >= 3 * decay_sd:
        return "ring_down"
    ring = obj.ringdown
    if ring is not None and len(ring.amplitude) >= 4:
        amp = np.asarray(ring.amplitude, np.float64)
        ok = amp > 0
        if ok.sum() >= 4:
            t = np.asarray(ring.times_s, np.float64)[ok]
            slope, _ = np.polyfit(t, np.log(amp[ok]), 1)
            span = float(t[-1] - t[0])
            if slope * span >= math.log(MIN_GROWTH) and float(amp[ok][-1]) > float(amp[ok][0]):
                return "growing"
    return "steady"


def drop_objects(
    objects: list[ObjectMeasurement],
    labels: NDArray[np.uint16],
    dropped: dict[int, RejectedPeak],
    quality: list[QualityNote],
) -> tuple[list[ObjectMeasurement], NDArray[np.uint16]]:
    """Remove the objects named in ``dropped`` (by id), noting each; renumber the rest 1, 2, ... in
    objects and labels."""
    for rejected in dropped.values():
        quality.append(QualityNote("artefact_peak", f"{rejected.reason}; not reported as an object", "info"))
    if not dropped:
        return objects, labels
    kept = [o for o in objects if o.id not in dropped]
    relabelled = np.zeros_like(labels)
    for new_id, o in enumerate(kept, start=1):
        relabelled[labels == o.id] = new_id
        o.id = new_id
    return kept, relabelled


__all__ = [
    "ARTEFACT_EVIDENCE",
    "MIN_RINGDOWN_SNR_DB",
    "SURVEY_PEAKS",
    "WINDOW_PEAKS",
    "WindowEvidence",
    "block_coverage",
    "candidate_peaks",
    "clip_regime",
    "drop_objects",
    "folded_image",
    "folded_verdicts",
    "judge_objects",
    "oscillation_verdict",
    "regime_of",
    "reject_artefacts",
]
