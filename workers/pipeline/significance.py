"""One detection statistic for every regime, with a stated false-alarm probability.

Is anything oscillating at frequency f, anywhere in the picture? :func:`motion_scan` answers with a scan
statistic over the whole frame, computed on the *constrained flow* z = J^(1/2) u
(:mod:`workers.pipeline.confidence`: flat, clipped or codec-blocked pixels carry no weight):

1. z's spectra are pooled coherently over square blocks of 1, 2, 4, 8 and 16 grid pixels (the levels of
   an area-averaging pyramid) and over strips one pixel wide and 8 or 16 long, upright and lying
   (:data:`STRIPS`: along a thin object's edge): parts of a rigid object moving in phase add up, the
   smallest block is one pixel;
2. each block's power spectrum is normalised twice: by the block's own level (a low percentile of its
   power over the band, robust to its own peak) and by the spectral colour of the noise (the median
   block's normalised power at each frequency, smoothed over frequency: broad, so that a line, even one
   a surface filling the picture makes, stays a line);
3. ``T(f)`` is the largest normalised power over every block of every size at f. Its *line contrast*
   (T over its neighbours' in frequency, :func:`line_contrast`) says whether a peak is a narrow-band
   line, what an oscillation is: a strongly moving object's broadband flow errors lift whole stretches
   of the spectrum at once (:mod:`workers.pipeline.detection` asks both).

Under "nothing moves here", T at one frequency is the maximum of many correlated, heavy-tailed noise
values. Its distribution is measured on the clip itself, from every frequency of the band (the
surrogates): log T is fitted by a Gumbel law, robustly (frequencies that stand out, and those known to be
artefacts such as a codec's keyframe comb, are left out of the fit; :mod:`workers.pipeline.calibration`).
The fit gives each frequency's standardised height ``z`` and its false-alarm probability; the probability
*per clip* allows for every frequency searched (``Calibration.bins_searched``).
``bench/null_corpus.py`` measures the rate on still scenes through H.264 and MPEG-4 and on still crops of
real footage, where it is calibrated or conservative (77 clips: no false object; at stated rates of 0.05 to
0.5, measured 0.026 to 0.195, the codecs' keyframe combs set aside as artefacts);
``bench/calibration.py`` on simulated noise independent from bin to bin, where the stated rate is
optimistic (the scan's statistic is not independent from bin to bin, and lines must pass
:func:`~workers.pipeline.detection.significant_bins`'s criteria before a probability is stated).

An object is reported when its false-alarm probability per clip is at most :data:`MAX_FALSE_ALARM`
(:mod:`workers.pipeline.detection`).
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.calibration import Calibration, fit_calibration
from workers.pipeline.confidence import Confidence, mixed_pair, tensor_sqrt
from workers.pipeline.peaks import nanmedian_over_time, noise_floor

#: An object is reported when the probability that noise alone gives a peak as high, anywhere in the
#: clip's band, is at most this.
MAX_FALSE_ALARM = 1e-3
#: Pyramid levels pooled (blocks of 2**level grid pixels a side) for a grid about 160 pixels wide; one
#: more for each doubling of the width.
LEVELS = 5
#: Lengths (grid pixels) of the strips also pooled, one pixel wide, upright and lying: a thin object's
#: edge (a bar, a string, a rod 1 or 2 grid pixels wide) fills a strip along it, where a square block of
#: the same area holds mostly the background's noise. (Each shape pooled adds noise's chances to the
#: largest of all: strips of 4 lifted the law more than the edges they pool; on a thin bar moving 0.2 px
#: through MPEG-4, z was 11.4 without strips, 11.8 with 4, 8 and 16, 13.5 with 8 and 16.)
STRIPS = (8, 16)
#: A single pixel counts when its confidence weight is at least this (it holds texture); a block of side s
#: when its textured pixels (their weight summed) are at least this times s: a thin edge across it.
MIN_BLOCK_WEIGHT = 0.3
#: A block's own level: this percentile of its power over the band's frequencies.
BLOCK_LEVEL_PERCENTILE = 30.0
#: The statistic is calibrated on at least this many of the window's frequencies.
MIN_BINS = 8
#: The picture is cut into TILES x TILES tiles; each tile at each frequency is one sample of the fit.
TILES = 4
#: The noise colour is smoothed over this many frequencies (odd).
COLOUR_WIDTH_BINS = 9
#: A line's contrast is T over the median of the frequencies 2 to this many bins away on either side.
CONTRAST_WIDTH_BINS = 8
#: A region at a frequency holds every connected part peaking at this share of the strongest pixel.
REGION_SHARE = 0.02
#: The flow is tapered by a Tukey window with this fraction of it in cosine lobes (0: none; 1: Hann).
TAPER_ALPHA = 0.5
#: Frequencies per block of work (bounds the working memory of one pass).
_CHUNK = 64
#: Threads pooling the scan's chunks of frequencies (one per core of the machine it was sized for).
POOL_THREADS = 2
#: Most memory the scan's spectra take at once, MiB (the band of a 1000-frame window on the 160 x 105 grid
#: is 126 MiB, one group; a 3000-frame window's 380 MiB is transformed in three).
SPECTRA_BUDGET_MIB = 160.0
#: Flow columns (pixel components) tapered and transformed at a time: a block stays in cache, and only
#: the band's bins of its spectra are kept.
_COLUMNS = 4096


@dataclass
class _Level:
    """One pyramid level: which blocks count, their raw power, own levels and the noise colour."""

    level: int
    shape: tuple[int, int]
    positions: NDArray[np.intp]  # flattened indices (at this level) of the blocks that count
    raw: NDArray[np.float32]  # (B, P) power of the counted blocks' mean z
    own: NDArray[np.float32]  # (P,) each block's own level
    colour: NDArray[np.float32]  # (B,) the median block's normalised power per band bin
    block: tuple[int, int] = (1, 1)  # grid pixels per block (rows, columns)

    def power(self, bins: slice | NDArray[np.intp]) -> NDArray[np.float32]:
        """Normalised power (len(bins), P) of the blocks that count."""
        return np.asarray(self.raw[bins] / self.own[None, :] / self.colour[bins][:, None], np.float32)

    def subset(self, inside: NDArray[np.bool_]) -> _Level:
        """The level with only the counted blocks where ``inside`` (per counted block) holds."""
        return replace(self, positions=self.positions[inside], raw=self.raw[:, inside], own=self.own[inside])


@dataclass(frozen=True)
class MotionScan:
    """The scan statistic of a window (see the module's description).

    Attributes
    ----------
    frequencies_hz : ndarray of float64, shape (B,)
        The band's frequencies (bins of the window's transform).
    statistic : ndarray of float64, shape (B,)
        T per frequency.
    contrast : ndarray of float64, shape (B,)
        T over its neighbours' in frequency (:func:`line_contrast`).
    z : ndarray of float64, shape (B,)
        Standardised height of log T over the fitted law.
    calibration : Calibration
    best_level : ndarray of int64, shape (B,)
        Which of the pooled block shapes gave T (square blocks of ``2 ** level`` grid pixels for the
        first :func:`pyramid_levels`, then the strips, :data:`STRIPS`).
    best_position : ndarray of int64, shape (B,)
        Flattened grid index of that block's centre.
    grid_shape : (h, w)
    sample_rate_hz : float
    """

    frequencies_hz: NDArray[np.float64]
    statistic: NDArray[np.float64]
    contrast: NDArray[np.float64]
    z: NDArray[np.float64]
    calibration: Calibration
    best_level: NDArray[np.int64]
    best_position: NDArray[np.int64]
    grid_shape: tuple[int, int]
    sample_rate_hz: float
    _levels: list[_Level] = field(repr=False)
    search_hz: tuple[float, float] = (0.0, math.inf)

    @property
    def searched(self) -> NDArray[np.bool_]:
        """Which of the band's bins are searched for objects (the others only calibrate)."""
        lo, hi = self.search_hz
        return np.asarray((self.frequencies_hz >= lo) & (self.frequencies_hz <= hi), bool)

    @property
    def bin_hz(self) -> float:
        return float(self.frequencies_hz[1] - self.frequencies_hz[0]) if len(self.frequencies_hz) > 1 else 1.0

    def statistic_at(self, frequency_hz: float) -> float:
        """T at the band's bin nearest ``frequency_hz`` (0 outside the band)."""
        if not len(self.frequencies_hz) or not (
            self.frequencies_hz[0] - self.bin_hz <= frequency_hz <= self.frequencies_hz[-1] + self.bin_hz
        ):
            return 0.0
        return float(self.statistic[int(np.argmin(np.abs(self.frequencies_hz - frequency_hz)))])

    def near(self, frequency_hz: float, *, half_width_bins: float = 1.5) -> NDArray[np.intp]:
        """Band bins within ``half_width_bins`` of ``frequency_hz`` (at least the nearest one)."""
        gap = np.abs(self.frequencies_hz - frequency_hz)
        near = np.flatnonzero(gap <= half_width_bins * self.bin_hz)
        return near if near.size else np.array([int(np.argmin(gap))], np.intp)

    def peak_bin(self, frequency_hz: float, *, half_width_bins: float = 1.5) -> int:
        """The bin of the highest T within ``half_width_bins`` of ``frequency_hz``."""
        near = self.near(frequency_hz, half_width_bins=half_width_bins)
        return int(near[np.argmax(self.statistic[near])])

    def z_at(self, frequency_hz: float, *, half_width_bins: float = 1.5) -> float:
        """The highest z within ``half_width_bins`` of ``frequency_hz``."""
        return float(self.z[self.peak_bin(frequency_hz, half_width_bins=half_width_bins)])

    def false_alarm(self, frequency_hz: float, *, half_width_bins: float = 1.5) -> float:
        """False-alarm probability per clip of the peak near ``frequency_hz``."""
        return float(self.calibration.p_clip(self.z_at(frequency_hz, half_width_bins=half_width_bins)))

    def power_map(self, bin_index: int, level: int = 0) -> NDArray[np.float32]:
        """Normalised power of every block of ``level`` at band bin ``bin_index``, upsampled to the grid
        (0 where a block does not count)."""
        lv = self._levels[level]
        values = np.zeros(lv.shape[0] * lv.shape[1], np.float32)
        values[lv.positions] = lv.power(np.array([bin_index]))[0]
        small = values.reshape(lv.shape)
        if lv.shape == self.grid_shape:
            return small
        h, w = self.grid_shape
        return np.asarray(cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST), np.float32)

    def region(self, frequency_hz: float, *, level: float = 6.0) -> NDArray[np.bool_]:
        """Where the picture moves at ``frequency_hz``: at the peak's bin and the bins beside it (two
        objects a line apart share one peak), the grid pixels whose single-pixel normalised power exceeds
        ``level``, in the connected parts that touch the best block or peak at twice ``level`` and
        :data:`REGION_SHARE` of that bin's strongest (a weaker object at the same frequency elsewhere: the
        second pass and its segmentation see it too); with the best block itself.

        Returns
        -------
        ndarray of bool, shape (h, w)
        """
        k = self.peak_bin(frequency_hz)
        h, w = self.grid_shape
        block = np.zeros((h, w), bool)
        rows, cols = self._levels[int(self.best_level[k])].block
        cy, cx = divmod(int(self.best_position[k]), w)
        ry, rx = max(rows // 2, 1), max(cols // 2, 1)
        block[max(0, cy - ry) : cy + ry + 1, max(0, cx - rx) : cx + rx + 1] = True
        mask = block.copy() if rows * cols > 1 else np.zeros((h, w), bool)
        for j in range(max(0, k - 1), min(len(self.frequencies_hz), k + 2)):
            q = self.power_map(j, 0)
            strong = q >= level
            count, parts = cv2.connectedComponents(strong.astype(np.uint8), connectivity=8)
            peak = np.zeros(count)
            np.maximum.at(peak, parts.ravel(), q.ravel())
            keep = peak >= max(2 * level, REGION_SHARE * float(q.max()))
            if j == k:
                keep[np.unique(parts[block])] = True
                mask |= block & strong
            keep[0] = False
            mask |= keep[parts]
        return mask

    def frequency_map(self, *, level: float = 8.0) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
        """Each grid pixel's dominant frequency and whether it stands out: its single-pixel normalised
        power peaks above ``level`` there (pixels without texture never do).

        Returns
        -------
        frequency_hz : ndarray of float32, shape (h, w)
        valid : ndarray of bool, shape (h, w)
        """
        lv = self._levels[0]
        h, w = self.grid_shape
        freq = np.zeros(h * w, np.float32)
        valid = np.zeros(h * w, bool)
        if lv.positions.size:
            best = np.zeros(lv.positions.size, np.float32)
            arg = np.zeros(lv.positions.size, np.intp)
            for k in range(0, len(self.frequencies_hz), _CHUNK):
                power = lv.power(slice(k, k + _CHUNK))
                j = np.argmax(power, axis=0)
                top = power[j, np.arange(power.shape[1])]
                better = top > best
                best[better], arg[better] = top[better], j[better] + k
            freq[lv.positions] = self.frequencies_hz[arg]
            valid[lv.positions] = best > level
        return freq.reshape(h, w), valid.reshape(h, w)

    def localised_share(self, frequency_hz: float, region: NDArray[np.bool_]) -> float:
        """How much the picture's excess power at ``frequency_hz`` (single pixels, above 1) concentrates
        in ``region``, beyond what its share of the picture's texture would hold were the power spread
        evenly: 1 when all of it is there, 0 or less when it is all over the picture (a codec's pulse,
        flicker, the camera); 0 for a region that holds most of the picture's texture (it is no one
        place)."""
        excess = np.maximum(self.power_map(self.peak_bin(frequency_hz), 0) - 1.0, 0.0)
        total = float(excess.sum())
        if total <= 0:
            return 0.0
        textured = self._levels[0]
        counted = np.zeros(excess.size, bool)
        counted[textured.positions] = True
        spread = float((counted & region.ravel()).sum()) / max(int(counted.sum()), 1)
        if spread > 0.5:
            return 0.0
        share = float(excess[region].sum() / total)
        return (share - spread) / (1.0 - spread)

    def within(self, mask: NDArray[np.bool_]) -> MotionScan:
        """The same scan over the blocks whose centre lies in ``mask`` only (a region's own statistic),
        judged by the picture's law: a region's largest block is no larger than the picture's, so its z
        and probabilities are conservative.

        Raises
        ------
        ValueError
            When the mask holds no block that counts.
        """
        levels: list[_Level] = []
        for lv in self._levels:
            small = cv2.resize(
                mask.astype(np.uint8), (lv.shape[1], lv.shape[0]), interpolation=cv2.INTER_AREA
            )
            levels.append(lv.subset(small.ravel()[lv.positions] > 0))
        if not any(lv.positions.size for lv in levels):
            raise ValueError("within: the mask holds no block that counts")
        return _finish(
            levels,
            frequencies_hz=self.frequencies_hz,
            grid_shape=self.grid_shape,
            sample_rate_hz=self.sample_rate_hz,
            calibration=self.calibration,
            search_hz=self.search_hz,
        )


def pyramid_levels(width_px: int) -> int:
    """Levels pooled on a grid ``width_px`` wide (:data:`LEVELS` at 160 pixels)."""
    return max(1, LEVELS + round(math.log2(max(width_px, 1) / 160.0)))


def motion_scan(
    flow: NDArray[np.float32],
    confidence: Confidence,
    *,
    sample_rate_hz: float,
    band_hz: tuple[float, float],
    exclude_hz: Sequence[float] = (),
    levels: int | None = None,
    search_hz: tuple[float, float] | None = None,
) -> MotionScan:
    """The scan statistic of a window of flow (see the module's description).

    Parameters
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
        Flow maps, grid pixels per sample.
    confidence : Confidence
        Of the window's mean grey frame on the same grid.
    sample_rate_hz : float
        Rate of the flow maps.
    band_hz : (low, high)
        Frequencies scanned: the calibration's surrogates.
    exclude_hz : sequence of float
        Frequencies known to be artefacts (a codec's keyframe comb, lighting flicker): left out of the fit.
    levels : int, optional
        Pyramid levels pooled; default :func:`pyramid_levels` of the grid's width.
    search_hz : (low, high), optional
        Frequencies searched for objects, within ``band_hz`` (default: all of it): a narrow band the user
        asked for is searched, and calibrated on the whole band the window shows (the per-clip
        probability allows for the searched frequencies only).

    Returns
    -------
    MotionScan

    Raises
    ------
    ValueError
        When the band holds fewer than :data:`MIN_BINS` of the window's frequencies, or the grids differ.
        (A picture without texture anywhere gives a statistic of 0 everywhere: nothing stands out.)
    """
    n, h, w = flow.shape[:3]
    if (h, w) != confidence.shape:
        raise ValueError(f"motion_scan: flow grid {(h, w)} is not the confidence's {confidence.shape}")
    freqs = np.fft.rfftfreq(n, d=1.0 / sample_rate_hz)
    inside = np.flatnonzero((freqs >= band_hz[0]) & (freqs <= band_hz[1]) & (freqs > 0))
    if inside.size < MIN_BINS:
        raise ValueError(
            f"motion_scan: the band [{band_hz[0]:.3g}, {band_hz[1]:.3g}] Hz holds {inside.size} of the "
            "window's frequencies; analyse more frames or widen the band"
        )
    levels_list = _pooled_levels(flow, confidence, bins=inside, levels=levels or pyramid_levels(w))
    return _finish(
        levels_list,
        frequencies_hz=np.asarray(freqs[inside], np.float64),
        grid_shape=(h, w),
        sample_rate_hz=sample_rate_hz,
        exclude_hz=exclude_hz,
        search_hz=search_hz or band_hz,
    )


def constrained_spectra(spectra: NDArray[np.complex64], confidence: Confidence) -> NDArray[np.float32]:
    """Spectra of the constrained flow z = J^(1/2) u from the flow's own.

    J is the same in every frame, so z's spectra are J^(1/2) times the flow's.

    Parameters
    ----------
    spectra : ndarray of complex64, shape (B, h, w, 2)
        The flow's spectra (u and v) at B frequencies.
    confidence : Confidence

    Returns
    -------
    ndarray of float32, shape (B, h, w, 4)
        Real and imaginary parts of z's x component, then of its y component.
    """
    # complex arithmetic on the two planes (real and imaginary parts together) is several times faster
    # than on interleaved real views
    zx, zy = mixed_pair(spectra[..., 0], spectra[..., 1], *tensor_sqrt(confidence))
    return np.stack([zx, zy], axis=-1).view(np.float32)


#: Blocks sampled over the whole picture (textured or not) per level for the noise's spectral colour.
_COLOUR_SAMPLE = 1024


def _block_shapes(grid_shape: tuple[int, int], levels: int) -> list[tuple[int, int]]:
    """The blocks pooled, as (rows, columns) of grid pixels: squares of 1, 2, 4, ... (``levels`` of them,
    fewer on a small grid), then the :data:`STRIPS` that fit the grid."""
    h, w = grid_shape
    shapes = [(1, 1)]
    for level in range(1, levels):
        side = 1 << level
        if min(h, w) // (side // 2) < 12:
            break
        shapes.append((side, side))
    for length in STRIPS:
        for rows, cols in ((length, 1), (1, length)):
            if h // rows >= 6 and w // cols >= 6:
                shapes.append((rows, cols))
    return shapes


def _pool(
    values: NDArray[np.float32], block: tuple[int, int], *, out: NDArray[np.float32] | None = None
) -> NDArray[np.float32]:
    """Means over blocks of ``block`` grid pixels (area averaging) of (h, w) or (h, w, c), into ``out``
    when given (of the pooled shape)."""
    rows, cols = block
    if rows == cols == 1:
        return values
    h, w = values.shape[:2]
    size = (max(w // cols, 1), max(h // rows, 1))
    return np.asarray(cv2.resize(values, size, dst=out, interpolation=cv2.INTER_AREA), np.float32)


def _level_positions(
    weight: NDArray[np.float32], blocks: list[tuple[int, int]]
) -> list[tuple[tuple[int, int], NDArray[np.intp], NDArray[np.intp]]]:
    """Each block shape's grid, the blocks that count there (textured, away from the picture's border),
    and a sample of all its blocks away from the border (for the noise colour: an object may be most of
    the textured blocks, never most of the picture). A block counts when its mean weight is
    :data:`MIN_BLOCK_WEIGHT` over the square root of its area (an edge crossing it)."""
    out: list[tuple[tuple[int, int], NDArray[np.intp], NDArray[np.intp]]] = []
    for block in blocks:
        wt = _pool(weight, block)
        interior = np.zeros(wt.shape, bool)
        edge = 2 if block == (1, 1) else 1
        interior[edge:-edge, edge:-edge] = True
        bound = MIN_BLOCK_WEIGHT / math.sqrt(block[0] * block[1])
        counted = np.flatnonzero((interior & (wt >= bound)).ravel())
        every = np.flatnonzero(interior.ravel())
        sample = every[:: max(1, every.size // _COLOUR_SAMPLE)]
        out.append(((int(wt.shape[0]), int(wt.shape[1])), counted, sample))
    return out


def _pooled_levels(
    flow: NDArray[np.float32], confidence: Confidence, *, bins: NDArray[np.intp], levels: int
) -> list[_Level]:
    """The raw power of every counted block of every shape at the given bins, a block of frequencies at
    a time (z's spectra, then their means over each block), with the blocks' own levels and the noise
    colour. The band's spectra are held :data:`SPECTRA_BUDGET_MIB` at a time: a longer window's band is
    transformed in groups of frequencies, one pass of the FFT over the flow each."""
    n, h, w = flow.shape[:3]
    series = flow.reshape(n, -1)
    taper = tukey(n, TAPER_ALPHA)
    shapes = _block_shapes((h, w), levels)
    grids = _level_positions(confidence.weight, shapes)
    raw = [np.empty((len(bins), pos.size), np.float32) for _, pos, _ in grids]
    sampled = [np.empty((len(bins), smp.size), np.float32) for _, _, smp in grids]
    per_bin = series.shape[1] * np.dtype(np.complex64).itemsize
    group = max(_CHUNK, int(SPECTRA_BUDGET_MIB * 2**20 // per_bin) // _CHUNK * _CHUNK)

    def pool_chunk(spectra: NDArray[np.complex64], first: int, size: int, k: int) -> None:
        chunk = spectra[k : k + size].reshape(-1, h, w, 2)
        z = constrained_spectra(chunk, confidence)
        rows = slice(first + k, first + k + len(z))
        pooled = [
            z if block == (1, 1) else np.empty((len(z), *shape, 4), np.float32)
            for block, (shape, _, _) in zip(shapes, grids, strict=True)
        ]
        for b in range(len(z)):  # every shape of one frequency's map while it is in the cache
            for block, out in zip(shapes, pooled, strict=True):
                if block != (1, 1):
                    _pool(z[b], block, out=out[b])
        for level, ((shape, positions, sample), blocks) in enumerate(zip(grids, pooled, strict=True)):
            flat = blocks.reshape(len(z), shape[0] * shape[1], 4)
            # every block's power, then the counted ones' (gathering powers moves a quarter of the bytes)
            power = np.einsum("bpc,bpc->bp", flat, flat)
            raw[level][rows] = power[:, positions]
            sampled[level][rows] = power[:, sample]

    # chunks of frequencies are independent and write their own rows (numpy and OpenCV release the GIL)
    with ThreadPoolExecutor(max_workers=POOL_THREADS, thread_name_prefix="scan") as pool:

        def pool_group(first: int) -> None:  # the group's spectra are let go before the next one's
            spectra = _band_spectra(series, taper, bins[first : first + group], map_blocks=pool.map)
            # a short window's few frequencies are shared between the threads too
            size = min(_CHUNK, -(-len(spectra) // POOL_THREADS))
            list(pool.map(functools.partial(pool_chunk, spectra, first, size), range(0, len(spectra), size)))

        for first in range(0, len(bins), group):
            pool_group(first)

        def summarised(level: int) -> _Level:
            shape, positions, _ = grids[level]
            found = _summarised(level, shape, positions, raw[level], colour_of(sampled[level]))
            return replace(found, block=shapes[level])

        return list(pool.map(summarised, range(len(shapes))))  # the levels' percentiles, side by side


def _band_spectra(
    series: NDArray[np.float32],
    taper: NDArray[np.float32],
    bins: NDArray[np.intp],
    *,
    map_blocks: Callable[..., Iterator[None]] = map,
) -> NDArray[np.complex64]:
    """The tapered ``series``' (N, C) spectra at ``bins``: (B, C), a block of columns at a time (a block
    stays in cache, and only those bins of its spectra are kept); the blocks are independent, shared out
    by ``map_blocks`` (a thread pool's ``map``: numpy and the FFT release the GIL)."""
    from scipy import fft

    spectra = np.empty((len(bins), series.shape[1]), np.complex64)
    kept = threading.local()  # each thread's tapered block, kept from block to block

    def block(c: int) -> None:
        columns = series[:, c : c + _COLUMNS]
        if not hasattr(kept, "tapered"):
            kept.tapered = np.empty((len(series), min(_COLUMNS, series.shape[1])), np.float32)
        tapered = _tapered(columns, taper, out=kept.tapered[:, : columns.shape[1]])
        spectra[:, c : c + _COLUMNS] = fft.rfft(tapered, axis=0)[bins]

    list(map_blocks(block, range(0, series.shape[1], _COLUMNS)))
    return spectra


def tukey(n: int, alpha: float) -> NDArray[np.float32]:
    """The Tukey window of ``n`` samples with the fraction ``alpha`` of it in cosine lobes (as
    ``scipy.signal.windows.tukey(n, alpha)``, whose import alone costs a command-line run most of a
    second)."""
    if n < 2 or alpha <= 0:
        return np.ones(n, np.float32)
    x = np.linspace(0.0, 1.0, n)
    edge = min(alpha, 1.0) / 2
    taper = np.ones(n)
    rising, falling = x < edge, x > 1 - edge
    taper[rising] = 0.5 * (1 + np.cos(np.pi * (x[rising] / edge - 1)))
    taper[falling] = 0.5 * (1 + np.cos(np.pi * ((x[falling] - 1) / edge + 1)))
    return taper.astype(np.float32)


def _tapered(
    series: NDArray[np.float32], taper: NDArray[np.float32], *, out: NDArray[np.float32] | None = None
) -> NDArray[np.float32]:
    """``series`` (N, C) times ``taper`` (N,), each column's taper-weighted mean removed first.

    A pixel's steady flow (a turning wheel's rim, a drifting camera's bias) is no oscillation; tapered
    with its mean, it becomes the taper's own spectrum, whose low bins stand far above any line there (a
    wheel's turning rate sat beside a skirt 7 times higher). Removing the mean weighted by the taper makes
    a constant vanish exactly. (Removing a straight line as well changed which of a narrow-band random
    motion's peaks the coherence gate saw, and let one through: the level is removed, not the drift.)
    Written into ``out`` (N, C) when given."""
    level = (taper @ series) / float(taper.sum())
    out = np.subtract(series, level[None, :], out=out)
    out *= taper[:, None]
    return out


def _own_levels(raw: NDArray[np.float32]) -> NDArray[np.float32]:
    """Each block's own level: the :data:`BLOCK_LEVEL_PERCENTILE` percentile of its power over the band
    (robust to its own peak). ``raw`` is (B, P)."""
    bins = raw.shape[0]
    by_block = np.ascontiguousarray(raw.T)  # percentiles along a contiguous axis
    q = max(0, min(bins - 1, round(BLOCK_LEVEL_PERCENTILE / 100 * (bins - 1))))
    return np.asarray(np.partition(by_block, q, axis=1)[:, q] + np.float32(1e-30), np.float32)


def colour_of(raw: NDArray[np.float32]) -> NDArray[np.float32]:
    """The noise's spectral colour (B,): the median block's power over its own level at each frequency,
    smoothed over frequency by a running median (the noise's colour is broad; a motion, even one that
    fills the picture, and a codec's comb are narrow lines, which it keeps out)."""
    bins = raw.shape[0]
    if raw.shape[1] == 0:
        return np.ones(bins, np.float32)
    median = np.median(raw / _own_levels(raw)[None, :], axis=1)
    smooth = noise_floor(median, width=COLOUR_WIDTH_BINS)
    return np.asarray(smooth + 1e-30, np.float32)


def _summarised(
    level: int,
    shape: tuple[int, int],
    positions: NDArray[np.intp],
    raw: NDArray[np.float32],
    colour: NDArray[np.float32],
) -> _Level:
    """A level with its counted blocks' own levels and the noise colour."""
    if positions.size == 0:
        return _Level(level, shape, positions, raw, np.ones(0, np.float32), colour)
    return _Level(level, shape, positions, raw, _own_levels(raw), colour)


@dataclass(frozen=True)
class _LevelPeaks:
    """One level's largest normalised power at each frequency, where it lies, and each tile's largest.

    Attributes
    ----------
    peak : ndarray of float32, shape (B,)
    position : ndarray of int64, shape (B,)
        Flattened grid index of the centre of the block holding ``peak``.
    tiles : ndarray of intp, shape (T,)
        The tiles the level's counted blocks lie in.
    tile_peak : ndarray of float32, shape (T, B)
        The largest power of each of those tiles' blocks at each frequency.
    """

    peak: NDArray[np.float32]
    position: NDArray[np.int64]
    tiles: NDArray[np.intp]
    tile_peak: NDArray[np.float32]


def _level_peaks(lv: _Level, *, grid_shape: tuple[int, int], bins: int) -> _LevelPeaks | None:
    """The level's peaks (:class:`_LevelPeaks`), a chunk of frequencies at a time; None when no block of
    it counts."""
    if not lv.positions.size:
        return None
    h, w = grid_shape
    centres = _centres(lv, grid_shape)
    cy, cx = np.divmod(centres, w)
    tile_of = (cy * TILES // h) * TILES + cx * TILES // w
    # the blocks in order of their tile, and where each tile's run starts: one gather and one reduction
    # a chunk give every tile's largest power
    by_tile = np.argsort(tile_of, kind="stable")
    present, starts = np.unique(tile_of[by_tile], return_index=True)
    peak = np.empty(bins, np.float32)
    position = np.empty(bins, np.int64)
    tile_peak = np.empty((len(present), bins), np.float32)
    for k in range(0, bins, _CHUNK):
        power = lv.power(slice(k, k + _CHUNK))
        j = np.argmax(power, axis=1)
        rows = slice(k, k + len(power))
        peak[rows] = power[np.arange(len(j)), j]
        position[rows] = centres[j]
        tile_peak[:, rows] = np.maximum.reduceat(power[:, by_tile], starts, axis=1).T
    return _LevelPeaks(peak, position, present.astype(np.intp), tile_peak)


def _finish(
    levels: list[_Level],
    *,
    frequencies_hz: NDArray[np.float64],
    grid_shape: tuple[int, int],
    sample_rate_hz: float,
    exclude_hz: Sequence[float] = (),
    calibration: Calibration | None = None,
    search_hz: tuple[float, float] = (0.0, math.inf),
) -> MotionScan:
    """T per frequency over every counted block of every level (and per tile of the picture), and its
    calibration (fitted, unless given)."""
    bins = len(frequencies_hz)
    searched = int(((frequencies_hz >= search_hz[0]) & (frequencies_hz <= search_hz[1])).sum())
    statistic = np.zeros(bins)
    tiles = np.zeros((TILES * TILES, bins))
    best_level = np.zeros(bins, np.int64)
    best_position = np.zeros(bins, np.int64)
    with ThreadPoolExecutor(max_workers=POOL_THREADS, thread_name_prefix="scan") as pool:
        found = list(pool.map(functools.partial(_level_peaks, grid_shape=grid_shape, bins=bins), levels))
    # in the levels' order: a tie goes to the earlier level, as it did chunk by chunk
    for lv, peaks in zip(levels, found, strict=True):
        if peaks is None:
            continue
        better = peaks.peak > statistic
        statistic[better] = peaks.peak[better]
        best_level[better] = lv.level
        best_position[better] = peaks.position[better]
        tiles[peaks.tiles] = np.maximum(tiles[peaks.tiles], peaks.tile_peak)
    if not statistic.any():
        # No part of the picture has texture enough to show motion: nothing can stand out.
        calibration = Calibration(location=0.0, scale=1.0, bins_fitted=0, bins_searched=searched)
    if calibration is None:
        calibration = fit_calibration(
            statistic, frequencies_hz=frequencies_hz, exclude_hz=exclude_hz, tiles=tiles[tiles.any(axis=1)]
        )
        calibration = replace(calibration, bins_searched=searched)
    return MotionScan(
        frequencies_hz=frequencies_hz,
        statistic=statistic,
        contrast=line_contrast(statistic),
        z=calibration.z(statistic),
        calibration=calibration,
        best_level=best_level,
        best_position=best_position,
        grid_shape=grid_shape,
        sample_rate_hz=sample_rate_hz,
        _levels=levels,
        search_hz=search_hz,
    )


def line_contrast(statistic: NDArray[np.float64]) -> NDArray[np.float64]:
    """How far T stands above its neighbours in frequency: T over the median of the frequencies 2 to
    :data:`CONTRAST_WIDTH_BINS` bins away on either side (fewer at the band's edges; the peak's own bin and
    its neighbours are left out, so that a line does not lift its own floor). An object is a narrow-band
    line; a strongly moving object's broadband flow errors, or a codec's broad noise, lift whole stretches
    of frequencies at once and stand out of nothing."""
    t = np.asarray(statistic, np.float64)
    log_t = np.log(np.maximum(t, 1e-30))
    bins = len(t)
    reach = CONTRAST_WIDTH_BINS
    # every bin's neighbours 2 to ``reach`` away, one column a bin (NaN beyond the band's edges)
    offsets = np.r_[-reach:-1, 2 : reach + 1]
    at = offsets[:, None] + np.arange(bins)[None, :]
    valid = (at >= 0) & (at < bins)
    around = np.where(valid, log_t[np.clip(at, 0, max(bins - 1, 0))], np.nan)
    floor = nanmedian_over_time(around)
    floor = np.where(valid.any(axis=0), floor, log_t)
    return np.asarray(np.exp(log_t - floor), np.float64)


def _centres(lv: _Level, grid_shape: tuple[int, int]) -> NDArray[np.int64]:
    """Flattened grid index of the centre of each counted block of a level."""
    h, w = grid_shape
    by, bx = np.divmod(lv.positions, lv.shape[1])
    cy = np.minimum(((by + 0.5) * h / lv.shape[0]).astype(np.int64), h - 1)
    cx = np.minimum(((bx + 0.5) * w / lv.shape[1]).astype(np.int64), w - 1)
    return np.asarray(cy * w + cx, np.int64)


__all__ = [
    "LEVELS",
    "MAX_FALSE_ALARM",
    "MIN_BINS",
    "MotionScan",
    "constrained_spectra",
    "motion_scan",
    "pyramid_levels",
]
