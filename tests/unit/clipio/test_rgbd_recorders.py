"""Depth from the RGB-D recorders' own layouts: Azure Kinect / Orbbec ``.mkv`` recordings and Open3D datasets,
written for real (PyAV's Matroska muxer, OpenCV's PNG and JPEG encoders) and read back."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from eigenscope.cli import main
from workers.pipeline.clipio import ClipOverrides, detect_format, open_clip
from workers.pipeline.clipio import writers as w
from workers.pipeline.clipio.mkv import DEPTH_MODES, calibration_json, parse_calibration
from workers.pipeline.errors import ClipError

# ------------------------------------------------------------------------------------ Azure Kinect .mkv


def _object_interior(depth_mm: Any) -> Any:
    """Pixels of the near object (0.7-0.9 m) at least 2 px from its edge, where depth is smooth."""
    mask = (depth_mm > 700) & (depth_mm < 900)
    inner = mask.copy()
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            inner &= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return inner


def assert_depth_matches(reader: Any, truth: Any, frames: range) -> None:
    """Over ``frames``: depth on more than 90 % of the pixels, a median error under 1 mm there, and a
    99th percentile error under 6 mm on the object's interior. The textured background changes by ~17 mm
    a pixel, so its reprojection through another camera and back errs by a neighbour's difference: the
    edges and the background are not held to the object's bound."""
    everywhere, interior, covered = [], [], []
    for frame in reader.frames(frames.start, frames.stop):
        expected = truth.depth[frame.index].astype(np.float64) * 0.001
        got = frame.depth_m
        assert got is not None
        assert got.shape == expected.shape
        ok = np.isfinite(got)
        covered.append(ok.mean())
        err = np.abs(got - expected)
        everywhere.append(err[ok])
        inner = _object_interior(truth.depth[frame.index])
        assert inner.sum() > 100
        assert np.isfinite(got[inner]).all()
        interior.append(err[inner])
    assert float(np.mean(covered)) > 0.9
    assert float(np.median(np.concatenate(everywhere))) < 0.001
    assert float(np.percentile(np.concatenate(interior), 99)) < 0.006


@pytest.mark.parametrize("mode", ["NFOV_2X2BINNED", "NFOV_UNBINNED", "WFOV_2X2BINNED"])
def test_k4a_recording_with_calibration(truth: Any, tmp_path: Path, mode: str) -> None:
    path = w.write_k4a_mkv(
        tmp_path / "rec.mkv",
        truth.rgb,
        depth=truth.depth,
        fps=truth.fps,
        intrinsics=truth.intrinsics,
        options=w.K4aOptions(depth_mode=mode),
    )
    assert detect_format(path) == "k4a-mkv"
    with open_clip(path) as reader:
        info = reader.info
        assert info.format == "k4a-mkv"
        assert info.frames == len(truth.rgb)
        assert (info.width, info.height) == (96, 80)
        assert info.has_depth
        assert info.depth_scale == 0.001
        assert info.fps == pytest.approx(truth.fps)
        assert info.timestamps_s is not None
        k = info.intrinsics
        assert k is not None
        np.testing.assert_allclose((k.fx, k.fy, k.cx, k.cy), truth.intrinsics, atol=1e-6)
        dw, dh = DEPTH_MODES[mode][2]
        assert f"DEPTH:b16g {dw}x{dh}" in info.streams
        assert "calibration.json" in info.streams
        assert any(mode in note and "reprojected" in note for note in info.notes)
        # The depth camera sees the colour view 3 cm away: edges of the colour image may have no depth.
        assert_depth_matches(reader, truth, range(0, len(truth.rgb)))
        first = next(iter(reader.frames(5, 6)))
        assert first.index == 5
        # MJPEG is lossy; the frame is still closer to its own truth than to its neighbours'.
        errors = [float(np.abs(first.rgb.astype(float) - truth.rgb[i]).mean()) for i in (4, 5, 6)]
        assert errors[1] < 8
        assert errors[1] < min(errors[0], errors[2])


def test_k4a_depth_delay_is_paired_by_time(truth: Any, tmp_path: Path) -> None:
    path = w.write_k4a_mkv(
        tmp_path / "rec.mkv",
        truth.rgb,
        depth=truth.depth,
        fps=truth.fps,
        intrinsics=truth.intrinsics,
        options=w.K4aOptions(depth_delay_frames=0.3),
    )
    with open_clip(path) as reader:
        assert reader.info.frames == len(truth.rgb)
        assert_depth_matches(reader, truth, range(10, 14))


def test_k4a_without_calibration_takes_same_size_depth_as_aligned(truth: Any, tmp_path: Path) -> None:
    path = w.write_k4a_mkv(tmp_path / "rec.mkv", truth.rgb, depth=truth.depth, fps=truth.fps)
    overrides = ClipOverrides(fx=70.0, depth_scale=0.002)
    with open_clip(path, overrides=overrides) as reader:
        info = reader.info
        assert info.has_depth
        assert info.depth_scale == 0.002
        assert info.intrinsics is not None
        assert info.intrinsics.fx == 70.0
        assert "calibration.json" not in info.streams
        frame = next(iter(reader.frames(3, 4)))
    assert frame.depth_m is not None
    expected = truth.depth[3].astype(np.float32) * np.float32(0.002)
    valid = truth.depth[3] > 0
    np.testing.assert_allclose(frame.depth_m[valid], expected[valid], rtol=1e-6)


def test_k4a_depth_of_another_size_without_calibration_is_left_out_with_a_note(
    truth: Any, tmp_path: Path
) -> None:
    small = np.ascontiguousarray(truth.depth[:, ::2, ::2])
    path = w.write_k4a_mkv(tmp_path / "rec.mkv", truth.rgb, depth=small, fps=truth.fps)
    with open_clip(path) as reader:
        assert not reader.info.has_depth
        assert any("48x40" in n and "no calibration.json" in n for n in reader.info.notes)
        assert next(iter(reader.frames(0, 1))).depth_m is None


def test_k4a_probe_reports_the_depth_track(
    truth: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = w.write_k4a_mkv(
        tmp_path / "rec.mkv", truth.rgb, depth=truth.depth, fps=truth.fps, intrinsics=truth.intrinsics
    )
    assert main(["probe", str(path)]) == 0
    out = capsys.readouterr().out
    assert "format:      k4a-mkv" in out
    assert "depth:       yes, 0.001 m/unit, from DEPTH track 1 (b16g 320x288, mm)" in out
    assert "fx=78.75" in out
    assert main(["probe", str(path), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["has_depth"] is True
    assert data["depth_source"].startswith("DEPTH track")


def test_k4a_calibration_follows_the_sdk_mode_tables() -> None:
    """Normalised parameters of a real Azure Kinect calibration, converted by the SDK's published rule:
    colour cut from the 4:3 image scaled to the mode's width, depth binned and cropped per mode."""
    color = [0.49984714388847351, 0.50661760568618774, 0.47796511650085449, 0.63742393255233765]
    depth = [0.50460, 0.51050, 0.49270, 0.49300]

    def cam(params: list[float], purpose: str, w_: int, h_: int, rt: Any) -> Any:
        return {
            "Intrinsics": {"ModelParameters": [*params, *([0.0] * 10)]},
            "Purpose": purpose,
            "SensorWidth": w_,
            "SensorHeight": h_,
            "Rt": rt,
        }

    rot = [
        0.9999992,
        0.0011818,
        -0.0004481,
        -0.0011388,
        0.9962806,
        0.0861603,
        0.0005483,
        -0.0861598,
        0.9962812,
    ]
    doc = {
        "CalibrationInformation": {
            "Cameras": [
                cam(depth, "CALIBRATION_CameraPurposeDepth", 1024, 1024, None),
                cam(
                    color,
                    "CALIBRATION_CameraPurposePhotoVideo",
                    4096,
                    3072,
                    {"Rotation": rot, "Translation": [-0.032083, -0.0022054, 0.0038837]},
                ),
            ]
        }
    }
    cal = parse_calibration(
        json.dumps(doc).encode(), color_size=(1280, 720), depth_size=(640, 576), depth_mode=None
    )
    assert cal.depth_mode == "NFOV_UNBINNED"
    # 720p: the 4096x3072 image scaled to 1280x960, 120 rows cropped top and bottom; pixel centres at 0.
    assert cal.color.fx == pytest.approx(0.47796511650085449 * 1280)
    assert cal.color.fy == pytest.approx(0.63742393255233765 * 960)
    assert cal.color.cx == pytest.approx(0.49984714388847351 * 1280 - 0.5)
    assert cal.color.cy == pytest.approx(0.50661760568618774 * 960 - 120 - 0.5)
    # NFOV unbinned: 1024x1024 cropped by (192, 180) to 640x576.
    assert cal.depth.fx == pytest.approx(0.49270 * 1024)
    assert cal.depth.cx == pytest.approx(0.50460 * 1024 - 192 - 0.5)
    assert cal.depth.cy == pytest.approx(0.51050 * 1024 - 180 - 0.5)
    np.testing.assert_allclose(cal.rotation, np.asarray(rot).reshape(3, 3))
    np.testing.assert_allclose(cal.translation_m, [-0.032083, -0.0022054, 0.0038837])
    binned = parse_calibration(
        json.dumps(doc).encode(), color_size=(2048, 1536), depth_size=(320, 288), depth_mode="NFOV_2X2BINNED"
    )
    assert binned.color.cy == pytest.approx(0.50661760568618774 * 1536 - 0.5)
    assert binned.depth.cx == pytest.approx(0.50460 * 512 - 96 - 0.5)


def test_k4a_calibration_round_trips_through_its_writer() -> None:
    doc = calibration_json(
        color=(600.0, 601.0, 639.0, 361.0),
        color_size=(1280, 720),
        depth=(500.0, 502.0, 319.0, 287.0),
        depth_mode="NFOV_UNBINNED",
        translation_m=np.array([-0.03, 0.0, 0.004]),
    )
    cal = parse_calibration(
        json.dumps(doc).encode(), color_size=(1280, 720), depth_size=(640, 576), depth_mode="NFOV_UNBINNED"
    )
    np.testing.assert_allclose((cal.color.fx, cal.color.fy, cal.color.cx, cal.color.cy), (600, 601, 639, 361))
    np.testing.assert_allclose((cal.depth.fx, cal.depth.fy, cal.depth.cx, cal.depth.cy), (500, 502, 319, 287))
    np.testing.assert_allclose(cal.translation_m, [-0.03, 0.0, 0.004])


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        (b"{not json", "not valid JSON"),
        (json.dumps({"CalibrationInformation": {}}).encode(), "no CalibrationInformation.Cameras"),
        (json.dumps({"CalibrationInformation": {"Cameras": []}}).encode(), "no camera with Purpose"),
    ],
)
def test_k4a_bad_calibration_is_a_clip_error(doc: bytes, message: str) -> None:
    with pytest.raises(ClipError, match=message):
        parse_calibration(doc, color_size=(1280, 720), depth_size=(640, 576), depth_mode=None)


def test_k4a_depth_mode_tag_must_match_the_frames() -> None:
    doc = calibration_json(
        color=(600.0, 600.0, 639.5, 359.5),
        color_size=(1280, 720),
        depth=(500.0, 500.0, 320, 288),
        depth_mode="NFOV_UNBINNED",
    )
    with pytest.raises(ClipError, match="K4A_DEPTH_MODE=WFOV_UNBINNED"):
        parse_calibration(
            json.dumps(doc).encode(),
            color_size=(1280, 720),
            depth_size=(640, 576),
            depth_mode="WFOV_UNBINNED",
        )
    with pytest.raises(ClipError, match="match no K4A depth mode"):
        parse_calibration(
            json.dumps(doc).encode(), color_size=(1280, 720), depth_size=(600, 500), depth_mode=None
        )


def test_a_plain_mkv_video_is_still_a_video(truth: Any, tmp_path: Path) -> None:
    path = w.write_video(tmp_path / "c.mkv", truth.rgb, fps=30.0, codec="ffv1")
    assert detect_format(path) == "video"


# ----------------------------------------------------------------------------------------------- Open3D


ASYMMETRIC = (81.0, 77.0, 50.5, 37.25)  # fx != fy and cx != cy: a transposed matrix would show


@pytest.mark.parametrize("as_zip", [True, False])
def test_open3d_dataset(truth: Any, tmp_path: Path, as_zip: bool) -> None:
    depth = (truth.depth.astype(np.uint32) * 5).clip(0, 65535).astype(np.uint16)  # 5000 units per metre
    target = tmp_path / ("o3d.zip" if as_zip else "o3d")
    path = w.write_open3d(
        target,
        truth.rgb,
        depth=depth,
        intrinsics=ASYMMETRIC,
        units_per_metre=5000.0,
        fps=15.0,
        options=w.Open3dOptions(image_format="png", root="scene/"),
    )
    assert detect_format(path) == "open3d"
    with open_clip(path) as reader:
        info = reader.info
        assert info.format == "open3d"
        assert info.frames == len(truth.rgb)
        assert info.fps == 15.0
        assert info.fps_source == "bundle"
        assert info.has_depth
        assert info.depth_scale == pytest.approx(1 / 5000)
        assert info.intrinsics is not None
        np.testing.assert_allclose(
            (info.intrinsics.fx, info.intrinsics.fy, info.intrinsics.cx, info.intrinsics.cy), ASYMMETRIC
        )
        frames = list(reader.frames(2, 5))
    assert [f.index for f in frames] == [2, 3, 4]
    np.testing.assert_array_equal(frames[0].rgb, truth.rgb[2])
    assert frames[0].depth_m is not None
    valid = truth.depth[2] > 0
    np.testing.assert_allclose(frames[0].depth_m[valid], truth.depth[2][valid] * 0.001, rtol=1e-6)
    assert frames[1].timestamp_s == pytest.approx(3 / 15.0)


def test_open3d_defaults_flags_and_intrinsic_json(truth: Any, tmp_path: Path) -> None:
    path = w.write_open3d(
        tmp_path / "o3d.zip",
        truth.rgb,
        depth=truth.depth,
        intrinsics=ASYMMETRIC,
        options=w.Open3dOptions(intrinsic_name="intrinsic.json"),
    )
    with open_clip(path) as reader:
        assert reader.info.depth_scale == 0.001  # Open3D's default: 1000 units per metre
        assert reader.info.fps is None
        assert "intrinsic.json" in reader.info.streams
    with open_clip(path, overrides=ClipOverrides(fps=60.0, fx=100.0, depth_scale=0.0005)) as reader:
        assert reader.info.fps == 60.0
        assert reader.info.depth_scale == 0.0005
        assert reader.info.intrinsics is not None
        assert reader.info.intrinsics.fx == 100.0
        assert reader.info.intrinsics.cy == 37.25


def test_open3d_metres_per_unit_scale_gets_a_note(truth: Any, tmp_path: Path) -> None:
    path = w.write_open3d(tmp_path / "o3d.zip", truth.rgb, depth=truth.depth, units_per_metre=0.001)
    with open_clip(path) as reader:
        assert reader.info.depth_scale == 0.001
        assert any("metres per unit" in n for n in reader.info.notes)


def test_open3d_intrinsic_of_another_size_is_scaled(truth: Any, tmp_path: Path) -> None:
    path = w.write_open3d(tmp_path / "o3d", truth.rgb, intrinsics=(80.0, 80.0, 47.5, 39.5))
    doc = json.loads((path / "camera_intrinsic.json").read_text())
    doc["width"], doc["height"] = 192, 160  # written for frames twice the size
    doc["intrinsic_matrix"] = [160.0, 0, 0, 0, 160.0, 0, 95.5, 79.5, 1]
    (path / "camera_intrinsic.json").write_text(json.dumps(doc))
    with open_clip(path) as reader:
        k = reader.info.intrinsics
    assert k is not None
    np.testing.assert_allclose((k.fx, k.fy, k.cx, k.cy), (80.0, 80.0, 47.5, 39.5))


def _rewrite(path: Path, name: str, data: bytes | None) -> None:
    tmp = path.with_suffix(".tmp")
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tmp, "w") as dst:
        for item in src.infolist():
            if item.filename != name:
                dst.writestr(item, src.read(item))
        if data is not None:
            dst.writestr(name, data)
    shutil.move(tmp, path)


@pytest.mark.parametrize(
    ("name", "data", "message"),
    [
        (
            "camera_intrinsic.json",
            b'{"intrinsic_matrix": [81, 0, 50.5, 0, 77, 37.25, 0, 0, 1]}',
            "column-major",
        ),
        ("camera_intrinsic.json", b'{"intrinsic_matrix": [1, 2]}', "9 numbers"),
        ("camera_intrinsic.json", b"[]", "JSON object"),
        ("config.json", b'{"depth_scale": -3}', "must be positive"),
        ("config.json", b'{"fps": "thirty"}', "finite number"),
        ("depth/000003.png", None, "24 colour frames but 23 depth frames"),
    ],
)
def test_open3d_malformed_files_say_what_to_fix(
    truth: Any, tmp_path: Path, name: str, data: bytes | None, message: str
) -> None:
    path = w.write_open3d(tmp_path / "o3d.zip", truth.rgb, depth=truth.depth, intrinsics=ASYMMETRIC, fps=30.0)
    _rewrite(path, name, data)
    with pytest.raises(ClipError, match=message):
        open_clip(path).close()
