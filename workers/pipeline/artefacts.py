"""Evidence that a peak is an artefact of the camera, the light or the codec rather than an object.

:class:`WindowEvidence` holds what the whole picture did during the window (the brightness and change of
its blocks, the motion of its border) and answers, for one frequency, whether the camera moved rigidly at
it (``camera_motion``), the lighting flickered at it (``illumination_flicker``), or a codec's keyframes
pulse at it (``codec_keyframes``, from what :mod:`workers.pipeline.codec` finds);
:func:`artefact_verdict` applies it to a measured object, which must also not be localised on a region.
The numbers behind each verdict go into the rejected peak's ``figures``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.codec import (
    frame_pattern_period,
    keyframe_period,
    region_keyframe_period,
)
from workers.pipeline.light import FLICKER_ROWS, FLICKER_SNR, flickering_rows, floor_of
from workers.pipeline.model import RejectedPeak
from workers.pipeline.peaks import Peak, PeakCriteria, find_peaks, folded
from workers.pipeline.segmentation import band_mask

#: Camera evidence: the border's motion at the peak stands this far above its own floor ...
CAMERA_SNR = 10.0
#: ... and the region moves (in power) less than this multiple of the border's.
CAMERA_RATIO = 4.0
#: An overtone of the camera's shake left by the flow moves less than this fraction of the shake's power.
CAMERA_OVERTONE_POWER = 0.1
#: A peak is on the keyframe comb when it lies within this many of its standard uncertainties of a tooth ...
KEYFRAME_SD = 2.0
#: ... and the teeth stand at least this many bins apart (closer, every frequency is near one).
KEYFRAME_TEETH_BINS = 4.5
#: A codec's pattern spans two or three groups of pictures when its pulses' heights differ this much.
KEYFRAME_PATTERN_RATIO = 1.3
#: The flow of a flickering picture (a rolling shutter's bands sweep across the texture) holds the
#: flicker's overtones up to this order, folded back below the Nyquist rate: the 5th of 100 Hz at 240 fps
#: is 20 Hz ...
MAX_FLICKER_ORDER = 6
#: ... and an object lit by it moves at n f_L +- f_o (n up to this) at most this share of its amplitude.
MAX_MIXING_ORDER = 2
MIXING_SHARE = 0.2
#: A motion with at least this share of the picture's excess power at its frequency inside its region is
#: localised: an object, not the light, the codec or the camera (they move the whole picture).
LOCALISED = 0.5


@dataclass(frozen=True)
class Finding:
    """One piece of artefact evidence: its kind, its sentence and its numbers."""

    evidence: str
    reason: str
    figures: dict[str, float]


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
    flow_level : ndarray of float32, shape (N,), or None
        Mean absolute flow of the picture's textured pixels in each map
        (:func:`~workers.pipeline.codec.flow_level`).
    """

    frequencies_hz: NDArray[np.float64]
    nfft: int
    brightness: NDArray[np.float32] | None = None
    frame_change: NDArray[np.float32] | None = None
    border_px: NDArray[np.float32] | None = None
    camera_removed: bool = False
    ring_pixels: NDArray[np.intp] | None = None
    ring_textured: NDArray[np.bool_] | None = None
    flow_level: NDArray[np.float32] | None = None
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

    def flicker(
        self, frequency_hz: float, width_bins: float, coverage: NDArray[np.float64]
    ) -> Finding | None:
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
        return Finding(
            "illumination_flicker",
            f"{frequency_hz:.4g} Hz is illumination flicker: the picture's brightness oscillates at "
            f"{float(self.frequencies_hz[k]):.3g} Hz in "
            f"phase along {rows * 100:.0f} % of its rows (by {relative * 100:.2g} % of the mean "
            f"level){where}, without motion of its own",
            {"rows_in_phase": float(rows), "relative_amplitude": relative},
        )

    def flicker_frequencies(self) -> list[float]:
        """Frequencies at which the picture's light flickers: lines of its blocks' brightness standing
        ``FLICKER_SNR`` above their floor, in phase along ``FLICKER_ROWS`` of its block rows."""
        spectra = self._brightness_spectra()
        if spectra is None:
            return []
        if "flicker_lines" not in self._cache:
            spec, _ = spectra
            power = (np.abs(spec) ** 2).reshape(len(spec), -1).sum(axis=1)
            band = (float(self.frequencies_hz[1]), float(self.frequencies_hz[-1]))
            found = find_peaks(
                self.frequencies_hz,
                power,
                band_hz=band,
                noise=floor_of(power),
                criteria=PeakCriteria(min_snr_db=10 * math.log10(FLICKER_SNR)),
            )
            self._cache["flicker_lines"] = [
                p.frequency_hz
                for p in found
                if flickering_rows(spec, self.frequencies_hz, p.frequency_hz, 1.5 * self.bin_hz)[0]
                >= FLICKER_ROWS
            ]
        lines = self._cache["flicker_lines"]
        assert isinstance(lines, list)
        return lines

    # -- the codec ---------------------------------------------------------------------------------
    def keyframe_period(self) -> int | None:
        """The period K (frames) of pulses in the frame-to-frame change of the whole picture, or None
        (:func:`~workers.pipeline.codec.keyframe_period`)."""
        if "keyframes" not in self._cache:
            self._cache["keyframes"] = keyframe_period(self.frame_change) or 0
        found = self._cache["keyframes"]
        return found if isinstance(found, int) and found > 0 else None

    def keyframe_pattern(self) -> int:
        """How many groups of pictures (1, 2 or 3) the codec's pattern spans: its pulses every K frames
        differ in height from one group to the next (a rate control that alternates), so the picture
        repeats every 2 K or 3 K frames, and its lines stand at multiples of fps / (m K)."""
        period = self.keyframe_period()
        if period is None or self.frame_change is None:
            return 1
        change = np.asarray(self.frame_change, np.float64).reshape(len(self.frame_change), -1).mean(axis=1)
        phase = int(np.argmax(change[: len(change) - len(change) % period].reshape(-1, period).mean(axis=0)))
        pulses = change[phase::period]
        for groups in (2, 3):
            usable = len(pulses) - len(pulses) % groups
            if usable < 2 * groups:
                continue
            heights = np.median(pulses[:usable].reshape(-1, groups), axis=0)
            if float(heights.max()) >= KEYFRAME_PATTERN_RATIO * max(float(heights.min()), 1e-9):
                return groups
        return 1

    def frame_pattern(self) -> int | None:
        """The period m (frames, 2 to :data:`~workers.pipeline.codec.MAX_PATTERN_FRAMES`) of a pattern in
        the level of the whole picture's flow noise, or None
        (:func:`~workers.pipeline.codec.frame_pattern_period`)."""
        if "pattern" not in self._cache:
            self._cache["pattern"] = frame_pattern_period(self.flow_level) or 0
        found = self._cache["pattern"]
        return found if isinstance(found, int) and found > 0 else None

    def region_keyframes(
        self, coverage: NDArray[np.float64], frequency_hz: float, sd_hz: float, sample_rate_hz: float
    ) -> Finding | None:
        """Why a peak is a codec's redraw of one region, or None: the region's own change (the blocks it
        covers, ``coverage`` as :func:`block_coverage` gives it) pulses every K frames
        (:func:`~workers.pipeline.codec.region_keyframe_period`) and the peak lies on that comb, as
        :meth:`keyframes` tests.

        A codec at a low bit rate may redraw only part of the picture at its keyframes (a flat wall's
        shading, say) and re-use every other block unchanged: the whole picture does not pulse, but the
        region does, and the comb's teeth there are a localised "motion" at n fps / K. A moving object's
        region changes in every frame, which is no pulse.
        """
        if self.frame_change is None or coverage.shape != self.frame_change.shape[1:]:
            return None
        period = region_keyframe_period(self.frame_change, coverage)
        if period is None:
            return None
        comb = (
            sample_rate_hz / period,
            f"the object's region changes only every {period} frames",
            {"keyframe_period_frames": float(period), "pattern_frames": float(period)},
        )
        return self._on_comb(frequency_hz, sd_hz, [comb])

    def keyframes(self, frequency_hz: float, sd_hz: float, sample_rate_hz: float) -> Finding | None:
        """Why a peak is a codec's pulse, or None: the whole picture changes every K frames (keyframes,
        :meth:`keyframe_period`) or its flow's noise follows a pattern of m frames (the types of frames a
        codec cycles through, :meth:`frame_pattern`), and the peak lies at n fps / (g K) (g:
        :meth:`keyframe_pattern`, the groups of pictures a codec's pattern spans) or n fps / m within
        ``KEYFRAME_SD`` standard uncertainties ``sd_hz`` of its frequency, the comb's teeth at least
        :data:`KEYFRAME_TEETH_BINS` bins apart (closer, any peak is near one)."""
        combs: list[tuple[float, str, dict[str, float]]] = []
        period = self.keyframe_period()
        if period is not None:
            for groups in sorted({1, self.keyframe_pattern()}):
                every = (
                    f"{period} frames"
                    if groups == 1
                    else f"{period} frames in a pattern of {groups * period}"
                )
                combs.append(
                    (
                        sample_rate_hz / (groups * period),
                        f"the whole picture changes every {every}",
                        {"keyframe_period_frames": float(period), "pattern_frames": float(groups * period)},
                    )
                )
        pattern = self.frame_pattern()
        if pattern is not None:
            combs.append(
                (
                    sample_rate_hz / pattern,
                    f"the picture's flow noise follows a pattern of {pattern} frames "
                    "(the codec's frame types)",
                    {"pattern_frames": float(pattern)},
                )
            )
        return self._on_comb(frequency_hz, sd_hz, combs)

    def _on_comb(
        self, frequency_hz: float, sd_hz: float, combs: list[tuple[float, str, dict[str, float]]]
    ) -> Finding | None:
        """The first comb (base frequency, why, figures) one of whose teeth lies within
        :data:`KEYFRAME_SD` standard uncertainties ``sd_hz`` of ``frequency_hz``, as a finding."""
        tolerance = KEYFRAME_SD * max(sd_hz, 0.0)
        for base, why, figures in combs:
            order = max(1, round(frequency_hz / base))
            offset = abs(frequency_hz - order * base)
            if base < KEYFRAME_TEETH_BINS * self.bin_hz or offset > tolerance:
                continue
            what = "it" if order == 1 else _ordinal(order) + " multiple"
            return Finding(
                "codec_keyframes",
                f"{frequency_hz:.4g} Hz is a codec's pulse: {why} ({base:.4g} Hz), and this is {what} "
                f"({offset:.3g} Hz away, within {KEYFRAME_SD:g} standard uncertainties of {sd_hz:.3g} Hz)",
                {
                    **figures,
                    "comb_hz": base,
                    "order": float(order),
                    "offset_hz": offset,
                    "tolerance_hz": tolerance,
                },
            )
        return None

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
                self.frequencies_hz,
                power,
                band_hz=band,
                noise=floor_of(power),
                criteria=PeakCriteria(min_snr_db=10.0),
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
        sample_rate_hz: float,
        sd_hz: float | None = None,
    ) -> Finding | None:
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
        sample_rate_hz : float
            Rate of the samples, Hz.
        """
        power = self._border_power()
        if power is None:
            return None
        near = self._near(frequency_hz, width_bins)
        camera = float(power[near].sum())
        floor = float(floor_of(power)[near].max()) * max(int(near.sum()), 1)
        if camera < CAMERA_SNR * floor:
            return self._camera_overtone(
                frequency_hz, region_power=region_power, sample_rate_hz=sample_rate_hz, sd_hz=sd_hz
            )
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
        return Finding(
            "camera_motion",
            f"{frequency_hz:.4g} Hz is camera motion: the picture's border moves rigidly at it "
            f"({amplitude:.2g} px per frame) and the region no more than the border",
            {"border_px_per_frame": amplitude, "region_to_border_power": region_power / max(camera, 1e-30)},
        )

    def _camera_overtone(
        self, frequency_hz: float, *, region_power: float, sample_rate_hz: float, sd_hz: float | None
    ) -> Finding | None:
        """An overtone of the camera's shake (also folded back) left where the shake was removed: at its
        frequency within ``KEYFRAME_SD`` of the peak's standard uncertainty (a bin when not known)."""
        if not self.camera_removed:
            return None
        slack = self.bin_hz if sd_hz is None else max(KEYFRAME_SD * sd_hz, 0.1 * self.bin_hz)
        for shake_hz, shake_power in self.camera_frequencies():
            for order in range(2, 4):
                multiple = order * shake_hz
                image = folded(multiple, sample_rate_hz)
                if abs(image - frequency_hz) <= slack and region_power < CAMERA_OVERTONE_POWER * shake_power:
                    back = "" if image == multiple else f" (folded back from {multiple:.4g} Hz)"
                    return Finding(
                        "camera_motion",
                        f"{frequency_hz:.4g} Hz is camera motion: overtone {order} of the camera's shake at "
                        f"{shake_hz:.4g} Hz{back}, left where that shake was removed, weaker than it",
                        {"shake_hz": shake_hz, "order": float(order)},
                    )
        return None


def camera_intermodulation(
    evidence: WindowEvidence,
    frequency_hz: float,
    *,
    objects_hz: list[float],
    tolerance_hz: float,
) -> RejectedPeak | None:
    """Why a region's motion is an object's moved by the camera's shake, or None: the camera shook at
    f_c (its motion removed from the flow), an object of the picture moves at f_o on the same pixels, and
    the region's frequency is f_o + f_c or |f_o - f_c| within ``tolerance_hz``. Removing the camera's
    motion from an object's flow is not exact (the flow of a moving edge is no sum of its two motions): what
    is left mixes the two.

    Parameters
    ----------
    objects_hz : list of float
        Frequencies of the stronger objects on the same pixels.
    """
    if not evidence.camera_removed:
        return None
    for shake_hz, _ in evidence.camera_frequencies():
        for f0 in objects_hz:
            for mixed, sign in ((f0 + shake_hz, "+"), (abs(f0 - shake_hz), "-")):
                if abs(frequency_hz - mixed) <= tolerance_hz:
                    return RejectedPeak(
                        frequency_hz,
                        f"{frequency_hz:.4g} Hz is the object at {f0:.4g} Hz moved by the camera's shake at "
                        f"{shake_hz:.4g} Hz ({f0:.4g} {sign} {shake_hz:.4g} Hz), on the same pixels",
                        "camera_motion",
                        figures={"shake_hz": shake_hz, "object_hz": f0},
                    )
    return None


def light_images(
    evidence: WindowEvidence,
    frequency_hz: float,
    *,
    tolerance_hz: float,
    motion_at: Callable[[float], float],
    amplitude_px: float | None,
    objects: Sequence[tuple[float, float | None]],
) -> RejectedPeak | None:
    """Why a motion is the flicker of the light seen through the flow, or None, when the light flickers
    at f_L (:meth:`WindowEvidence.flicker_frequencies`) and the motion lies within ``tolerance_hz`` of

    - an overtone n f_L (n from 2 to :data:`MAX_FLICKER_ORDER`, folded back below the Nyquist rate) while
      the picture moves more at f_L itself (``motion_at``, the scan's statistic): the flow follows a
      rolling shutter's bands, not a sine, and its overtones fold back anywhere in the band; or
    - n f_L +- f_o of a stronger object at f_o (n up to :data:`MAX_MIXING_ORDER`), moving at most
      :data:`MIXING_SHARE` of its amplitude: the object's texture lit by a flickering light.

    The brightness need not oscillate at the motion's frequency (:meth:`WindowEvidence.flicker` asks
    that): the light flickers at f_L alone.

    Parameters
    ----------
    objects : sequence of (frequency_hz, amplitude_px)
        The stronger objects.
    """
    rate = evidence.sample_rate_hz
    for light_hz in evidence.flicker_frequencies():
        for order in range(2, MAX_FLICKER_ORDER + 1):
            image = folded(order * light_hz, rate)
            if abs(image - frequency_hz) <= tolerance_hz and motion_at(light_hz) >= motion_at(frequency_hz):
                back = "" if image == order * light_hz else f", folded back from {order * light_hz:.4g} Hz"
                return RejectedPeak(
                    frequency_hz,
                    f"{frequency_hz:.4g} Hz is illumination flicker: overtone {order} of the light's "
                    f"flicker at {light_hz:.4g} Hz{back}, in the flow of the flickering picture, which "
                    "moves more at the flicker itself",
                    "illumination_flicker",
                    figures={"flicker_hz": light_hz, "order": float(order)},
                )
        for object_hz, object_px in objects:
            if amplitude_px is None or object_px is None or amplitude_px > MIXING_SHARE * object_px:
                continue
            for order in range(1, MAX_MIXING_ORDER + 1):
                for sign in (1, -1):
                    image = folded(order * light_hz + sign * object_hz, rate)
                    if abs(image - frequency_hz) <= tolerance_hz:
                        how = f"{order} x " if order > 1 else ""
                        return RejectedPeak(
                            frequency_hz,
                            f"{frequency_hz:.4g} Hz is the object at {object_hz:.4g} Hz lit by the light's "
                            f"flicker at {light_hz:.4g} Hz ({how}{light_hz:.4g} {'+' if sign > 0 else '-'} "
                            f"{object_hz:.4g} Hz), at {amplitude_px / object_px:.1%} of its amplitude",
                            "illumination_flicker",
                            figures={"flicker_hz": light_hz, "object_hz": object_hz, "order": float(order)},
                        )
    return None


def block_coverage(labels: NDArray[np.integer], label: int, blocks: int) -> NDArray[np.float64]:
    """Fraction of each of ``blocks`` x ``blocks`` blocks of the picture covered by ``label``.

    Returns
    -------
    ndarray of float64, shape (blocks, blocks)
    """
    import cv2

    mask = (labels == label).astype(np.float32)
    return np.asarray(cv2.resize(mask, (blocks, blocks), interpolation=cv2.INTER_AREA), np.float64)


@dataclass(frozen=True)
class Suspect:
    """One measured object as the artefact tests see it.

    Attributes
    ----------
    frequency_hz, sd_hz : float
        The object's frequency and its standard uncertainty.
    width_bins : float
        Half-power half width of its peak, bins.
    localised : float
        The share of the picture's excess power at the peak inside the object's region.
    region_power : float
        Its region's typical band power on the evidence's grid.
    peak_hz, peak_sd_hz : float, optional
        The frequency of the peak the object was found at, and its uncertainty (a codec's comb is judged
        on either: a fit to the pulses' broadband motion may wander from their line).
    coverage : ndarray of float64, shape (B, B), or None
        Fraction of each brightness block its region covers.
    ring_power : ndarray of float32, shape (R,), or None
        Band power of the border ring's pixels there.
    """

    frequency_hz: float
    sd_hz: float
    width_bins: float
    localised: float
    region_power: float
    peak_hz: float | None = None
    peak_sd_hz: float = 0.0
    coverage: NDArray[np.float64] | None = None
    ring_power: NDArray[np.float32] | None = None


def artefact_verdict(
    evidence: WindowEvidence, suspect: Suspect, *, sample_rate_hz: float
) -> RejectedPeak | None:
    """Why a measured object is an artefact of the light, the codec or the camera, or None.

    A motion confined to one region (``suspect.localised`` at least :data:`LOCALISED`) is an object
    whatever the codec or the camera do at its frequency: they move the whole picture. (Flicker is shown
    by brightness oscillating outside the region too.) Otherwise the evidence must match in numbers
    (:meth:`WindowEvidence.flicker`, :meth:`~WindowEvidence.keyframes` within the object's own frequency
    uncertainty, :meth:`~WindowEvidence.camera`).

    Parameters
    ----------
    evidence : WindowEvidence
    suspect : Suspect
    sample_rate_hz : float

    Returns
    -------
    RejectedPeak or None
    """
    frequency_hz, sd_hz, width_bins = suspect.frequency_hz, suspect.sd_hz, suspect.width_bins
    found = None
    if suspect.coverage is not None:
        # Flicker's own evidence is the brightness outside the region (its apparent motion follows the
        # texture, so it may look localised): it needs no test of where the motion is.
        found = evidence.flicker(frequency_hz, width_bins, suspect.coverage)
    if found is None and suspect.coverage is not None:
        # A codec redrawing only the region at its keyframes makes a localised line on its comb.
        found = evidence.region_keyframes(
            suspect.coverage,
            frequency_hz if suspect.peak_hz is None else suspect.peak_hz,
            sd_hz if suspect.peak_hz is None else suspect.peak_sd_hz,
            sample_rate_hz,
        )
    if found is None and suspect.localised >= LOCALISED:
        return None
    if found is None and suspect.peak_hz is not None:
        found = evidence.keyframes(suspect.peak_hz, suspect.peak_sd_hz, sample_rate_hz)
        frequency_hz = suspect.peak_hz if found is not None else frequency_hz
    if found is None and sd_hz <= 0.5 * evidence.bin_hz:  # a fit that knows its frequency within half a bin
        found = evidence.keyframes(frequency_hz, sd_hz, sample_rate_hz)
    found = found or evidence.camera(
        frequency_hz,
        width_bins,
        region_power=suspect.region_power,
        ring_power=suspect.ring_power,
        sample_rate_hz=sample_rate_hz,
        sd_hz=sd_hz,
    )
    if found is None:
        return None
    return RejectedPeak(
        frequency_hz, found.reason, found.evidence, {**found.figures, "localised_share": suspect.localised}
    )


def _ordinal(n: int) -> str:
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"its {n}{suffix}"


__all__ = [
    "CAMERA_OVERTONE_POWER",
    "CAMERA_RATIO",
    "CAMERA_SNR",
    "KEYFRAME_SD",
    "LOCALISED",
    "Finding",
    "Suspect",
    "WindowEvidence",
    "artefact_verdict",
    "block_coverage",
    "camera_intermodulation",
    "light_images",
]
