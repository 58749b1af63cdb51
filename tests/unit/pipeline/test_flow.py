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


@pytest.mark.parametrize(
    "shape",
    [(5, 9, 12, 2), (4, 300), (3, 40), (1, 1, 1, 1), (0, 6), (7,)],
    ids=lambda s: "x".join(map(str, s)),
)
def test_half_precision_is_numpys_bit_for_bit(shape: tuple[int, ...]) -> None:
    """to_float16 and as_float32 give what numpy's casts give, bit for bit: values below float16's normal
    range (a still picture's flow), ties, overflow to infinity, NaN; and a box cut out of maps."""
    from workers.pipeline.flow import as_float32, to_float16

    rng = np.random.default_rng(3)
    scale = rng.choice(np.array([1e-9, 1e-6, 3e-5, 1.0, 7e4], np.float32), size=shape)
    values = (rng.standard_normal(shape) * scale).astype(np.float32)
    if values.size:
        values.flat[0] = np.nan
        values.flat[-1] = 2.9802322e-08  # a tie between 0 and float16's smallest value
    with np.errstate(over="ignore"):
        expected = values.astype(np.float16)
        half = to_float16(values)
        box = values[:, 2:7, 3:10] if len(shape) == 4 else None
        boxed = None if box is None else (to_float16(box), box.astype(np.float16))
    assert half.dtype == np.float16
    assert half.shape == values.shape
    np.testing.assert_array_equal(half.view(np.uint16), expected.view(np.uint16))
    single = as_float32(half)
    assert single.dtype == np.float32
    np.testing.assert_array_equal(single, expected.astype(np.float32))
    if boxed is not None:
        np.testing.assert_array_equal(boxed[0].view(np.uint16), boxed[1].view(np.uint16))
