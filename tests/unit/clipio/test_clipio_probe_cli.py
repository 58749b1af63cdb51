"""``eigenscope probe``: text and JSON output, overrides, one-line errors, and no OpenCV import."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from eigenscope.cli import main
from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.clipio import writers as w


def test_probe_text_for_a_bag(truth: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = bw.write_ros_bag(
        tmp_path / "c.bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
    )
    assert main(["probe", str(path)]) == 0
    out = capsys.readouterr().out
    assert "format:      ros1-bag" in out
    assert "frames:      24 of 96x80 px" in out
    assert "(from timestamps)" in out
    assert "dropped frames: 0" in out
    assert "0.001 m/unit" in out
    assert "/camera/aligned_depth_to_color/image_raw" in out
    assert "fx=78.75" in out


def test_probe_json_with_user_fps(truth: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = w.write_video(tmp_path / "c.mkv", truth.rgb, fps=30.0, codec="ffv1")
    assert main(["probe", str(path), "--fps", "240", "--fx", "500", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["format"] == "video"
    assert data["fps"] == 240.0
    assert data["fps_source"] == "user"
    assert data["container_fps"] == pytest.approx(30.0)
    assert data["intrinsics"]["fx"] == 500.0
    assert data["has_depth"] is False
    assert data["frames"] == 24


def test_probe_error_is_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "notes.mp4"
    path.write_text("not a video")
    assert main(["probe", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("eigenscope probe: error: video: notes.mp4")
    assert "\n" not in err


def test_probe_does_not_import_opencv(truth: Any, tmp_path: Path) -> None:
    zipped = w.write_zip_frames(tmp_path / "c.zip", truth.rgb, depth=truth.depth, fps=30.0)
    bag = bw.write_ros_bag(
        tmp_path / "c.bag", truth.rgb, stamps_ns=truth.stamps_ns, intrinsics=truth.intrinsics
    )
    npz = tmp_path / "c.npz"
    np.savez(npz, rgb=truth.rgb, fps=np.float64(30.0))
    video = w.write_video(tmp_path / "c.mp4", truth.rgb, fps=30.0)
    code = (
        "import sys\n"
        "from workers.pipeline.clipio import open_clip\n"
        "for p in sys.argv[1:]:\n"
        "    with open_clip(p) as r:\n"
        "        assert r.info.frames == 24, r.info\n"
        "assert 'cv2' not in sys.modules, 'probing imported cv2'\n"
    )
    subprocess.run(
        [sys.executable, "-c", code, str(zipped), str(bag), str(npz), str(video)],
        check=True,
        cwd=Path(__file__).resolve().parents[3],
        timeout=60,
    )
