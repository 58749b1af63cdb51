"""The live window's buffers: what the final analysis gets is what the batch frame stream keeps of the
same frames (block brightness and change taken as frames arrive, the camera's motion removed alike)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from workers.pipeline.camera import CameraRing, remove_camera_motion
from workers.pipeline.flow import prepare_gray
from workers.pipeline.light import block_brightness, block_change
from workers.pipeline.live import LiveAnalysis, LiveConfig
from workers.pipeline.synth import Scene, SceneObject, SceneReader


def _pushed(scene: Scene, **config: object) -> tuple[LiveAnalysis, list[np.ndarray]]:
    live = LiveAnalysis(
        width=scene.width,
        height=scene.height,
        config=LiveConfig(fps=scene.fps, **config),  # type: ignore[arg-type]
    )
    rgbs = []
    for frame in SceneReader(scene).frames():
        live.push(rgb=frame.rgb, depth_m=None, timestamp_s=frame.timestamp_s)
        rgbs.append(frame.rgb)
    live.close()
    return live, rgbs


@pytest.mark.parametrize("release", [5, 40], ids=["motion-at-once", "window-slides-first"])
def test_block_series_taken_as_frames_arrive_match_the_kept_frames(release: int) -> None:
    obj = SceneObject(
        center_px=(48, 36), size_px=(30, 24), frequency_hz=4.0, force_n=6.0, release_frame=release
    )
    scene = Scene(
        width=96, height=72, frames=70, fps=30.0, objects=(obj,), seed=2, flicker=0.05, flicker_hz=3.0
    )
    live, rgbs = _pushed(scene, window_frames=32, lead_frames=4)
    n = live.window.flows
    buffers = live.window.buffers(n)
    # The kept frames are the stream's frames base .. base + n: their grey frames on the grid give the
    # same series as the batch stream's (workers.pipeline.stream).
    smalls = [prepare_gray(rgbs[live.window.base + i], live.grid) for i in range(n + 1)]
    assert buffers.brightness is not None
    assert buffers.frame_change is not None
    np.testing.assert_array_equal(buffers.brightness, np.stack([block_brightness(g) for g in smalls]))
    changes = np.stack([block_change(a, b) for a, b in itertools.pairwise(smalls)])
    np.testing.assert_array_equal(buffers.frame_change, changes)
    if release == 40:
        assert live.window.base > 0, "the window should have slid before the motion"
    assert np.ptp(buffers.brightness) > 0  # the flicker shows


def test_the_camera_motion_is_judged_as_the_batch_stream_judges_it() -> None:
    obj = SceneObject(center_px=(48, 36), size_px=(30, 24), frequency_hz=4.0, force_n=6.0, release_frame=5)
    scene = Scene(
        width=96, height=72, frames=40, fps=30.0, objects=(obj,), seed=3, shake_px=1.5, shake_hz=2.0
    )
    live, rgbs = _pushed(scene, window_frames=64)
    n = live.window.flows
    raw = live.window.flow_maps(n)
    border = live.window.camera_motion_px(n)
    buffers = live.window.buffers(n)
    ring = CameraRing(live.grid)
    ring.set_texture(prepare_gray(rgbs[0], live.grid))
    expected = remove_camera_motion(raw, border, ring)
    assert expected.removed  # the shake is removed ...
    assert buffers.camera_removed
    assert buffers.camera_still_fraction == pytest.approx(expected.still_fraction)
    np.testing.assert_array_equal(buffers.flow, raw)


@pytest.mark.parametrize("shake_px", [0.0, 1.5], ids=["still-camera", "shaking-camera"])
def test_maps_pooled_as_they_arrive_are_the_window_flow_pooled(shake_px: float) -> None:
    """The final analysis scans the look's grid; a stream pools each flow map onto it as it arrives
    (after the window slid, and with the camera's motion removed as from the flow itself), so that the
    last frame's result waits for no pooling of the whole window."""
    from workers.pipeline.front import _on_look_grid, look_factor, pool_map

    obj = SceneObject(center_px=(160, 120), size_px=(70, 50), frequency_hz=4.0, force_n=6.0, release_frame=30)
    scene = Scene(
        width=320, height=240, frames=60, fps=30.0, objects=(obj,), seed=4, shake_px=shake_px, shake_hz=2.0
    )
    live, _ = _pushed(scene, window_frames=32, lead_frames=4)
    if not shake_px:
        assert live.window.base > 0, "the window should have slid"  # (a shaking camera moves from the start)
    n = live.window.flows
    buffers = live.window.buffers(n)
    factor = look_factor(buffers.flow.shape[2])
    assert factor == 2
    assert buffers.camera_removed == (shake_px > 0)
    assert buffers.pooled_flow is not None
    expected = np.empty_like(buffers.pooled_flow)
    for i in range(n):
        pool_map(buffers.flow[i], factor, out=expected[i])
    np.testing.assert_allclose(buffers.pooled_flow, expected, atol=1e-5)
    pooled, used = _on_look_grid(buffers)
    assert used == factor
    assert pooled is buffers.pooled_flow


@pytest.mark.parametrize("where", ["inside", "at-the-border"])
def test_an_estimates_depth_read_around_its_region_gives_the_whole_grids_depth_track(where: str) -> None:
    """An estimate copies only the window's depth around its moving region (grown by DEPTH_MARGIN_PX);
    the object's depth track over that crop is the one over the whole grid, the region's eroded core
    included (with no margin, the erosion sees the crop's edge as the object's and the track differs)."""
    import workers.pipeline.live as live_module
    from workers.pipeline.metric import depth_track

    rng = np.random.default_rng(4)
    depth = (1.0 + 0.3 * rng.random((7, 40, 50))).astype(np.float32)
    region = np.zeros((40, 50), bool)
    top, left = (10, 14) if where == "inside" else (0, 0)
    region[top : top + 12, left : left + 15] = True
    region[top + 5 : top + 12, left + 15 : left + 22] = True  # not a rectangle
    whole = depth_track(depth, region)
    for margin, same in ((live_module.DEPTH_MARGIN_PX, True), (0, False)):
        rows, cols = live_module._around(region, margin=margin)
        cropped = depth_track(depth[:, rows, cols], region[rows, cols])
        assert np.array_equal(cropped, whole) == same, (margin, cropped - whole)
