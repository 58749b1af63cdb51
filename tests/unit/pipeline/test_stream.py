"""The frame stream (``workers.pipeline.stream``) over a tiny synthetic reader: a textured patch sliding
half a pixel a frame over a still textured background. The flow maps have the window's shape and the
patch's motion, whole-picture motion is removed as the camera's, depth is sampled onto the grid, and a
clip that ends early keeps what decoded."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.pipeline.clipio.types import MIN_FRAMES, ClipInfo, ClosingReader, Frame
from workers.pipeline.errors import AnalysisError
from workers.pipeline.flow import FlowConfig
from workers.pipeline.light import BRIGHTNESS_BLOCKS, block_brightness
from workers.pipeline.stream import stream_frames

H, W, FPS = 64, 96, 30.0
SHIFT_PX = 0.5
#: Textures larger than the frame by a margin, so that what slides into view is texture, not a border.
MARGIN = 16
_rng = np.random.default_rng(5)
_SIZE = (H + 2 * MARGIN, W + 2 * MARGIN)
BACKGROUND = cv2.GaussianBlur(_rng.integers(0, 256, _SIZE).astype(np.uint8), (7, 7), 1.5)
TEXTURE = cv2.GaussianBlur(_rng.integers(0, 256, _SIZE).astype(np.uint8), (5, 5), 1.0)
#: The moving patch (rows, columns) and its interior, where the flow is measured.
PATCH = (slice(12, 44), slice(20, 68))
INSIDE = (slice(20, 36), slice(30, 58))
#: Still background, away from the patch.
STILL = (slice(54, 63), slice(78, 95))


class SlidingReader(ClosingReader):
    """Frames of a texture sliding ``shift`` pixels a frame to the right: a patch of it over a still
    background, or (``whole``) the whole picture, as a panning camera shows it. Depth (optional) is
    1.5 m + 1 cm per frame; frame i is captured at i / FPS. ``decodes`` frames decode of the ``frames``
    announced."""

    def __init__(
        self, frames: int = 40, *, whole: bool = False, depth: bool = False, decodes: int | None = None
    ) -> None:
        self._info = ClipInfo(
            format="npz",
            frames=frames,
            width=W,
            height=H,
            fps=FPS,
            fps_source="bundle",
            has_depth=depth,
            depth_scale=None,
            intrinsics=None,
        )
        self.whole = whole
        self.decodes = frames if decodes is None else decodes

    @property
    def info(self) -> ClipInfo:
        return self._info

    def gray(self, i: int) -> np.ndarray:
        big = BACKGROUND if self.whole else TEXTURE
        warp = np.float32([[1, 0, i * SHIFT_PX], [0, 1, 0]])
        moved = cv2.warpAffine(big, warp, (big.shape[1], big.shape[0]))[MARGIN:-MARGIN, MARGIN:-MARGIN]
        if self.whole:
            return moved
        out = BACKGROUND[MARGIN:-MARGIN, MARGIN:-MARGIN].copy()
        out[PATCH] = moved[PATCH]
        return out

    def frames(self, start: int = 0, stop: int | None = None):
        stop = min(self.decodes, self._info.frames if stop is None else stop)
        for i in range(start, stop):
            depth = np.full((H, W), 1.5 + 0.01 * i, np.float32) if self._info.has_depth else None
            rgb = np.repeat(self.gray(i)[..., None], 3, axis=2)
            yield Frame(index=i, rgb=rgb, depth_m=depth, timestamp_s=i / FPS)

    def close(self) -> None:
        pass


def test_a_sliding_patch_gives_its_motion_in_the_flow_and_none_around_it():
    reader = SlidingReader(depth=True)
    buffers = stream_frames(reader, 4, 36, (H, W), FlowConfig(), None)
    assert buffers.flow.shape == (31, H, W, 2)
    assert buffers.flow.dtype == np.float32
    assert buffers.count == buffers.announced == 31
    flow = buffers.flow
    assert float(np.median(flow[:, *INSIDE, 0])) == pytest.approx(SHIFT_PX, abs=0.05)
    assert abs(float(np.median(flow[:, *INSIDE, 1]))) < 0.02
    assert float(np.median(np.abs(flow[:, *STILL, :]))) < 0.02
    # The camera stood still: nothing was removed.
    assert not buffers.camera_removed
    np.testing.assert_array_equal(buffers.camera_px, 0)
    # Times from the window's first frame, which is frame 4 of the clip.
    np.testing.assert_allclose(buffers.times_s, np.arange(32) / FPS)
    assert buffers.start_s == pytest.approx(4 / FPS)
    np.testing.assert_array_equal(buffers.first_rgb[..., 0], reader.gray(4))
    # Depth on the grid for every frame.
    assert buffers.depth.shape == (32, H, W)
    np.testing.assert_allclose(buffers.depth[:, 0, 0], 1.5 + 0.01 * np.arange(4, 36), rtol=1e-6)
    # Block brightness of every frame and its change between frames.
    assert buffers.brightness.shape == (32, BRIGHTNESS_BLOCKS, BRIGHTNESS_BLOCKS)
    np.testing.assert_allclose(buffers.brightness[0], block_brightness(reader.gray(4)))
    assert buffers.frame_change.shape == (31, BRIGHTNESS_BLOCKS, BRIGHTNESS_BLOCKS)
    assert buffers.gray is None


def test_a_smaller_grid_scales_the_motion_and_keeps_the_grey_frames_at_input_resolution():
    """On a grid of half the frame's size, the camera's half-pixel pan is a quarter of a grid pixel."""
    reader = SlidingReader(whole=True)
    buffers = stream_frames(reader, 0, 40, (H // 2, W // 2), FlowConfig(), None, keep_gray=True)
    assert buffers.flow.shape == (39, H // 2, W // 2, 2)
    assert buffers.camera_removed
    assert float(np.median(buffers.camera_px[:, 0])) == pytest.approx(SHIFT_PX / 2, abs=0.03)
    assert buffers.gray.shape == (40, H, W)
    np.testing.assert_array_equal(buffers.gray[7], reader.gray(7))
    assert buffers.depth is None


def test_the_whole_picture_moving_is_the_camera_and_is_removed():
    buffers = stream_frames(SlidingReader(whole=True), 0, 32, (H, W), FlowConfig(), None)
    assert buffers.camera_removed
    assert float(np.median(buffers.camera_px[:, 0])) == pytest.approx(SHIFT_PX, abs=0.05)
    assert abs(float(np.median(buffers.camera_px[:, 1]))) < 0.02
    np.testing.assert_allclose(buffers.border_px, buffers.camera_px)
    assert float(np.median(np.abs(buffers.flow[:, *INSIDE, :]))) < 0.05


def test_magnitudes_for_the_papers_recipe():
    buffers = stream_frames(SlidingReader(), 0, 24, (H, W), FlowConfig(), None, magnitude=True)
    assert buffers.flow.shape == (23, H, W, 1)
    assert float(buffers.flow.min()) >= 0
    assert float(np.median(buffers.flow[:, *INSIDE, 0])) == pytest.approx(SHIFT_PX, abs=0.05)
    assert not buffers.camera_removed
    np.testing.assert_array_equal(buffers.camera_px, 0)


def test_progress_is_reported_as_the_flow_advances():
    calls: list[tuple[str, float]] = []
    stream_frames(SlidingReader(), 0, 40, (H, W), FlowConfig(), lambda stage, f: calls.append((stage, f)))
    assert {stage for stage, _ in calls} == {"flow"}
    fractions = [f for _, f in calls]
    assert fractions == sorted(fractions)
    assert fractions[-1] == pytest.approx(0.8)
    assert len(fractions) >= 5


def test_a_clip_that_ends_early_keeps_what_decoded():
    buffers = stream_frames(SlidingReader(40, decodes=25), 0, 40, (H, W), FlowConfig(), None)
    assert buffers.count == 24
    assert buffers.announced == 39
    assert buffers.flow.shape == (24, H, W, 2)
    assert len(buffers.times_s) == len(buffers.brightness) == 25
    assert len(buffers.frame_change) == len(buffers.camera_px) == 24


def test_too_few_frames_is_an_analysis_error_that_says_how_many():
    with pytest.raises(AnalysisError, match=f"ended after 10 of the 40 frames.*at least {MIN_FRAMES}"):
        stream_frames(SlidingReader(40, decodes=10), 0, 40, (H, W), FlowConfig(), None)
