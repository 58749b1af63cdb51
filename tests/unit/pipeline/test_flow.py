"""Streamed optical flow: in order, into a caller's buffer, and blind to what that buffer held before."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.pipeline.flow import FlowConfig, compute_flow, flow_stream


def _frames(count: int, *, shift_px: float = 0.7) -> list[np.ndarray]:
    """A textured picture moving right by ``shift_px`` per frame (sub-pixel, by warping)."""
    rng = np.random.default_rng(5)
    base = cv2.GaussianBlur(rng.integers(0, 256, (96, 128)).astype(np.uint8), (7, 7), 1.5)
    frames = []
    for i in range(count):
        warp = np.float32([[1, 0, i * shift_px], [0, 1, 0]])
        frames.append(cv2.warpAffine(base, warp, (128, 96), borderMode=cv2.BORDER_REFLECT))
    return frames


@pytest.mark.parametrize("method", ["dis", "farneback"])
@pytest.mark.parametrize("threads", [1, 2])
def test_flow_written_into_a_buffer_matches_flow_returned(method: str, threads: int):
    frames = _frames(9)
    config = FlowConfig(method=method, threads=threads)
    returned = [f.copy() for f in flow_stream(iter(frames), config=config)]
    assert len(returned) == 8
    for fill in (np.nan, 0.0, 1e6):  # DIS reads a buffer it is handed: NaN crashed it, zeros changed it
        out = np.full((8, 96, 128, 2), fill, np.float32)
        yielded = list(flow_stream(iter(frames), config=config, out=out))
        assert all(np.shares_memory(y, out) for y in yielded)
        np.testing.assert_array_equal(out, np.stack(returned), err_msg=f"buffer filled with {fill}")
    # The motion itself: about 0.7 px to the right inside the picture.
    inner = np.stack(returned)[:, 16:-16, 16:-16]
    assert abs(float(np.median(inner[..., 0])) - 0.7) < 0.1
    assert abs(float(np.median(inner[..., 1]))) < 0.05


def test_a_buffer_bounds_the_frames_consumed():
    frames = _frames(12)
    taken: list[int] = []

    def source():
        for i, f in enumerate(frames):
            taken.append(i)
            yield f

    out = np.zeros((4, 96, 128, 2), np.float32)
    assert len(list(flow_stream(source(), config=FlowConfig(threads=2), out=out))) == 4
    assert taken == [0, 1, 2, 3, 4], "five frames make the four flows; none is read beyond them"
    np.testing.assert_array_equal(out[2], compute_flow(frames[2], frames[3]))


@pytest.mark.parametrize("channels", [1, 2])
def test_pixel_columns_are_the_fancy_index_of_the_pixels(channels: int) -> None:
    from workers.pipeline.flow import pixel_columns

    rng = np.random.default_rng(channels)
    maps = rng.standard_normal((7, 5, 6, channels)).astype(np.float16)
    pixels = np.array([29, 0, 7, 7, 13], np.intp)
    expected = maps.reshape(7, -1, channels)[:, pixels, :].reshape(7, -1)
    got = pixel_columns(maps, pixels)
    assert got.dtype == maps.dtype
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(pixel_columns(maps.reshape(7, 30, channels), pixels), expected)
