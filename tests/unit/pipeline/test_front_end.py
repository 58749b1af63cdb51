"""The two passes' front end on small rendered scenes (workers.pipeline.look, roi, fine): the coarse grid,
what the first pass keeps, the box around the moving region and its grid, and the second pass's flow
from kept frames and from frames read again."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.pipeline.fine import ROI_BUDGET_PX, grid_for, plan_roi, stream_roi
from workers.pipeline.flow import FlowConfig
from workers.pipeline.look import CoarseGrid, KeptFrames, frame_noise, look_at
from workers.pipeline.roi import Roi
from workers.pipeline.synth import Scene, SceneObject, SceneReader


def _scene(**kw) -> Scene:
    obj = SceneObject(center_px=(200, 120), size_px=(60, 50), frequency_hz=4.0, damping_ratio=0.02)
    return Scene(width=320, height=240, frames=48, fps=30.0, objects=(obj,), **kw)


@pytest.mark.parametrize(
    ("size", "factor", "shape"),
    [
        ((480, 640), 4, (120, 160)),
        ((420, 640), 4, (105, 160)),
        ((240, 320), 2, (120, 160)),
        ((120, 160), 1, (120, 160)),
        ((720, 1280), 8, (90, 160)),
        ((30, 40), 1, (30, 40)),
    ],
)
def test_the_coarse_grid_is_an_integer_factor_about_160_wide(size, factor, shape):
    grid = CoarseGrid.for_frame(*size)
    assert (grid.factor, grid.shape) == (factor, shape)
    small = grid.shrink(np.zeros(size, np.uint8))
    assert small.shape == shape


def test_the_look_keeps_a_short_window_and_says_where_it_moves():
    scene = _scene()
    with SceneReader(scene) as reader:
        look = look_at(reader, 0, scene.frames)
    assert look.count == scene.frames - 1
    assert look.flow.shape == (scene.frames - 1, 120, 160, 2)
    assert look.kept is not None
    assert len(look.kept) == scene.frames
    gray, depth = look.kept.frame(scene.frames - 1)
    assert gray.shape == (240, 320)
    assert depth is not None
    assert depth.shape == (120, 160)
    assert not look.camera_removed
    assert look.times_s[1] == pytest.approx(1 / 30.0)
    assert 0.2 < look.max_step_px < 20.0


def test_kept_frames_come_back_as_they_went_in_from_a_file_not_from_memory(tmp_path):
    """The window's frames are written to a temporary file as the look decodes them (a long window's
    frames would otherwise be most of the process's memory, or be decoded twice) and read back exactly;
    a frame without depth comes back as NaN; the file is gone once closed."""
    rng = np.random.default_rng(3)
    grays = rng.integers(0, 256, (5, 42, 64), dtype=np.uint8)
    depths = rng.uniform(0.3, 4.0, (5, 21, 32)).astype(np.float32)
    kept = KeptFrames((42, 64), (21, 32), directory=str(tmp_path))
    for i in range(5):
        kept.append(grays[i], None if i == 3 else depths[i])
    assert len(kept) == 5
    for i in (4, 0, 3):
        gray, depth = kept.frame(i)
        np.testing.assert_array_equal(gray, grays[i])
        assert depth is not None
        if i == 3:
            assert np.isnan(depth).all()
        else:
            np.testing.assert_array_equal(depth, depths[i])
    kept.truncate(2)
    with pytest.raises(IndexError, match="frame 2 of 2"):
        kept.frame(2)
    without_depth = KeptFrames((42, 64), None, directory=str(tmp_path))
    without_depth.append(grays[1], None)
    gray, depth = without_depth.frame(0)
    np.testing.assert_array_equal(gray, grays[1])
    assert depth is None
    assert list(tmp_path.iterdir()) == []  # unlinked: nothing to clean up, even after a crash
    kept.close()
    without_depth.close()


def test_one_frame_noise_is_at_least_the_rounding_of_grey_levels():
    assert frame_noise(np.zeros((10, 8, 8), np.float32)) == pytest.approx(1 / np.sqrt(12))
    pulses = np.zeros((24, 8, 8), np.float32)
    pulses[::12] = 4.0  # a codec changes the picture at its keyframes only
    assert frame_noise(pulses) > 1.0


def test_a_box_moves_maps_between_its_grid_and_the_frame():
    roi = Roi(40, 20, 100, 60, (30, 50), (240, 320))
    assert roi.pixel_scale == pytest.approx(2.0)
    grid = np.arange(30 * 50, dtype=np.uint16).reshape(30, 50)
    frame = roi.to_frame(grid)
    assert frame.shape == (240, 320)
    assert frame[:20].max() == 0
    assert frame[:, :40].max() == 0
    np.testing.assert_array_equal(roi.from_frame(frame), grid)
    assert not roi.whole_frame
    assert Roi.whole((240, 320), (120, 160)).whole_frame


def test_the_box_grid_is_full_resolution_when_small_and_within_budgets():
    assert grid_for(120, 300, samples=256) == (300, 120)
    h, w = grid_for(640, 480, samples=256)
    assert h * w <= ROI_BUDGET_PX * 1.01
    long_h, long_w = grid_for(200, 400, samples=3000)
    assert long_h * long_w < 200 * 400  # memory bounds a long window's grid


def test_a_box_over_budget_whose_motion_is_large_is_measured_in_whole_2x2_blocks():
    """A box beyond the pixel budget is area-averaged by the fraction the budget allows; when its motion is
    two input pixels a frame or more, in whole 2 x 2 blocks instead (exact and cheap), the box trimmed to
    an even size."""
    from dataclasses import replace as with_

    scene = _scene()
    with SceneReader(scene) as reader:
        look = look_at(reader, 0, scene.frames)
    region = np.zeros(look.grid.shape, bool)
    region[40:81, 50:111] = True  # input x 100-222, y 80-162, with margins 24-50 px
    budget = 20_000
    slow = plan_roi(
        with_(look, max_step_px=0.5), [region], frame_shape=(240, 320), samples=48, budget_px=budget
    )
    fast = plan_roi(
        with_(look, max_step_px=3.0), [region], frame_shape=(240, 320), samples=48, budget_px=budget
    )
    assert (slow.x, slow.y) == (fast.x, fast.y)
    assert slow.width * slow.height > budget  # over the budget: not at full resolution
    assert slow.pixel_scale != pytest.approx(2.0, abs=0.05)  # the fraction the budget allows
    assert fast.width % 2 == 0
    assert fast.height % 2 == 0
    assert fast.grid_shape == (fast.height // 2, fast.width // 2)
    assert fast.pixel_scale == pytest.approx(2.0)


def test_the_box_holds_the_regions_with_a_margin_and_falls_back_to_the_frame():
    scene = _scene()
    with SceneReader(scene) as reader:
        look = look_at(reader, 0, scene.frames)
    region = np.zeros(look.grid.shape, bool)
    region[52:68, 85:115] = True  # coarse pixels: input x 170-230, y 104-136
    roi = plan_roi(look, [region], frame_shape=(240, 320), samples=look.count)
    assert roi.x <= 170 - 24
    assert roi.x + roi.width >= 230 + 24
    assert roi.y <= 104 - 24
    assert roi.y + roi.height >= 136 + 24
    assert roi.grid_shape == (roi.height, roi.width)  # small: full resolution
    whole = plan_roi(look, [], frame_shape=(240, 320), samples=look.count)
    assert whole.whole_frame


def test_the_second_pass_reads_kept_frames_as_it_reads_the_clip():
    scene = _scene()
    with SceneReader(scene) as reader:
        look = look_at(reader, 0, scene.frames)
        roi = Roi(120, 60, 160, 120, (120, 160), (240, 320))
        kept = stream_roi(look, roi, start=0, stop=scene.frames, look=look, flow_config=FlowConfig(threads=1))
        again = stream_roi(
            reader, roi, start=0, stop=scene.frames, look=look, flow_config=FlowConfig(threads=1)
        )
    assert kept.roi == roi
    assert kept.flow.shape == (scene.frames - 1, 120, 160, 2)
    assert kept.gray is not None
    assert kept.gray.shape == (scene.frames, 120, 160)
    np.testing.assert_allclose(kept.flow, again.flow, atol=1e-5)
    assert kept.depth is not None
    assert again.depth is not None
    np.testing.assert_allclose(kept.depth, again.depth, equal_nan=True)
    # the object (centre x 200, y 120) moves: the flow of the box sees it
    assert float(np.abs(kept.flow[..., 0]).max()) > 0.3


def test_a_whole_frame_flow_is_scanned_on_the_looks_grid():
    """A live stream's flow grid (here 320 wide) is area-averaged onto the look's (160 wide) before the
    scan, in that grid's pixels: the scan costs a quarter, and an object moving there is found there."""
    from workers.pipeline.front import front_of_buffers
    from workers.pipeline.stream import FrameBuffers

    rng = np.random.default_rng(5)
    n, h, w = 96, 120, 320
    flow = rng.normal(0, 0.05, (n, h, w, 2)).astype(np.float32)
    flow[:, 40:70, 100:150, 0] += (0.4 * np.sin(2 * np.pi * 6.0 * np.arange(n) / 30.0))[:, None, None]
    texture = cv2.GaussianBlur(rng.uniform(40, 200, (2 * h, 2 * w)).astype(np.float32), (0, 0), 1.5)
    rgb = np.repeat(texture.astype(np.uint8)[..., None], 3, axis=2)
    buffers = FrameBuffers(
        flow=flow,
        depth=None,
        gray=None,
        first_rgb=rgb,
        count=n,
        times_s=np.arange(n + 1) / 30.0,
        camera_px=np.zeros((n, 2), np.float32),
        start_s=0.0,
    )
    front = front_of_buffers(buffers, sample_rate_hz=30.0, band_hz=(0.7, 14.7), max_objects=4)
    assert front.scan.grid_shape == (60, 160)
    assert front.grid_factor == pytest.approx(4.0)
    assert [round(c.peak.frequency_hz) for c in front.candidates.found] == [6]
    ys, xs = np.nonzero(front.candidates.found[0].region)
    assert 20 <= ys.mean() <= 35  # the patch, on the halved grid
    assert 50 <= xs.mean() <= 75


def test_the_front_keeps_only_the_boxs_coarse_flow_and_measures_the_object_the_same():
    """Once the box is chosen, the front keeps the coarse flow over it alone (a copy: the whole picture's
    flow can be freed), in half precision, and an object's motion on that grid is what it was on the whole
    grid (exactly, of the flow rounded as it is kept)."""
    from dataclasses import replace

    from workers.pipeline.front import front_of_look
    from workers.pipeline.tracking import object_motion

    scene = _scene()
    with SceneReader(scene) as reader:
        look = look_at(reader, 0, scene.frames)
    front = front_of_look(look, sample_rate_hz=30.0, band_hz=(1.0, 14.0), max_objects=4)
    assert front.candidates.found
    roi = plan_roi(look, front.candidates.regions, frame_shape=(240, 320), samples=look.count)
    kept = front.keeping_flow_of(roi)
    f = front.grid_factor
    y0, x0 = kept.flow_origin
    assert (y0, x0) == (roi.y // f, roi.x // f)
    assert kept.flow.base is None
    assert kept.flow.shape[1] < front.flow.shape[1]
    assert kept.flow.shape[1] * f >= roi.height
    assert kept.flow.shape[2] * f >= roi.width
    assert kept.flow.dtype == np.float16  # kept in half precision
    region = front.candidates.regions[0]
    whole, boxed = front.coarse_view(region), kept.coarse_view(region)
    assert boxed.region.sum() == region.sum()  # the object lies in the box
    # the same flow, rounded as the box keeps it: the same motion exactly
    rounded = replace(front, flow=front.flow.astype(np.float16).astype(np.float32)).coarse_view(region)
    motions = [
        object_motion(v.flow, v.region, frequency_hz=4.0, sample_rate_hz=30.0, confidence=v.confidence)
        for v in (whole, rounded, boxed)
    ]
    np.testing.assert_allclose(motions[2].velocity_px, motions[1].velocity_px, rtol=1e-5, atol=1e-7)
    # and the rounding (2^-11 of a value) moves the motion by a thousandth of its size at most
    scale = float(np.abs(motions[0].velocity_px).max())
    np.testing.assert_allclose(motions[2].velocity_px, motions[0].velocity_px, rtol=0, atol=1e-3 * scale)
    # the camera's and the region's band powers need the ring's flow and the region's only
    region_power, ring_power = front.band_powers(4.0, 1.0, region)
    kept_power, kept_ring = kept.band_powers(4.0, 1.0, region)
    rounded_front = replace(front, flow=front.flow.astype(np.float16).astype(np.float32))
    rounded_power, rounded_ring = rounded_front.band_powers(4.0, 1.0, region)
    assert region_power > 0
    assert kept_power == pytest.approx(rounded_power, rel=1e-5)
    np.testing.assert_allclose(kept_ring, rounded_ring, rtol=1e-5)
    assert kept_power == pytest.approx(region_power, rel=1e-3)
    np.testing.assert_allclose(kept_ring, ring_power, rtol=1e-3, atol=1e-3 * float(ring_power.max()))
    picture = front.spectra  # the whole picture's spectra (before the box only) give the same powers
    sel = np.abs(picture.frequencies_hz - 4.0) <= 1.5 * picture.bin_hz
    power = picture.power[sel].sum(axis=0)
    assert region_power == pytest.approx(float(np.median(power[region.ravel()])), rel=1e-5)
    np.testing.assert_allclose(ring_power, power[front.ring.pixels], rtol=1e-5)
    with pytest.raises(ValueError, match="keeping_flow_of"):
        _ = kept.spectra
    whole_frame = Roi(0, 0, 320, 240, (240, 320), (240, 320))
    all_of_it = front.keeping_flow_of(whole_frame)
    assert all_of_it.flow.shape == front.flow.shape
    assert all_of_it.flow.dtype == np.float16
    assert all_of_it.flow_origin == (0, 0)


@pytest.mark.slow
def test_grey_frames_over_their_budget_are_kept_on_the_grid_and_registration_still_measures(
    monkeypatch, tmp_path
):
    """The second pass keeps the box's grey frames at input resolution within GRAY_BUDGET_MIB, on the flow
    grid beyond it (a long window's frames grow with it); registration then works on that grid and the
    object's stiffness is still measured within 2 % (0.13 % when written; the tier's floor is 10 %)."""
    import workers.pipeline.analysis as analysis
    from tests.scenes import excitation_of
    from workers.pipeline import fine
    from workers.pipeline.clipio import open_clip, write_npz
    from workers.pipeline.synth import render

    obj = SceneObject(
        center_px=(320, 240), size_px=(300, 230), frequency_hz=5.0, mass_kg=0.5, force_n=10.0, release_frame=8
    )
    scene = Scene(width=640, height=480, frames=64, fps=30.0, objects=(obj,), seed=4, background_depth_m=2.5)
    clip = render(scene)
    path = tmp_path / "large.npz"
    write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
    truth = scene.truth()["objects"][0]
    kept: list[tuple[tuple[int, ...], float, tuple[int, int]]] = []
    second_pass = analysis.stream_roi

    def recording(*args, **kwargs):
        buffers = second_pass(*args, **kwargs)
        kept.append((buffers.gray.shape[1:], buffers.gray_pixel_scale, buffers.flow.shape[1:3]))
        return buffers

    monkeypatch.setattr(analysis, "stream_roi", recording)
    results = []
    for budget_mib in (fine.GRAY_BUDGET_MIB, 0.0):
        monkeypatch.setattr(fine, "GRAY_BUDGET_MIB", budget_mib)
        with open_clip(path) as reader:
            results.append(analysis.analyze(reader, excitation=excitation_of(scene)))
    (full_shape, full_scale, grid), (small_shape, small_scale, grid_again) = kept
    assert grid == grid_again
    assert full_scale == 1.0
    assert full_shape != grid  # the box is larger than its flow grid
    assert small_shape == grid
    assert small_scale == pytest.approx(full_shape[1] / grid[1])
    for result in results:
        (o,) = result.objects
        assert o.amplitude_source == "registration"
        assert o.eigenfrequency_hz == pytest.approx(truth["eigenfrequency_hz"], rel=0.01)
        assert o.stiffness_n_per_m == pytest.approx(truth["stiffness_n_per_m"], rel=0.02)


def test_without_room_for_the_kept_frames_the_analysis_reads_the_clip_again(monkeypatch):
    """A full disk while the look keeps the window's frames costs a second decode, not the analysis."""
    import errno

    from workers.pipeline.analysis import analyze

    def full(self, gray, depth):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(KeptFrames, "append", full)
    scene = _scene()
    with SceneReader(scene) as reader:
        look = look_at(reader, 0, scene.frames)
        assert look.kept is None
        result = analyze(reader)
    assert result.objects
    assert result.objects[0].eigenfrequency_hz == pytest.approx(4.0, rel=0.02)


def _whole_frame_buffers(
    n: int = 6, *, grid: tuple[int, int] = (60, 80), frame: tuple[int, int] = (240, 320)
):
    from workers.pipeline.stream import FrameBuffers

    rng = np.random.default_rng(4)
    h, w = grid
    return FrameBuffers(
        flow=rng.normal(size=(n, h, w, 2)).astype(np.float32),
        depth=rng.uniform(0.5, 2.0, (n + 1, h, w)).astype(np.float32),
        gray=rng.integers(0, 255, (n + 1, *frame), dtype=np.uint8),
        first_rgb=np.zeros((*frame, 3), np.uint8),
        count=n,
        times_s=np.arange(n + 1) / 30.0,
        camera_px=np.zeros((n, 2), np.float32),
        start_s=0.0,
    )


def test_a_whole_frame_window_is_cut_to_the_box_that_moves_on_its_own_grid():
    """A live window's flow (computed as the frames came, on a grid of 4 input pixels) is cut to the box
    around the moving region with plan_roi's margin: the same flow, depth and full-resolution grey
    frames there, and the box says where it lies. Nothing moving, most of the frame moving, or a grid
    of a fraction of input pixels leave the buffers as they are."""
    from workers.pipeline.fine import MIN_MARGIN_PX, crop_to_motion

    buffers = _whole_frame_buffers()
    region = np.zeros((30, 40), bool)  # a grid of 8 input pixels
    region[10:14, 20:24] = True  # input x 160-192, y 80-112
    cut = crop_to_motion(buffers, [region], factor=8.0, frame_shape=(240, 320))
    roi = cut.roi
    assert roi is not None
    assert roi.pixel_scale == 4.0
    assert roi.x % 4 == 0
    assert roi.y % 4 == 0
    assert roi.width % 4 == 0
    assert roi.height % 4 == 0
    assert roi.x <= 160 - MIN_MARGIN_PX
    assert roi.x + roi.width >= 192 + MIN_MARGIN_PX
    assert roi.y <= 80 - MIN_MARGIN_PX
    assert roi.y + roi.height >= 112 + MIN_MARGIN_PX
    assert roi.width * roi.height < 0.2 * 240 * 320
    gy, gx = roi.y // 4, roi.x // 4
    h, w = roi.grid_shape
    np.testing.assert_array_equal(cut.flow, buffers.flow[:, gy : gy + h, gx : gx + w])
    assert cut.depth is not None
    assert buffers.depth is not None
    np.testing.assert_array_equal(cut.depth, buffers.depth[:, gy : gy + h, gx : gx + w])
    assert cut.gray is not None
    assert buffers.gray is not None
    rows, cols = slice(roi.y, roi.y + roi.height), slice(roi.x, roi.x + roi.width)
    np.testing.assert_array_equal(cut.gray, buffers.gray[:, rows, cols])
    assert cut.gray_pixel_scale == 1.0
    assert cut.box((240, 320)) == roi
    assert crop_to_motion(buffers, [np.zeros((30, 40), bool)], factor=8.0, frame_shape=(240, 320)) is buffers
    most = np.ones((30, 40), bool)
    assert crop_to_motion(buffers, [most], factor=8.0, frame_shape=(240, 320)) is buffers
    odd = _whole_frame_buffers(grid=(70, 93))  # 320 / 93 input pixels a grid pixel
    assert crop_to_motion(odd, [region], factor=8.0, frame_shape=(240, 320)) is odd
