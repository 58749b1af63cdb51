"""Which motions may be objects: the candidates of one detection statistic.

An object is a region whose motion has a coherent, narrow-band oscillation. One statistic decides for
every regime: the scan statistic of :mod:`workers.pipeline.significance`, whose false-alarm probability
per clip is measured on the clip itself. :func:`find_candidates` takes its significant peaks (at most
:data:`~workers.pipeline.significance.MAX_FALSE_ALARM`), strongest first, each with the region where the
picture moves at it; an overtone on the same pixels as a stronger peak is that peak's harmonic, and a
peak whose fundamental (half, a third, a quarter of it) moves the same pixels significantly is that
fundamental's overtone (a rotating wheel's rate, not its second harmonic); a comb of lines at the
multiples of one frequency is that frequency.

Each candidate is then measured (:mod:`workers.pipeline.measure`), and :mod:`workers.pipeline.verdicts`
says which measured motions are objects and why the others are not.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.model import RejectedPeak
from workers.pipeline.peaks import Peak, PeakPolicy, folded, interpolate_peak
from workers.pipeline.significance import CONTRAST_WIDTH_BINS, MAX_FALSE_ALARM, MotionScan

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
        image = folded(multiple, rate)
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


__all__ = [
    "SURVEY_PEAKS",
    "Candidate",
    "Candidates",
    "find_candidates",
    "images_of",
    "shared_region",
    "significant_bins",
]
