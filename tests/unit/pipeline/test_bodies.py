"""Regions that are parts of one body ringing in several modes are joined, on arrays: touching regions that
each carry the other's line are one object; regions that only touch, share lines only at their border,
lie apart, or differ by a line's flank stay apart."""

from __future__ import annotations

import numpy as np

from workers.pipeline.bodies import join_bodies
from workers.pipeline.peaks import Peak
from workers.pipeline.segmentation import Segmentation

F = 256
FREQS = np.arange(F, dtype=np.float64) * 0.5  # 0.5 Hz bins


def _peak(f: float) -> Peak:
    return Peak(frequency_hz=f, bin=round(f / 0.5), power=1.0, prominence_db=20.0, snr_db=20.0)


def _scene(lines: dict[int, list[tuple[float, float]]], labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """Per-pixel power (F, P): noise everywhere plus, on label ``i``'s pixels, lines (frequency, power)."""
    rng = np.random.default_rng(seed)
    power = rng.exponential(1.0, (F, labels.size)).astype(np.float32)
    for label, found in lines.items():
        on = (labels == label).ravel()
        for f, p in found:
            power[round(f / 0.5), on] += p
    return power


def _segmentation(labels: np.ndarray, frequencies: list[float]) -> Segmentation:
    k = len(frequencies)
    return Segmentation(
        labels=labels.astype(np.int32),
        peaks=[_peak(f) for f in frequencies],
        band_power=np.ones((k, *labels.shape), np.float32) * np.arange(1, k + 1)[:, None, None],
        noise_power=np.arange(1.0, k + 1),
    )


def _strip(split: int, *, gap: int = 0) -> np.ndarray:
    """A 6 x 40 strip on a 12 x 48 grid: label 1 left of ``split``, label 2 right of it (``gap`` columns
    of background between them)."""
    labels = np.zeros((12, 48), np.int32)
    labels[3:9, 4:split] = 1
    labels[3:9, split + gap : 44] = 2
    return labels


def test_touching_parts_that_carry_each_others_lines_are_one_body() -> None:
    labels = _strip(28)
    # The tip (label 1) moves most at 4 Hz, the middle (label 2) at 25 Hz; each carries the other's line.
    power = _scene({1: [(4.0, 400.0), (25.0, 60.0)], 2: [(25.0, 300.0), (4.0, 40.0)]}, labels)
    seg = join_bodies(_segmentation(labels, [4.0, 25.0]), power, frequencies_hz=FREQS)
    assert len(seg.peaks) == 1
    assert seg.peaks[0].frequency_hz == 4.0  # the strongest part's peak
    assert set(np.unique(seg.labels)) == {0, 1}
    assert (seg.labels > 0).sum() == (labels > 0).sum()
    assert seg.band_power.shape == (1, *labels.shape)
    assert seg.noise_power.tolist() == [1.0]


def test_touching_objects_that_do_not_share_their_lines_stay_apart() -> None:
    labels = _strip(28)
    power = _scene({1: [(4.0, 400.0)], 2: [(25.0, 300.0)]}, labels)
    seg = _segmentation(labels, [4.0, 25.0])
    assert join_bodies(seg, power, frequencies_hz=FREQS) is seg


def test_a_line_only_on_one_side_is_not_enough() -> None:
    labels = _strip(28)
    power = _scene({1: [(4.0, 400.0), (25.0, 60.0)], 2: [(25.0, 300.0)]}, labels)
    seg = _segmentation(labels, [4.0, 25.0])
    assert join_bodies(seg, power, frequencies_hz=FREQS) is seg


def test_objects_apart_stay_apart_even_when_they_share_lines() -> None:
    labels = _strip(22, gap=10)
    power = _scene({1: [(4.0, 400.0), (25.0, 60.0)], 2: [(25.0, 300.0), (4.0, 40.0)]}, labels)
    seg = _segmentation(labels, [4.0, 25.0])
    assert join_bodies(seg, power, frequencies_hz=FREQS) is seg


def test_close_frequencies_are_not_joined_by_a_line_s_flank() -> None:
    """Two touching objects 1 Hz apart (2 bins): each one's own line spills into the other's bins, which is
    no line of its own."""
    labels = _strip(28)
    power = _scene({1: [(10.0, 400.0), (10.5, 150.0)], 2: [(11.0, 300.0), (10.5, 120.0)]}, labels)
    seg = _segmentation(labels, [10.0, 11.0])
    assert join_bodies(seg, power, frequencies_hz=FREQS) is seg


def test_three_parts_of_one_body_join_in_the_order_of_their_strength() -> None:
    labels = np.zeros((12, 60), np.int32)
    labels[3:9, 4:20], labels[3:9, 20:38], labels[3:9, 38:56] = 1, 2, 3
    # A separate object (label 4) far away keeps its own label, renumbered after the body.
    labels[10:12, 0:6] = 4
    lines = [(4.0, 400.0), (25.0, 80.0), (70.0, 30.0)]
    power = _scene({1: lines, 2: lines[::-1], 3: lines, 4: [(40.0, 200.0)]}, labels)
    seg = join_bodies(_segmentation(labels, [4.0, 25.0, 70.0, 40.0]), power, frequencies_hz=FREQS)
    assert [p.frequency_hz for p in seg.peaks] == [4.0, 40.0]
    assert (seg.labels == 1).sum() == (labels[:, :] > 0).sum() - (labels == 4).sum()
    assert ((seg.labels == 2) == (labels == 4)).all()
