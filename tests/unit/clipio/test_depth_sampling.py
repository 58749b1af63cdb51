"""Depth sampled onto the flow grid before conversion: the same values as converting, then resizing."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from workers.pipeline.clipio import NpzClip, write_npz
from workers.pipeline.clipio.types import depth_to_metres, nearest_indices, sample_nearest
from workers.pipeline.errors import ParameterError

# (source rows, source columns) -> (rows, columns): the grids of common camera sizes, odd sizes whose
# ratio is not a whole number, and enlargement.
SHAPES = [
    ((480, 640), (240, 320)),
    ((720, 1280), (180, 320)),
    ((240, 320), (240, 320)),
    ((481, 641), (240, 320)),
    ((100, 137), (37, 51)),
    ((7, 9), (16, 25)),
    ((1080, 1920), (180, 320)),
]


@pytest.mark.parametrize(("source", "target"), SHAPES)
def test_sample_nearest_is_opencv_inter_nearest(source: tuple[int, int], target: tuple[int, int]) -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 65535, size=source, dtype=np.uint16)
    expected = cv2.resize(image, (target[1], target[0]), interpolation=cv2.INTER_NEAREST)
    got = sample_nearest(image, target)
    assert got.shape == target
    assert got.dtype == image.dtype
    np.testing.assert_array_equal(got, expected)


def test_nearest_indices_reject_empty_axes() -> None:
    with pytest.raises(ParameterError, match="at least 1"):
        nearest_indices(0, 4)


@pytest.mark.parametrize("stored", ["uint16", "float32"])
def test_npz_frames_with_depth_on_a_grid_equal_the_resized_full_maps(tmp_path: Path, stored: str) -> None:
    rng = np.random.default_rng(1)
    frames, height, width = 16, 48, 64
    rgb = rng.integers(0, 255, size=(frames, height, width, 3), dtype=np.uint8)
    if stored == "uint16":
        depth = rng.integers(0, 3000, size=(frames, height, width), dtype=np.uint16)
        depth[:, :4] = 0  # no reading
    else:
        depth = rng.uniform(0.3, 3.0, size=(frames, height, width)).astype(np.float32)
        depth[:, :4] = np.nan
    path = write_npz(tmp_path / "clip.npz", rgb, fps=30.0, depth=depth, depth_scale=0.001)
    grid = (24, 32)
    with NpzClip(path) as reader:
        full = list(reader.frames(1, 4))
        sampled = list(reader.frames_with_depth_on(grid, 1, 4))
    assert [f.index for f in sampled] == [1, 2, 3]
    for a, b in zip(full, sampled, strict=True):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        assert a.timestamp_s == b.timestamp_s
        assert a.depth_m is not None
        assert b.depth_m is not None
        expected = cv2.resize(a.depth_m, (grid[1], grid[0]), interpolation=cv2.INTER_NEAREST)
        assert b.depth_m.shape == grid
        np.testing.assert_array_equal(b.depth_m, expected)  # NaN where no reading, in both
        np.testing.assert_array_equal(b.depth_m, depth_to_metres(depth[a.index, ::2, ::2], 0.001))
