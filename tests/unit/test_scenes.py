"""The accuracy tier's scene cache (``tests/scenes.py``) keeps analyses, never the frames of a clip."""

from __future__ import annotations

from pathlib import Path

from tests import scenes
from workers.pipeline.synth import Scene, SceneObject


def test_a_cached_run_holds_no_frames(tmp_path: Path) -> None:
    scene = Scene(
        width=48, height=32, frames=8, objects=(SceneObject(center_px=(24, 16), size_px=(12, 10)),), seed=77
    )
    clip, path = scenes.rendered(scene, tmp_path)
    assert path.is_file()
    for frames in (clip.rgb, clip.depth):
        assert frames.shape[0] == 0
        # A view of the rendered frames would keep them all in memory for the whole session.
        assert frames.base is None
    assert clip.mask.shape == (32, 48)
