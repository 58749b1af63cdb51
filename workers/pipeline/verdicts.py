"""Which measured motions are objects, and why the others are not: the one place that decides.

:mod:`workers.pipeline.detection` finds the candidates of one statistic; each is measured
(:mod:`workers.pipeline.measure`); this module judges the measurements. How an object moves is a finding,
not a filter: its **regime** is ``ring_down`` (it decays in the window, so its damping is measured),
``steady`` (a sustained or forced vibration: a motor, a shaker), or ``growing``. A measured object is
dropped only for a stated reason, with its figures:

- ``not_significant``: its false-alarm probability per clip, on its own pixels, is above the bound;
- positive evidence that it is an artefact of the camera, the light or the codec
  (:mod:`workers.pipeline.artefacts`: ``camera_motion``, ``illumination_flicker``, ``codec_keyframes``);
- ``same_pixels``: a line found on a stronger object's pixels is that object's second motion;
- ``harmonic``: an overtone of an object already reported, on the same pixels, possibly folded back
  below the Nyquist rate, or a faint copy of its motion seen elsewhere;
- ``incoherent``, ``uncertain`` / ``out_of_band``: no one oscillation explains its motion, its frequency
  is not known to a quarter of itself, or it lies outside the analysed band (the band is law).

Every drop becomes a :class:`~workers.pipeline.model.RejectedPeak` and a quality note. Objects are
reported most significant first; one with fewer than :data:`MIN_PERIODS` periods in the window is never
the main one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.detection import images_of
from workers.pipeline.model import ObjectMeasurement, QualityNote, RejectedPeak, Survey
from workers.pipeline.peaks import folded
from workers.pipeline.ringdown import MIN_DECAY
from workers.pipeline.segmentation import Segmentation
from workers.pipeline.significance import MAX_FALSE_ALARM, MotionScan

#: The evidence that a peak is an artefact of the camera or the light (rather than no object).
ARTEFACT_EVIDENCE = ("camera_motion", "illumination_flicker", "codec_keyframes")
#: A line is a second motion of a stronger object when that object's mask holds at least this share of
#: where the picture moves at it, and more of it than the line's own region does.
HELD_SHARE = 0.3
#: An object's mask lies where its line was found when at least this share of it does
#: (:meth:`Footing.own_pixels`).
FOUND_SHARE = 0.5
#: An object's own statistic is the scan's over the blocks within this many grid pixels of its region
#: (the fine grid's mask and the scan's grid need not line up to the pixel; an edge's flow lies beside it).
OWN_MARGIN_PX = 2
#: An object is a coherent oscillation: one damped oscillation explains at least this share of its
#: region's motion near its frequency (its fit's ``concentration``; 0.93-1.0 for the objects of the test
#: scenes and real clips, under 0.5 for narrow-band random motion) ...
MIN_COHERENCE = 0.5
#: ... unless a second motion this strong shares its region (two unresolved oscillations: a longer window
#: separates them; :data:`workers.pipeline.quality.SECOND_MOTION`) and the two together explain that share
#: (one oscillation of two explains 1 / (1 + r) of their power, r the second's strength: the product is
#: near 1; broadband motion, a hump of a camera's noise, spreads over both and explains little with
#: either: on the shared 128 Hz fork at 250 fps a hump at 62 Hz over the whole picture had 0.24 and r 0.79).
SECOND_MOTION_SHARE = 0.2
#: No object is reported whose frequency's standard uncertainty is this fraction of it or more.
MAX_RELATIVE_SD = 0.25
#: The main object spans at least this many periods of its frequency in the window.
MIN_PERIODS = 2.0

#: A region apart from a stronger object, at its frequency, is that object's motion seen elsewhere (flow's
#: leakage, a mount) when it moves at most this share of the object's amplitude ...
ECHO_AMPLITUDE = 0.05
#: ... and its displacement less the best scaled copy of the object's keeps at most this share of its
#: power at that frequency (a copy keeps almost none: 2e-4 for a 0.04 % copy seen across the background
#: of an auto-exposure hunting at 0.7 Hz through H.264; a second object has its own phase or release).
ECHO_RESIDUAL = 0.1
#: ... or no more than this many times the remainder's median 3 to 12 lines beside it (its noise: a copy
#: whose own region is noisy leaves noise; a power of 4 times the median of exponential powers has odds
#: of about 6 % under noise alone, and then the region is simply kept).
ECHO_FLOOR = 4.0


@dataclass(frozen=True)
class Footing:
    """Where an object's line was found and where the object was measured, on the scan's grid.

    Attributes
    ----------
    found : ndarray of bool, shape (h, w)
        Where the picture moves at its frequency (its candidate's region).
    held : ndarray of float32, shape (h, w)
        The share of each grid pixel's input pixels that the object's mask holds.
    """

    found: NDArray[np.bool_]
    held: NDArray[np.float32]

    def own_pixels(self) -> NDArray[np.bool_]:
        """The object's own pixels for its significance: where its mask lies, and where its line was found
        too when the mask lies there (at least :data:`FOUND_SHARE` of it). A thin bar's mask on the part of
        its edge that moves the most is measured where the line was found; its line stands out over the
        whole edge, not over the mask's few grid pixels alone (a 0.3 px bar through H.264: p 1.9e-4 over
        the edge, 0.03 over the mask)."""
        mask = self.held > 0
        total = float(self.held.sum())
        if total > 0 and float(self.held[self.found].sum()) >= FOUND_SHARE * total:
            return mask | self.found
        return mask

    def held_where_found(self, other: Footing | None = None) -> float:
        """The share of this object's found region that its mask (or ``other``'s) holds."""
        held = (other or self).held
        return float(held[self.found].mean()) if self.found.any() else 0.0


def significance_verdict(
    obj: ObjectMeasurement, scan: MotionScan, *, region: NDArray[np.bool_] | None = None
) -> RejectedPeak | None:
    """Why a measured object is not significant, or None: its false-alarm probability per clip (set on
    the object) exceeds :data:`~workers.pipeline.significance.MAX_FALSE_ALARM`. The probability is its
    strongest line's, at its frequency or one of its ``harmonics_hz``.

    Given ``region`` (the object's pixels on the scan's grid), the statistic is the scan's over the
    blocks that overlap the region grown by :data:`OWN_MARGIN_PX` (:meth:`MotionScan.within`), judged by
    the picture's law: what is measured must be where the line was found. A line found on one object's
    pixels (a second mode of it, until modes are reported) whose own measurement landed on other pixels,
    where nothing rings at it, is not reported as an object there."""
    f = obj.eigenfrequency_hz
    # The motion stands out by its strongest line: a wheel's rate is reported with its marks' passing,
    # twice as fast and far stronger, among its harmonics (any line of the band is within the per-clip law)
    low, high = float(scan.frequencies_hz[0]), float(scan.frequencies_hz[-1])
    lines = [f, *(h for h in obj.harmonics_hz if low <= h <= high)]
    z_picture = max(scan.z_at(x) for x in lines)
    z = z_picture
    if region is not None:
        grown = cv2.dilate(region.astype(np.uint8), np.ones((2 * OWN_MARGIN_PX + 1,) * 2, np.uint8)) > 0
        try:
            own = scan.within(grown)
            z = min(z_picture, max(own.z_at(x) for x in lines))
        except ValueError:  # no block with texture under the object: nothing there can show the line
            z = -math.inf
    p = float(scan.calibration.p_clip(z))
    obj.false_alarm_probability = p
    obj.detection_z = z if math.isfinite(z) else None
    if p <= MAX_FALSE_ALARM:
        return None
    where = (
        ""
        if z >= z_picture
        else (
            f" on the object's own pixels (it stands out elsewhere in the picture, with probability "
            f"{float(scan.calibration.p_clip(z_picture)):.2g}: the region measured is not where it moves)"
        )
    )
    return RejectedPeak(
        f,
        f"{f:.4g} Hz does not stand out of the noise{where}: a peak as high comes from noise alone with "
        f"probability {p:.2g} per clip (the bound is {MAX_FALSE_ALARM:g})",
        "not_significant",
        figures={
            "false_alarm_probability": p,
            "z": z if math.isfinite(z) else -1e9,
            "picture_z": z_picture,
            "bound": MAX_FALSE_ALARM,
        },
    )


def oscillation_verdict(obj: ObjectMeasurement, *, band_hz: tuple[float, float]) -> RejectedPeak | None:
    """Why a measured region is not reported whatever its significance, or None: its frequency lies
    outside the band, is not known to better than ``MAX_RELATIVE_SD`` of itself, or its motion near the
    frequency is no oscillation (one damped oscillation explains less than :data:`MIN_COHERENCE` of it,
    and it is not two unresolved ones, which a longer window separates)."""
    f = obj.eigenfrequency_hz
    if not (band_hz[0] <= f <= band_hz[1]):
        return RejectedPeak(
            f,
            f"{f:.4g} Hz lies outside the analysed band [{band_hz[0]:.3g}, {band_hz[1]:.3g}] Hz",
            "out_of_band",
            figures={"band_low_hz": band_hz[0], "band_high_hz": band_hz[1]},
        )
    sd = obj.eigenfrequency_uncertainty_hz
    if sd is None or not math.isfinite(sd) or sd >= MAX_RELATIVE_SD * f:
        return RejectedPeak(
            f,
            f"{f:.4g} Hz is too uncertain to report (± {sd:.3g} Hz, a quarter of itself or more)",
            "uncertain",
            figures={"frequency_sd_hz": float("nan") if sd is None else sd},
        )
    share = obj.concentration
    two_motions = (
        obj.second_motion >= SECOND_MOTION_SHARE
        and share is not None
        and share * (1 + obj.second_motion) >= MIN_COHERENCE
    )
    if share is not None and share < MIN_COHERENCE and not two_motions:
        second = obj.second_motion
        beside = (
            f", and with the second motion beside it {share * (1 + second) * 100:.0f} %"
            if second >= SECOND_MOTION_SHARE
            else ""
        )
        return RejectedPeak(
            f,
            f"{f:.4g} Hz is no oscillation: a damped oscillation explains only {share * 100:.0f} % of the "
            f"region's motion near it{beside} (narrow-band random motion, a wandering frequency)",
            "incoherent",
            figures={"explained_share": share, "second_motion": second, "bound": MIN_COHERENCE},
        )
    return None


def held_verdict(
    obj: ObjectMeasurement, footing: Footing, stronger: Sequence[tuple[ObjectMeasurement, Footing]]
) -> RejectedPeak | None:
    """Why a line is not an object of its own, or None: where the picture moves at it, a stronger object's
    mask holds more of the pixels than its own does (at least :data:`HELD_SHARE` of them). The line is a
    second motion of that object (not its harmonic, which :func:`_overtone` finds: another mode), and the
    region measured for it lies elsewhere, where that motion is not."""
    own = footing.held_where_found()
    for base, other in stronger:
        held = footing.held_where_found(other)
        if held >= HELD_SHARE and held > own:
            f = obj.eigenfrequency_hz
            return RejectedPeak(
                f,
                f"{f:.4g} Hz moves on the pixels of object {base.id} ({base.eigenfrequency_hz:.4g} Hz), "
                f"which holds {held * 100:.0f} % of them (the region measured for it {own * 100:.0f} %), "
                "and is not its harmonic: another motion of that object (a higher mode), not an object of "
                "its own",
                "same_pixels",
                figures={"object_id": float(base.id), "held_share": held, "own_share": own},
            )
    return None


@dataclass(frozen=True)
class OvertoneRules:
    """When a region is an overtone of a stronger object (see :func:`judge_objects`).

    Attributes
    ----------
    tolerance : float
        Relative tolerance of an overtone's frequency (or a bin and a half, whichever is wider).
    shared_power : float
        The region's pixels move at the stronger object's own frequency with at least this share of their
        power at their own.
    max_order : int
        Overtones up to this order ...
    max_folded_order : int
        ... and, folded back below the Nyquist rate, up to this one.
    """

    tolerance: float = 0.02
    shared_power: float = 0.25
    max_order: int = 10
    max_folded_order: int = 5


def judge_objects(
    objects: list[ObjectMeasurement],
    seg: Segmentation,
    *,
    scan: MotionScan,
    band_hz: tuple[float, float],
    sample_rate_hz: float,
    bin_hz: float,
    footings: Sequence[Footing] | None = None,
    overtones: OvertoneRules = OvertoneRules(),
) -> dict[int, RejectedPeak]:
    """The objects (by id) that are not reported, and why: :func:`oscillation_verdict`,
    :func:`significance_verdict` (every object's false-alarm probability is set), or an overtone of a
    stronger object on the same pixels.

    A region ringing at n times (n up to ``overtones.max_order``; or, folded back below the Nyquist rate,
    at |n f - m fs| for n up to ``overtones.max_folded_order``) the frequency of a stronger object, whose
    pixels also move at that object's own frequency with at least ``overtones.shared_power`` of their
    power at their own, is its overtone. Two objects an octave apart (two strings) ring on pixels of
    their own and are both kept; a neighbour's spectral leakage is far weaker than that.

    Parameters
    ----------
    objects : list of ObjectMeasurement
        Strongest first; ``objects[i].id`` is label ``i + 1`` of ``seg``.
    seg : Segmentation
        Their labels and band powers on the flow grid.
    band_hz : (low, high)
    sample_rate_hz, bin_hz : float
        Rate of the samples and width of one bin, Hz.
    footings : sequence of Footing, optional
        Where each object was found and measured on the scan's grid: its significance is judged on its
        own pixels (:func:`significance_verdict`), and a line found on a stronger object's pixels is
        that object's (:func:`held_verdict`).
    overtones : OvertoneRules, optional

    Returns
    -------
    dict of int to RejectedPeak
    """
    out: dict[int, RejectedPeak] = {}
    kept: list[ObjectMeasurement] = []
    kept_footings: list[tuple[ObjectMeasurement, Footing]] = []
    for i, obj in enumerate(objects):
        footing = None if footings is None else footings[i]
        verdict = significance_verdict(obj, scan, region=None if footing is None else footing.own_pixels())
        if footing is not None:
            verdict = held_verdict(obj, footing, kept_footings) or verdict
        verdict = oscillation_verdict(obj, band_hz=band_hz) or verdict
        if verdict is None:
            verdict = _overtone(obj, kept, seg, sample_rate_hz=sample_rate_hz, bin_hz=bin_hz, rules=overtones)
        if verdict is None:
            kept.append(obj)
            if footing is not None:
                kept_footings.append((obj, footing))
        else:
            out[obj.id] = verdict
    return out


def _overtone(
    obj: ObjectMeasurement,
    stronger: list[ObjectMeasurement],
    seg: Segmentation,
    *,
    sample_rate_hz: float,
    bin_hz: float,
    rules: OvertoneRules,
) -> RejectedPeak | None:
    """Why ``obj`` is an overtone (or the image, or the motion) of one of the ``stronger`` objects on its
    pixels, or None (see :func:`judge_objects`)."""
    f = obj.eigenfrequency_hz
    region = seg.labels == obj.id
    own = obj.id - 1
    if not region.any() or not 0 <= own < len(seg.peaks):
        return None
    own_power = float(np.median(seg.band_power[own][region]))
    slack = max(rules.tolerance * f, 1.5 * bin_hz)
    for base in stronger:
        if not 0 <= base.id - 1 < len(seg.peaks):
            continue
        f0 = base.eigenfrequency_hz
        for order in range(1, rules.max_order + 1):
            same = [(f0, "")] if order == 1 else []
            images = images_of(
                f0, order, sample_rate_hz=sample_rate_hz, max_folded_order=rules.max_folded_order
            )
            for image, how in same + images:
                if abs(f - image) > slack:
                    continue
                direct = order == 1 and not how
                shared = _shared_motion(
                    obj,
                    base,
                    region,
                    seg,
                    direct=direct,
                    own_power=own_power,
                    sample_rate_hz=sample_rate_hz,
                    rules=rules,
                )
                if shared is None:
                    continue
                where, figures = shared
                what = "the motion" if direct else ("an image" if order == 1 else f"overtone {order}")
                return RejectedPeak(
                    f,
                    f"{f:.4g} Hz is {what} of the object at {f0:.4g} Hz, {where}{how}",
                    "harmonic",
                    figures={"fundamental_hz": f0, **figures, "order": float(order)},
                )
    return None


def _shared_motion(
    obj: ObjectMeasurement,
    base: ObjectMeasurement,
    region: NDArray[np.bool_],
    seg: Segmentation,
    *,
    direct: bool,
    own_power: float,
    sample_rate_hz: float,
    rules: OvertoneRules,
) -> tuple[str, dict[str, float]] | None:
    """Where ``obj`` (on ``region``) shows the motion of the stronger ``base`` at a frequency of it (its
    own when ``direct``, else an overtone or an image): how to say so and its figures, or None when it is
    another object. The same frequency is ``base``'s motion on pixels touching it, or a faint copy of it
    elsewhere; an overtone or image needs ``region`` to move at ``base``'s frequency too."""
    if direct:
        if touching(region, seg.labels == base.id):
            return "on the same pixels", {}
        if not faint_copy(obj, base, sample_rate_hz=sample_rate_hz):
            return None  # the same frequency elsewhere: another object
        share = (obj.amplitude_px or 0.0) / (base.amplitude_px or 1.0)
        where = f"seen elsewhere, a copy in step with it at {share:.2%} of its amplitude"
        return where, {"amplitude_share": share}
    if float(np.median(seg.band_power[base.id - 1][region])) < rules.shared_power * own_power:
        return None  # its pixels do not move at the stronger object's frequency: another object
    return "on the same pixels", {}


def faint_copy(obj: ObjectMeasurement, base: ObjectMeasurement, *, sample_rate_hz: float) -> bool:
    """Whether ``obj``'s motion is a faint copy of the stronger ``base``'s: at most :data:`ECHO_AMPLITUDE`
    of its amplitude, and its displacement, less the best scaled copy of ``base``'s, has no line of its own
    at its frequency: at most :data:`ECHO_RESIDUAL` of the line's power is left, or no more than
    :data:`ECHO_FLOOR` times the remainder's own floor beside it (Hann-windowed lines of the window).

    Optical flow carries a strong motion faintly into the rest of the picture (DIS's coarse scales, a
    codec's motion search) and a mount passes it on: the copy is in step with the object, released with
    it, damped with it. A second object at the same frequency has its own phase, release or amplitude.
    """
    own, other = obj.displacement_px, base.displacement_px
    if own is None or other is None or not obj.amplitude_px or not base.amplitude_px:
        return False
    if obj.amplitude_px > ECHO_AMPLITUDE * base.amplitude_px:
        return False
    n = min(len(own), len(other))
    if n < 32:
        return False
    d1 = np.nan_to_num(own[:n] - np.nanmean(own[:n]))
    d0 = np.nan_to_num(other[:n] - np.nanmean(other[:n]))
    scale = float(d0 @ d0)
    if scale <= 0:
        return False
    residual = d1 - (float(d1 @ d0) / scale) * d0
    offsets = np.r_[0, np.arange(3, 13), -np.arange(3, 13)] * sample_rate_hz / n
    probes = np.hanning(n) * np.exp(
        -2j * np.pi * (obj.eigenfrequency_hz + offsets[:, None]) * np.arange(n) / sample_rate_hz
    )
    left = np.abs(probes @ residual) ** 2
    line = abs(complex(probes[0] @ d1)) ** 2
    return line > 0 and left[0] <= max(ECHO_RESIDUAL * line, ECHO_FLOOR * float(np.median(left[1:])))


def touching(a: NDArray[np.bool_], b: NDArray[np.bool_], *, gap_px: int = 3) -> bool:
    """Whether two masks overlap or lie within ``gap_px`` of each other."""
    import cv2

    grown = cv2.dilate(a.astype(np.uint8), np.ones((2 * gap_px + 1, 2 * gap_px + 1), np.uint8)) > 0
    return bool((grown & b).any())


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
        image = folded(f, sample_rate_hz)
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
    obj.damping_ratio_uncertainty = sigma_sd / omega
    obj.null_reasons = [r for r in obj.null_reasons if not r.startswith("damping:")]
    obj.notes.append(
        "damping from the decay of its energy over the whole clip "
        f"({math.exp(-sigma * clip_s) * 100:.0f} % of the amplitude left after {clip_s:.3g} s): the "
        "analysed window shows too little of it"
    )
    obj.regime = "ring_down"
    return obj.regime


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
    "MIN_PERIODS",
    "Footing",
    "OvertoneRules",
    "clip_regime",
    "drop_objects",
    "faint_copy",
    "folded_image",
    "folded_verdicts",
    "held_verdict",
    "judge_objects",
    "oscillation_verdict",
    "significance_verdict",
    "touching",
]
