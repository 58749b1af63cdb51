"""One synthetic ground-truth scene, written in every clip format with real writer libraries, analysed end to
end: each format recovers the npz bundle's eigenfrequency within 1%, and its stiffness and mass where the
format carries depth."""

from __future__ import annotations

import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from api_schemas import AnalysisParameters, StepReleaseExcitation
from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.clipio import write_npz
from workers.pipeline.clipio import writers as w
from workers.pipeline.synth import Scene, SceneObject, SyntheticClip, render
from workers.runner import run_analysis

#: A whole analysis of one scene in every format.
pytestmark = pytest.mark.slow

FPS = 30.0
T0 = 1_700_000_000_000_000_000
FORCE_N = 5.0
EXCITATION = StepReleaseExcitation(type="step_release", force_n=FORCE_N)


@pytest.fixture(scope="module")
def scene() -> tuple[Scene, SyntheticClip]:
    obj = SceneObject(center_px=(160.0, 120.0), size_px=(70.0, 55.0), frequency_hz=4.0, force_n=FORCE_N)
    sc = Scene(width=320, height=240, frames=96, fps=FPS, objects=(obj,), seed=7)
    return sc, render(sc)


def _stamps(n: int) -> Any:
    return T0 + np.rint(np.arange(n) * 1e9 / FPS).astype(np.int64)


@pytest.fixture(scope="module")
def baseline(scene: tuple[Scene, SyntheticClip], tmp_path_factory: pytest.TempPathFactory) -> Any:
    _, clip = scene
    d = tmp_path_factory.mktemp("npz")
    path = write_npz(d / "c.npz", clip.rgb, fps=FPS, depth=clip.depth, intrinsics=clip.intrinsics)
    result = run_analysis(path, d / "out", excitation=EXCITATION)
    obj = result.objects[0]
    truth = scene[0].truth()["objects"][0]
    assert obj.eigenfrequency_hz == pytest.approx(truth["eigenfrequency_hz"], rel=0.01)
    assert obj.stiffness_n_per_m is not None
    assert obj.mass_kg is not None
    return obj


def _video_with_npz_depth(d: Path, clip: SyntheticClip) -> tuple[Path, dict[str, Any]]:
    video = w.write_video(d / "c.mkv", clip.rgb, fps=FPS, codec="ffv1")
    with zipfile.ZipFile(d / "bundle.zip", "w") as zf:
        zf.write(video, "clip.mkv")
        import cv2

        for i, dep in enumerate(clip.depth):
            zf.writestr(f"depth/{i:04d}.png", bytes(cv2.imencode(".png", dep)[1]))
        fx, fy, cx, cy = clip.intrinsics
        zf.writestr("camera.json", f'{{"fx": {fx}, "fy": {fy}, "cx": {cx}, "cy": {cy}}}')
    return d / "bundle.zip", {}


Writer = Callable[[Path, SyntheticClip], tuple[Path, dict[str, Any]]]

WITH_DEPTH: dict[str, tuple[Writer, bool]] = {
    "zip-frames-png": (
        lambda d, c: (
            w.write_zip_frames(d / "c.zip", c.rgb, depth=c.depth, fps=FPS, intrinsics=c.intrinsics),
            {},
        ),
        True,
    ),
    "tum": (
        lambda d, c: (
            w.write_tum(
                d / "tum.zip",
                c.rgb,
                (c.depth.astype(np.uint32) * 5).clip(0, 65535).astype(np.uint16),
                rgb_times_s=_stamps(len(c.rgb)) * 1e-9,
                depth_times_s=_stamps(len(c.rgb)) * 1e-9 + 0.008,
                intrinsics=c.intrinsics,
            ),
            {},
        ),
        True,
    ),
    "video-zip-with-depth": (_video_with_npz_depth, True),
    "open3d-zip": (
        lambda d, c: (
            w.write_open3d(
                d / "o3d.zip",
                c.rgb,
                depth=c.depth,
                intrinsics=c.intrinsics,
                fps=FPS,
                options=w.Open3dOptions(image_format="png"),
            ),
            {},
        ),
        True,
    ),
    "k4a-mkv-calibrated": (
        lambda d, c: (
            w.write_k4a_mkv(d / "k4a.mkv", c.rgb, depth=c.depth, fps=FPS, intrinsics=c.intrinsics),
            {},
        ),
        False,
    ),
    "ros1-realsense-ros": (
        lambda d, c: (
            bw.write_ros_bag(
                d / "c.bag", c.rgb, stamps_ns=_stamps(96), intrinsics=c.intrinsics, depth=c.depth
            ),
            {},
        ),
        True,
    ),
    "ros1-realsense-sdk": (
        lambda d, c: (
            bw.write_ros_bag(
                d / "rs.bag",
                c.rgb,
                stamps_ns=_stamps(96),
                intrinsics=c.intrinsics,
                depth=c.depth,
                options=bw.RosBagOptions(layout="realsense-sdk"),
            ),
            {},
        ),
        True,
    ),
    "ros2-mcap-file": (
        lambda d, c: (
            next(
                bw.write_ros_bag(
                    d / "b", c.rgb, stamps_ns=_stamps(96), intrinsics=c.intrinsics, depth=c.depth, version=2
                ).glob("*.mcap")
            ),
            {},
        ),
        True,
    ),
    "ros2-zipped-sqlite3": (
        lambda d, c: (
            bw.write_ros2_zip(
                d / "b.zip",
                c.rgb,
                stamps_ns=_stamps(96),
                intrinsics=c.intrinsics,
                depth=c.depth,
                options=bw.RosBagOptions(storage="sqlite3"),
            ),
            {},
        ),
        True,
    ),
    "ros2-compressed": (
        lambda d, c: (
            bw.write_ros_bag(
                d / "bc",
                c.rgb,
                stamps_ns=_stamps(96),
                intrinsics=c.intrinsics,
                depth=c.depth,
                version=2,
                options=bw.RosBagOptions(compressed=True),
            ),
            {},
        ),
        False,
    ),
}


@pytest.mark.parametrize("fmt", list(WITH_DEPTH))
def test_format_with_depth_matches_npz(
    fmt: str, scene: tuple[Scene, SyntheticClip], baseline: Any, tmp_path: Path
) -> None:
    write, lossless = WITH_DEPTH[fmt]
    path, params = write(tmp_path, scene[1])
    result = run_analysis(
        path, tmp_path / "out", excitation=EXCITATION, parameters=AnalysisParameters(**params)
    )
    obj = result.objects[0]
    assert obj.eigenfrequency_hz == pytest.approx(baseline.eigenfrequency_hz, rel=0.01)
    rel = 1e-3 if lossless else 0.03
    assert obj.stiffness_n_per_m == pytest.approx(baseline.stiffness_n_per_m, rel=rel)
    assert obj.mass_kg == pytest.approx(baseline.mass_kg, rel=rel)


@pytest.mark.parametrize(("name", "codec"), [("c.mp4", "libx264"), ("c.avi", "mjpeg"), ("c.mov", "mpeg4")])
def test_video_without_depth_gives_frequency(
    name: str, codec: str, scene: tuple[Scene, SyntheticClip], baseline: Any, tmp_path: Path
) -> None:
    path = w.write_video(tmp_path / name, scene[1].rgb, fps=FPS, codec=codec)
    result = run_analysis(path, tmp_path / "out", excitation=EXCITATION)
    obj = result.objects[0]
    assert obj.eigenfrequency_hz == pytest.approx(baseline.eigenfrequency_hz, rel=0.01)
    assert obj.stiffness_n_per_m is None
    assert obj.mass_kg is None


def test_video_without_depth_with_depth_m_and_intrinsics(
    scene: tuple[Scene, SyntheticClip], baseline: Any, tmp_path: Path
) -> None:
    sc, clip = scene
    path = w.write_video(tmp_path / "c.mp4", clip.rgb, fps=FPS)
    params = AnalysisParameters(fx=clip.intrinsics[0], fy=clip.intrinsics[1], depth_m=sc.objects[0].depth_m)
    result = run_analysis(path, tmp_path / "out", excitation=EXCITATION, parameters=params)
    obj = result.objects[0]
    assert obj.eigenfrequency_hz == pytest.approx(baseline.eigenfrequency_hz, rel=0.01)
    assert obj.stiffness_n_per_m == pytest.approx(baseline.stiffness_n_per_m, rel=0.03)
    assert obj.mass_kg == pytest.approx(baseline.mass_kg, rel=0.03)


def test_container_rate_wrong_user_fps_wins(
    scene: tuple[Scene, SyntheticClip], baseline: Any, tmp_path: Path
) -> None:
    """The file claims 10 fps (as high-speed cameras misreport); the given fps is the truth."""
    path = w.write_video(tmp_path / "c.mkv", scene[1].rgb, fps=10.0, codec="ffv1")
    wrong = run_analysis(path, tmp_path / "o1", excitation=EXCITATION)
    assert wrong.objects[0].eigenfrequency_hz == pytest.approx(baseline.eigenfrequency_hz / 3, rel=0.01)
    right = run_analysis(path, tmp_path / "o2", excitation=EXCITATION, parameters=AnalysisParameters(fps=FPS))
    assert right.objects[0].eigenfrequency_hz == pytest.approx(baseline.eigenfrequency_hz, rel=0.01)


def test_bag_with_dropped_frames_keeps_frequency(scene: tuple[Scene, SyntheticClip], tmp_path: Path) -> None:
    """Frames lost in recording leave gaps in the header stamps; the frequency must not be biased."""
    sc, clip = scene
    keep = np.ones(96, bool)
    keep[[10, 11, 30, 47, 48, 49, 70]] = False
    stamps = _stamps(96)[keep]
    path = bw.write_ros_bag(
        tmp_path / "drop.bag",
        clip.rgb[keep],
        stamps_ns=stamps,
        intrinsics=clip.intrinsics,
        depth=clip.depth[keep],
    )
    result = run_analysis(path, tmp_path / "out", excitation=EXCITATION)
    truth = sc.truth()["objects"][0]
    assert result.objects[0].eigenfrequency_hz == pytest.approx(truth["eigenfrequency_hz"], rel=0.01)
