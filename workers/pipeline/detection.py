"""Which motions are objects, and why the others are not: the one place that decides.

An object is a region whose motion has a coherent, narrow-band oscillation. One statistic decides for
every regime: the scan statistic of :mod:`workers.pipeline.significance`, whose false-alarm probability
per clip is measured on the clip itself. :func:`find_candidates` takes its significant peaks (at most
:data:`~workers.pipeline.significance.MAX_FALSE_ALARM`), strongest first, each with the region where the
picture moves at it; an overtone on the same pixels as a stronger peak is that peak's harmonic, and a
peak whose fundamental (half, a third, a quarter of it) moves the same pixels significantly is that
fundamental's overtone (a rotating wheel's rate, not its second harmonic).

How an object moves is a finding, not a filter: its **regime** is ``ring_down`` (it decays in the
window, so its damping is measured), ``steady`` (a sustained or forced vibration: a motor, a shaker), or
``growing``. A measured object is dropped only for a stated reason, with its figures:

- ``not_significant``: its false-alarm probability per clip is above the bound;
- positive evidence that it is an artefact of the camera, the light or the codec
  (:mod:`workers.pipeline.artefacts`: ``camera_motion``, ``illumination_flicker``, ``codec_keyframes``);
- ``harmonic``: an overtone of an object already reported, on the same pixels, possibly folded back
  below the Nyquist rate;
- ``uncertain`` / ``out_of_band``: its frequency is not known to a quarter of itself, or lies outside
  the analysed band (the band is law).

Every drop becomes a :class:`~workers.pipeline.model.RejectedPeak` and a quality note. Objects are
reported most significant first; one with fewer than :data:`MIN_PERIODS` periods in the window is never
the main one.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.model import ObjectMeasurement, QualityNote, RejectedPeak, Survey
from workers.pipeline.peaks import Peak, PeakPolicy, interpolate_peak
from workers.pipeline.ringdown import MIN_DECAY
from workers.pipeline.segmentation import Segmentation
from workers.pipeline.significance import CONTRAST_WIDTH_BINS, MAX_FALSE_ALARM, MotionScan

#: The evidence that a peak is an artefact of the camera or the light (rather than no object).
ARTEFACT_EVIDENCE = ("camera_motion", "illumination_flicker", "codec_keyframes")
#: A line is a second motion of a stronger object when that object's mask holds at least this share of
#: where the picture moves at it, and more of it than the line's own region does.
HELD_SHARE = 0.3
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
#: A peak's fundamental is sought at these fractions of it ...
SUBHARMONIC_ORDERS = (2, 3, 4)
#: ... where the region's statistic is at least this share of the peak's, and its line contrast this.
FUNDAMENTAL_SHARE = 0.03
FUNDAMENTAL_CONTRAST = 2.0
#: An overtone (or a fundamental) shares the pixels of its peak when this much of the smaller region
#: overlaps the other.
SHARED_REGION = 0.3
#: A line within this many bins of a stronger one on the same pixels, and below this share of its
#: statistic, is its leakage (the Tukey window's side lobes stand below a twentieth of its main lobe from
#: two bins on, :data:`~workers.pipeline.significance.TAPER_ALPHA`).
LEAKAGE_BINS = 4.5
LEAKAGE_LEVEL = 0.05
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
#: Relative tolerance of a harmonic's frequency (or a bin and a half, whichever is wider).
HARMONIC_TOLERANCE = 0.02
#: An oscillation is a line: its statistic at least this many times its neighbours' in frequency
#: (:func:`workers.pipeline.significance.line_contrast`) ...
LINE_CONTRAST = 3.0
#: ... the neighbours beyond its own width when it is a damped oscillation's broad line: one whose
#: half-power half-width is at most this share of its frequency (a damping ratio of about a tenth, with the
#: window's own width) and its neighbours' median there stands this far below it. (A ring-down of
#: damping 0.03 at 9.7 Hz, released a second into a 256-frame window at 30 fps, is five bins wide: 1.76
#: times the neighbours two to eight bins away, against a false-alarm probability of 2.6e-7.)
MAX_LINE_HALF_WIDTH = 0.1
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


@dataclass(frozen=True)
class Candidate:
    """A significant peak of the scan and where the picture moves at it.

    Attributes
    ----------
    peak : Peak
        Its frequency (interpolated), harmonics and width; ``snr_db`` is its standardised height z.
    z : float
    false_alarm : float
        Probability per clip that noise gives a peak as high.
    region : ndarray of bool, shape (h, w)
        Where it moves, on the scan's grid.
    localised : float
        Share of the picture's excess power at the peak inside ``region`` (1: one place; small: everywhere).
    """

    peak: Peak
    z: float
    false_alarm: float
    region: NDArray[np.bool_]
    localised: float


@dataclass(frozen=True)
class Candidates:
    """What :func:`find_candidates` found: candidates strongest first, and the peaks it set aside."""

    found: list[Candidate]
    rejected: list[RejectedPeak] = field(default_factory=list)

    @property
    def peaks(self) -> list[Peak]:
        return [c.peak for c in self.found]

    @property
    def regions(self) -> list[NDArray[np.bool_]]:
        return [c.region for c in self.found]


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

    def held_where_found(self, other: Footing | None = None) -> float:
        """The share of this object's found region that its mask (or ``other``'s) holds."""
        held = (other or self).held
        return float(held[self.found].mean()) if self.found.any() else 0.0


def significant_bins(scan: MotionScan, *, limit: float = MAX_FALSE_ALARM) -> list[int]:
    """Bins of the scan's local maxima that are lines (their contrast at least :data:`LINE_CONTRAST`,
    beside them or, a damped oscillation's broad line, beyond its width: :func:`_broad_line_contrast`)
    whose false-alarm probability per clip is at most ``limit``, highest first."""
    z = scan.z
    # The band's edge bins are no peaks: what lies beyond them rises towards them (below the lowest a drift,
    # the camera creeping; above the highest, motion faster than the band).
    padded = np.concatenate(([np.inf], z, [np.inf]))
    local = np.flatnonzero((padded[1:-1] > padded[:-2]) & (padded[1:-1] >= padded[2:]) & scan.searched)
    p = scan.calibration.p_clip(z[local])
    line = scan.contrast[local] >= LINE_CONTRAST
    for i in np.flatnonzero(~line & (p <= limit)):
        line[i] = _broad_line_contrast(scan, int(local[i])) >= LINE_CONTRAST
    chosen = local[(p <= limit) & line]
    return [int(k) for k in chosen[np.argsort(-z[chosen])]]


def _broad_line_contrast(scan: MotionScan, k: int) -> float:
    """The statistic at bin ``k`` over the median of its neighbours beyond its half-power half-width
    (the neighbours :func:`~workers.pipeline.significance.line_contrast` takes, moved out by it), or 0
    when it is no single broad line: narrower than two bins each side (the plain contrast judges it),
    wider than a damped oscillation's (:data:`MAX_LINE_HALF_WIDTH`), or rising again before it falls to
    half on either side (one peak of a speckled stretch lifted at once, which stands out of nothing)."""
    t = scan.statistic
    span = _half_power_span(t, k, single_lobe=True)
    if span is None:
        return 0.0
    width = max(k - span[0], span[1] - k)
    if width < 2 or width * scan.bin_hz > MAX_LINE_HALF_WIDTH * scan.frequencies_hz[k]:
        # within a bin either side, the plain contrast's neighbours (from two bins on) judge it already
        return 0.0
    reach = CONTRAST_WIDTH_BINS
    offsets = np.r_[-(width + reach) : -width, width + 1 : width + reach + 1]
    at = k + offsets
    at = at[(at >= 0) & (at < len(t))]
    if at.size < reach:
        return 0.0
    return float(t[k] / max(float(np.median(t[at])), 1e-30))


def _half_power_span(t: NDArray[np.float64], k: int, *, single_lobe: bool = False) -> tuple[int, int] | None:
    """The bins ``(lo, hi)`` around ``k`` over which ``t`` stays above half of ``t[k]``; with
    ``single_lobe``, None when ``t`` rises again on the way out (more than one peak above the half)."""
    half = 0.5 * t[k]
    lo, hi = k, k
    while lo > 0 and t[lo - 1] > half:
        if single_lobe and t[lo - 1] > t[lo]:
            return None
        lo -= 1
    while hi < len(t) - 1 and t[hi + 1] > half:
        if single_lobe and t[hi + 1] > t[hi]:
            return None
        hi += 1
    return lo, hi


def _peak_at(scan: MotionScan, k: int) -> Peak:
    """The scan's peak at bin ``k``: parabolic interpolation of log T, its half-power width."""
    t = scan.statistic
    offset = interpolate_peak(t, k) - k
    f = float(scan.frequencies_hz[k] + offset * scan.bin_hz)
    span = _half_power_span(t, k)
    assert span is not None  # only a single lobe's span can be refused
    lo, hi = span
    return Peak(
        frequency_hz=f,
        bin=k,
        power=float(t[k]),
        prominence_db=0.0,
        snr_db=float(scan.z[k]),
        width_bins=max(1.0, (hi - lo + 1) / 2),
    )


def shared_region(a: NDArray[np.bool_], b: NDArray[np.bool_]) -> bool:
    """Whether two regions share their pixels: :data:`SHARED_REGION` of the smaller lies in the other."""
    smaller = min(int(a.sum()), int(b.sum()))
    return smaller > 0 and int((a & b).sum()) >= SHARED_REGION * smaller


def images_of(
    f0: float, order: int, *, sample_rate_hz: float, max_folded_order: int
) -> list[tuple[float, str]]:
    """Where the overtone ``order`` of a motion at ``f0`` shows in frames at ``sample_rate_hz``, with how:
    at ``order * f0`` itself; folded back below the Nyquist rate (orders up to ``max_folded_order``); and
    mirrored about a quarter of the rate (the same orders), the image a camera or codec whose frames
    alternate in two kinds (two read-outs, two frame types) makes of any motion: its amplitude changes
    every other frame, which shifts it by half the rate. Order 1 gives only its images, not ``f0``."""
    multiple = order * f0
    found = [] if order == 1 else [(multiple, "")]
    if order > max_folded_order:
        return found
    for rate, how in (
        (sample_rate_hz, "folded back below the Nyquist rate"),
        (sample_rate_hz / 2, "mirrored about a quarter of the frame rate"),
    ):
        image = abs(multiple - rate * round(multiple / rate))
        if abs(image - multiple) > 1e-9 and image > 0:
            found.append((image, f", {how} from {multiple:.4g} Hz"))
    return found


def _overtone_of(
    f: float,
    f0: float,
    *,
    sample_rate_hz: float,
    bin_hz: float,
    max_order: int = 10,
    max_folded_order: int = 5,
) -> tuple[int, float]:
    """The order n (1 .. ``max_order``) of which ``f`` is an image n f0 (:func:`images_of`), and how far
    it lies from it (Hz); (0, inf) when none is within the harmonic tolerance."""
    slack = max(HARMONIC_TOLERANCE * f, 1.5 * bin_hz)
    best = (0, math.inf)
    for order in range(1, max_order + 1):
        for image, _ in images_of(
            f0, order, sample_rate_hz=sample_rate_hz, max_folded_order=max_folded_order
        ):
            error = abs(f - image)
            if error <= slack and error < best[1]:
                best = (order, error)
    return best


def _fundamental(scan: MotionScan, cand: Candidate, *, band_hz: tuple[float, float]) -> Candidate:
    """``cand`` with its frequency moved to its fundamental when the same pixels have a line at f / n (the
    lowest such n of :data:`SUBHARMONIC_ORDERS` wins), ``f`` then among its harmonics.

    A line there is a local peak of the region's statistic at f / n (within the harmonic tolerance),
    :data:`LINE_CONTRAST` times its neighbours' (a strongly moving object lifts every low frequency of
    its region, which is no line), significant by the picture's law at that one frequency (held to the
    bound divided by the number of fractions tried), and at least :data:`FUNDAMENTAL_SHARE` of the
    line at f (a motor's faint trace at half its frequency does not make its vibration half as fast)."""
    f = cand.peak.frequency_hz
    try:
        own = scan.within(cand.region)
    except ValueError:
        return cand
    best: int | None = None
    strongest = float(own.statistic[own.peak_bin(f, half_width_bins=1.0)])
    for n in SUBHARMONIC_ORDERS:
        sub = f / n
        if sub < band_hz[0] or sub < 1.5 * scan.bin_hz:
            break
        k = own.peak_bin(sub, half_width_bins=1.0)
        if own.statistic[k] < FUNDAMENTAL_SHARE * strongest:
            continue  # a trace at f / n beside a strong line at f: the line is the motion
        if _line_at(own, sub, bound=MAX_FALSE_ALARM / len(SUBHARMONIC_ORDERS)) and _divides(
            scan, own.peak_bin(sub, half_width_bins=1.0), f, n
        ):
            best = n
    if best is None:
        return cand
    base = _peak_at(scan, own.peak_bin(f / best, half_width_bins=1.0))
    harmonics = sorted({*(m * base.frequency_hz for m in range(2, best)), f, *cand.peak.harmonics_hz})
    peak = Peak(**{**vars(base), "harmonics_hz": [h for h in harmonics if h <= band_hz[1]]})
    return Candidate(
        peak, cand.z, cand.false_alarm, cand.region | scan.region(base.frequency_hz), cand.localised
    )


def _divides(scan: MotionScan, k: int, frequency_hz: float, order: int) -> bool:
    """Whether the line at bin ``k`` (its interpolated frequency) times ``order`` is ``frequency_hz``,
    within the harmonic tolerance or half a bin of that line times the order (a bin is wide; the line's
    frequency is known to a fraction of one)."""
    sub = _peak_at(scan, k).frequency_hz
    return abs(order * sub - frequency_hz) <= max(
        HARMONIC_TOLERANCE * frequency_hz, 0.5 * order * scan.bin_hz
    )


def _line_at(scan: MotionScan, frequency_hz: float, *, bound: float) -> bool:
    """Whether ``scan`` has a line at ``frequency_hz``: a local peak there (within the harmonic
    tolerance), its contrast at least :data:`FUNDAMENTAL_CONTRAST` (a fundamental sits among the low
    frequencies a moving object lifts), and significant at that one frequency."""
    k = scan.peak_bin(frequency_hz, half_width_bins=1.0)
    t = scan.statistic
    if abs(scan.frequencies_hz[k] - frequency_hz) > max(HARMONIC_TOLERANCE * frequency_hz, scan.bin_hz):
        return False
    if (k > 0 and t[k - 1] > t[k]) or (k < len(t) - 1 and t[k + 1] > t[k]):
        return False
    if scan.contrast[k] < FUNDAMENTAL_CONTRAST:
        return False
    return float(scan.calibration.p_frequency(scan.z[k])) <= bound


def find_candidates(
    scan: MotionScan, *, band_hz: tuple[float, float], max_objects: int, asserted: int = 0
) -> Candidates:
    """The scan's significant peaks as object candidates (see the module's description).

    Parameters
    ----------
    scan : MotionScan
        Of the window's whole picture.
    band_hz : (low, high)
    max_objects : int
    asserted : int
        How many objects the user says were excited (the excitations given): when fewer peaks are
        significant, the strongest lines are candidates up to that number, whatever their false-alarm
        probability (which their objects report; :func:`significance_verdict` does not drop an object an
        excitation names). The question is then where and at what frequency, not whether.

    Returns
    -------
    Candidates
    """
    found = _candidates(scan, significant_bins(scan), band_hz=band_hz, max_objects=max_objects)
    if len(found.found) >= min(asserted, max_objects):
        return found
    return _candidates(
        scan, significant_bins(scan, limit=1.0), band_hz=band_hz, max_objects=min(asserted, max_objects)
    )


def _candidates(
    scan: MotionScan, bins: list[int], *, band_hz: tuple[float, float], max_objects: int
) -> Candidates:
    """The peaks at ``bins`` (strongest first) as candidates: see :func:`find_candidates`."""
    kept: list[Candidate] = []
    rejected: list[RejectedPeak] = []
    for k in bins:
        peak = _peak_at(scan, k)
        if _known(peak.frequency_hz, kept, scan.bin_hz):
            continue
        region = scan.region(peak.frequency_hz)
        cand = Candidate(peak, float(scan.z[k]), float(scan.calibration.p_clip(scan.z[k])), region, 0.0)
        if _leakage(cand, kept, scan.bin_hz):
            continue
        if _as_harmonic(cand, kept, scan) or len(kept) >= max_objects:
            continue
        trace = _subharmonic_trace(cand, kept, scan)
        if trace is not None:
            rejected.append(trace)
            continue
        cand = _fundamental(scan, cand, band_hz=band_hz)
        f = cand.peak.frequency_hz
        same = next((c for c in kept if abs(f - c.peak.frequency_hz) <= 1.5 * scan.bin_hz), None)
        if same is not None:  # its fundamental is a candidate already: it is that one's overtone
            same.peak.harmonics_hz.extend(
                h for h in cand.peak.harmonics_hz if not _known(h, [same], scan.bin_hz)
            )
            continue
        localised = scan.localised_share(f, cand.region)
        kept.append(Candidate(cand.peak, cand.z, cand.false_alarm, cand.region, localised))
    kept = _merge_combs(kept, scan, band_hz=band_hz)
    for c in kept:
        c.peak.harmonics_hz.sort()
    return Candidates(kept, rejected)


def _merge_combs(kept: list[Candidate], scan: MotionScan, *, band_hz: tuple[float, float]) -> list[Candidate]:
    """Candidates on shared pixels whose frequencies are all overtones of one fundamental present there, as
    that one candidate: a wheel turning at f whose marks make lines at 2f, 5f, 10f ... is one motion at f.

    The fundamental is the highest f0 (at least the band's lower edge and a bin and a half) of which every
    line of the group (their frequencies and overtones) is a multiple up to :data:`MAX_COMB_ORDER` within
    the harmonic tolerance, and where the group's pixels have a line (:func:`_line_at`) or a candidate."""
    out: list[Candidate] = []
    used: set[int] = set()
    for i, c in enumerate(kept):
        if i in used:
            continue
        group = [i] + [
            j for j in range(i + 1, len(kept)) if j not in used and shared_region(c.region, kept[j].region)
        ]
        if len(group) < 2:
            out.append(c)
            continue
        lines = sorted({kept[j].peak.frequency_hz for j in group})
        f0 = _comb_fundamental(lines, scan, region=_union(kept[j].region for j in group), band_hz=band_hz)
        if f0 is None:
            out.append(c)
            continue
        used.update(group)
        k = scan.peak_bin(f0, half_width_bins=1.0)
        base = _peak_at(scan, k)
        extra = {h for j in group for h in (kept[j].peak.frequency_hz, *kept[j].peak.harmonics_hz)}
        harmonics = sorted(h for h in extra if abs(h - base.frequency_hz) > 1.5 * scan.bin_hz)
        peak = Peak(**{**vars(base), "harmonics_hz": harmonics})
        region = _union(kept[j].region for j in group)
        best = max((kept[j] for j in group), key=lambda d: d.z)
        out.append(
            Candidate(peak, best.z, best.false_alarm, region, scan.localised_share(base.frequency_hz, region))
        )
    return out


#: A comb's lines are overtones of its fundamental up to this order.
MAX_COMB_ORDER = 16


def _union(masks: Iterable[NDArray[np.bool_]]) -> NDArray[np.bool_]:
    it = iter(masks)
    out = np.array(next(it), bool)
    for m in it:
        out |= m
    return out


def _comb_fundamental(
    lines: list[float], scan: MotionScan, *, region: NDArray[np.bool_], band_hz: tuple[float, float]
) -> float | None:
    """The highest frequency of which every one of ``lines`` is an overtone (see :func:`_merge_combs`),
    other than what they are already (the lowest line when it divides the others is that line), or None."""
    try:
        own = scan.within(region)
    except ValueError:
        return None
    floor = max(band_hz[0], 1.5 * scan.bin_hz)
    tries = sorted(
        {f / n for f in lines for n in range(1, MAX_COMB_ORDER + 1) if f / n >= floor}, reverse=True
    )
    for f0 in tries:
        orders = [round(f / f0) for f in lines]
        if max(orders) > MAX_COMB_ORDER or min(orders) < 1:
            continue
        slack = [max(HARMONIC_TOLERANCE * f, 0.5 * scan.bin_hz) for f in lines]  # interpolated lines
        if any(abs(f - n * f0) > tol for f, n, tol in zip(lines, orders, slack, strict=True)):
            continue
        strongest = max(float(own.statistic[own.peak_bin(f, half_width_bins=1.0)]) for f in lines)
        if float(own.statistic[own.peak_bin(f0, half_width_bins=1.0)]) < FUNDAMENTAL_SHARE * strongest:
            return None  # a faint trace at f0 beside strong lines: the lines are the motions
        present = [f for f, tol in zip(lines, slack, strict=True) if abs(f - f0) <= tol]
        if present:
            # The fundamental is one of the lines, measured: its overtones are its multiples.
            if _multiples(lines, min(present, key=lambda f: abs(f - f0)), slack):
                return f0
            continue
        if _line_at(own, f0, bound=MAX_FALSE_ALARM / len(SUBHARMONIC_ORDERS)):
            measured = _peak_at(scan, own.peak_bin(f0, half_width_bins=1.0)).frequency_hz
            return f0 if _multiples(lines, measured, slack) else None
        return None  # the highest common fundamental is not on these pixels: lower ones are guesses
    return None


def _multiples(lines: list[float], f0: float, slack: list[float]) -> bool:
    """Whether every one of ``lines`` is a whole multiple of ``f0`` within its ``slack`` (a cantilever's
    second mode, 6.27 times its first, is no overtone of it, though it is of a frequency half a bin off)."""
    return all(abs(f - round(f / f0) * f0) <= tol for f, tol in zip(lines, slack, strict=True))


def _subharmonic_trace(cand: Candidate, kept: list[Candidate], scan: MotionScan) -> RejectedPeak | None:
    """Why a weaker line at 1/n of a kept candidate's frequency (n of :data:`SUBHARMONIC_ORDERS`), on the
    same pixels, is no object of its own, or None: the stronger line's fundamental it is not (it stands
    below :data:`FUNDAMENTAL_SHARE` of it, :func:`_fundamental`), so it is a faint modulation of that
    motion (a motor's trace at half its rate), not another one."""
    f = cand.peak.frequency_hz
    for c in kept:
        for n in SUBHARMONIC_ORDERS:
            if abs(c.peak.frequency_hz - n * f) > max(HARMONIC_TOLERANCE * n * f, 1.5 * scan.bin_hz):
                continue
            if shared_region(cand.region, c.region):
                f0 = c.peak.frequency_hz
                return RejectedPeak(
                    f,
                    f"{f:.4g} Hz is a faint trace at 1/{n} of the motion at {f0:.4g} Hz, on the same pixels",
                    "harmonic",
                    figures={"fundamental_hz": f0, "order": 1.0 / n},
                )
    return None


def _leakage(cand: Candidate, kept: list[Candidate], bin_hz: float) -> bool:
    """Whether ``cand`` is the spectral leakage of a far stronger candidate a few lines away on the same
    pixels: within :data:`LEAKAGE_BINS` of it and below :data:`LEAKAGE_LEVEL` of its statistic (the
    tapered window's side lobes there)."""
    f = cand.peak.frequency_hz
    return any(
        abs(f - c.peak.frequency_hz) <= LEAKAGE_BINS * bin_hz
        and cand.peak.power <= LEAKAGE_LEVEL * c.peak.power
        and shared_region(cand.region, c.region)
        for c in kept
    )


def _known(f: float, kept: list[Candidate], bin_hz: float) -> bool:
    """Whether ``f`` is one of the candidates' frequencies or harmonics (within their width)."""
    for c in kept:
        if abs(f - c.peak.frequency_hz) <= max(1.5, c.peak.width_bins) * bin_hz:
            return True
        if any(abs(f - h) <= 1.5 * bin_hz for h in c.peak.harmonics_hz):
            return True
    return False


def _as_harmonic(cand: Candidate, kept: list[Candidate], scan: MotionScan) -> bool:
    """Fold ``cand`` into the kept candidate it is most nearly an overtone of on the same pixels: its
    pixels also move significantly at that candidate's frequency (or the two regions overlap)."""
    f = cand.peak.frequency_hz
    own: MotionScan | None = None
    matches = []
    for c in kept:
        order, error = _overtone_of(
            f, c.peak.frequency_hz, sample_rate_hz=scan.sample_rate_hz, bin_hz=scan.bin_hz
        )
        if order:
            matches.append((error, order, c))
    for _, order, c in sorted(matches, key=lambda m: m[0]):
        if not shared_region(cand.region, c.region):
            if own is None:
                try:
                    own = scan.within(cand.region)
                except ValueError:
                    return False
            z = own.z_at(c.peak.frequency_hz, half_width_bins=1.0)
            if float(own.calibration.p_frequency(z)) > MAX_FALSE_ALARM:
                continue
        if order > 1:  # an overtone; an image of the motion itself is no overtone of it
            c.peak.harmonics_hz.append(f)
        return True
    return False


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
        verdict = significance_verdict(obj, scan, region=None if footing is None else footing.held > 0)
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
        index = base.id - 1
        if not 0 <= index < len(seg.peaks):
            continue
        f0 = base.eigenfrequency_hz
        for order in range(1, rules.max_order + 1):
            same = [(f0, "")] if order == 1 else []
            folded = images_of(
                f0, order, sample_rate_hz=sample_rate_hz, max_folded_order=rules.max_folded_order
            )
            where, figures = "on the same pixels", {"fundamental_hz": f0}
            for image, how in same + folded:
                if abs(f - image) > slack:
                    continue
                if order == 1 and not how:
                    if not touching(region, seg.labels == base.id):
                        if not faint_copy(obj, base, sample_rate_hz=sample_rate_hz):
                            continue  # the same frequency elsewhere: another object
                        share = (obj.amplitude_px or 0.0) / (base.amplitude_px or 1.0)
                        where = f"seen elsewhere, a copy in step with it at {share:.2%} of its amplitude"
                        figures["amplitude_share"] = share
                elif float(np.median(seg.band_power[index][region])) < rules.shared_power * own_power:
                    continue  # its pixels do not move at the stronger object's frequency: another object
                break
            else:
                continue
            what = (
                "the motion"
                if order == 1 and not how
                else ("an image" if order == 1 else f"overtone {order}")
            )
            return RejectedPeak(
                f,
                f"{f:.4g} Hz is {what} of the object at {f0:.4g} Hz, {where}{how}",
                "harmonic",
                figures={**figures, "order": float(order)},
            )
    return None


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
    "SURVEY_PEAKS",
    "Candidate",
    "Candidates",
    "Footing",
    "OvertoneRules",
    "clip_regime",
    "drop_objects",
    "find_candidates",
    "folded_image",
    "folded_verdicts",
    "held_verdict",
    "judge_objects",
    "oscillation_verdict",
    "shared_region",
    "significance_verdict",
    "significant_bins",
    "touching",
]
