"""Live estimation: frames one at a time, bounded memory, honest intervals, the final analysis."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from workers.pipeline.analysis import Excitation
from workers.pipeline.clipio.types import Intrinsics
from workers.pipeline.errors import ClipError, ParameterError
from workers.pipeline.live import LiveAnalysis, LiveConfig
from workers.pipeline.synth import Scene, SceneObject, SceneReader


def _scene(frames: int = 100, release: int = 12) -> Scene:
    obj = SceneObject(
        center_px=(160, 120),
        size_px=(80, 60),
        frequency_hz=4.5,
        mass_kg=0.8,
        force_n=6.0,
        release_frame=release,
    )
    return Scene(width=320, height=240, frames=frames, fps=30.0, objects=(obj,), seed=5)


def _live(scene: Scene, **config: object) -> LiveAnalysis:
    fx, fy, cx, cy = scene.intrinsics
    return LiveAnalysis(
        width=scene.width,
        height=scene.height,
        intrinsics=Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy),
        config=LiveConfig(fps=scene.fps, **config),  # type: ignore[arg-type]
        excitation=Excitation(kind="step_release", value=6.0),
    )


def test_estimates_converge_on_the_truth_and_the_final_analysis_uses_the_live_flow() -> None:
    scene = _scene()
    truth = scene.truth()["objects"][0]
    live = _live(scene)
    estimates = []
    for frame in SceneReader(scene).frames():
        live.push(rgb=frame.rgb, depth_m=frame.depth_m, timestamp_s=frame.timestamp_s)
        if frame.index % 4 == 3:
            live.wait(10)
            est = live.estimate()
            if est is not None:
                estimates.append(est)
    assert estimates, "motion was never seen"
    assert not any(e.converged for e in estimates[:1])
    converged = [e for e in estimates if e.converged]
    assert converged, [e.relative_uncertainty for e in estimates]
    first = converged[0]
    assert first.relative_uncertainty <= 0.01
    f_true = truth["eigenfrequency_hz"]
    for est in estimates:
        low, high = est.interval_hz()
        assert low <= f_true <= high, (
            est.frames_used,
            est.eigenfrequency_hz,
            est.eigenfrequency_uncertainty_hz,
        )
    assert first.stiffness_n_per_m is not None
    assert first.stiffness_uncertainty_n_per_m is not None
    assert (
        abs(first.stiffness_n_per_m - truth["stiffness_n_per_m"]) <= 2.5 * first.stiffness_uncertainty_n_per_m
    )
    assert abs(first.release_time_s - truth["release_time_s"]) < 2 / scene.fps
    analysis = live.finish(excitations=[Excitation(kind="step_release", value=6.0)])
    obj = analysis.objects[0]
    assert abs(obj.eigenfrequency_hz - f_true) / f_true < 1e-3
    assert abs(obj.mass_kg - 0.8) / 0.8 < 0.02  # type: ignore[operator]
    assert analysis.frames_used[1] == scene.frames
    assert analysis.labels.shape == (scene.height, scene.width)
    # measured over the box that moves (the live flow cut to it), not the whole frame
    x, y, w, h = analysis.parameters["region"]["box_px"]
    assert w * h < 0.5 * scene.width * scene.height
    assert x <= 160 - 40
    assert x + w >= 160 + 40
    assert y <= 120 - 30
    assert y + h >= 120 + 30
    assert analysis.labels[120, 160] == obj.id
    assert not analysis.labels[:, : max(x - 1, 0)].any()


def test_memory_is_bounded_by_the_window() -> None:
    scene = _scene(frames=120, release=70)
    live = _live(scene, window_frames=32, lead_frames=4)
    names = ("flow", "gray", "times")
    shapes = [live.window.buffer_shapes()[name] for name in names]
    for frame in SceneReader(scene).frames():
        live.push(rgb=frame.rgb, depth_m=frame.depth_m, timestamp_s=frame.timestamp_s)
    live.wait(10)
    assert [live.window.buffer_shapes()[name] for name in names] == shapes
    assert live.frames_received == 120
    analysis = live.finish(excitations=[])
    first, last = analysis.frames_used
    assert last - first <= 32
    # The window slides (keeping its last 4 frames) until the motion at frame 70, then fills from there.
    assert 70 - 32 < first <= 70 - 4, "the window holds the frames from just before the motion"
    assert last >= 70 + 16
    assert any(q.code == "window" for q in analysis.quality)


def test_a_lagging_flow_leaves_the_window_its_frames_after_the_motion(monkeypatch) -> None:
    """The window slides as far as the flow has reached, which lags the frames (a loaded machine): once the
    motion is seen, the window starts ``lead_frames`` before it however far the flow lagged, and the
    rest of it follows the motion (a lag of 8 pairs left it 8 frames short, as many more before it)."""
    import time

    from workers.pipeline import live_window as window_module

    plain = window_module.flow_stream

    def lagging(grays, **kw):
        for flow in plain(grays, **kw):
            time.sleep(0.01)  # slower than the frames are pushed: the flow runs the bounded lag behind
            yield flow

    monkeypatch.setattr(window_module, "flow_stream", lagging)
    scene = _scene(frames=120, release=70)
    live = _live(scene, window_frames=32, lead_frames=4)
    for frame in SceneReader(scene).frames():
        live.push(rgb=frame.rgb, depth_m=frame.depth_m, timestamp_s=frame.timestamp_s)
    live.wait(20)
    motion = live.window.motion_at
    assert motion is not None
    assert 68 <= motion <= 76
    first, last = live.finish(excitations=[]).frames_used
    assert first == motion - 4
    assert last - first == 32


def test_bad_frames_are_refused_with_their_index() -> None:
    live = _live(_scene())
    try:
        rgb = np.zeros((240, 320, 3), np.uint8)
        live.push(rgb=rgb, timestamp_s=0.0)
        with pytest.raises(ClipError, match="frame 1: colour is"):
            live.push(rgb=np.zeros((10, 10, 3), np.uint8), timestamp_s=0.1)
        with pytest.raises(ClipError, match="frame 1: timestamp"):
            live.push(rgb=rgb, timestamp_s=0.0)
        with pytest.raises(ClipError, match="frame 1: depth"):
            live.push(rgb=rgb, depth_m=np.zeros((5, 5), np.float32), timestamp_s=0.2)
        assert live.frames_received == 1
        assert live.estimate() is None
    finally:
        live.close()


def test_config_errors_say_the_fix() -> None:
    with pytest.raises(ParameterError, match="window_frames"):
        LiveConfig(window_frames=4)
    with pytest.raises(ParameterError, match="target_relative_uncertainty"):
        LiveConfig(target_relative_uncertainty=0)


def test_a_stream_that_stops_early_is_analysed_over_a_band_its_window_barely_holds() -> None:
    """Twenty frames of an 8 Hz vibration and a band from 5 Hz: the window holds 6 frequencies of the band,
    too few to calibrate the detection on; every frequency the window holds calibrates it instead (a
    stream that stopped early gets its result, not an internal error); ten frames are too few for
    anything, which is said."""
    from workers.pipeline.analysis import AnalysisConfig
    from workers.pipeline.errors import AnalysisError

    obj = SceneObject(center_px=(160, 120), size_px=(80, 60), frequency_hz=8.0, mass_kg=0.3, force_n=6.0)
    scene = Scene(width=320, height=240, frames=20, fps=30.0, objects=(obj,), seed=6)
    config = AnalysisConfig(min_frequency_hz=5.0)
    live = _live(scene)
    for frame in SceneReader(scene).frames():
        live.push(rgb=frame.rgb, depth_m=frame.depth_m, timestamp_s=frame.timestamp_s)
    analysis = live.finish(analysis_config=config, excitations=[Excitation(kind="step_release", value=6.0)])
    assert analysis.objects
    assert analysis.objects[0].eigenfrequency_hz == pytest.approx(8.0, rel=0.05)
    short = _live(replace(scene, frames=10))
    for frame in SceneReader(replace(scene, frames=10)).frames():
        short.push(rgb=frame.rgb, depth_m=frame.depth_m, timestamp_s=frame.timestamp_s)
    with pytest.raises(AnalysisError, match="analyse more frames"):
        short.finish(analysis_config=config, excitations=[])
