"""The accuracy tier's scene cache (``tests/scenes.py``) keeps analyses, never the frames of a clip, and
its workers make each once."""

from __future__ import annotations

import multiprocessing
import time
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


def _ask(folder: Path, made: Path, out: Path) -> None:
    def make() -> str:
        with made.open("a") as log:
            log.write("made\n")
        time.sleep(0.3)  # long enough that the other process asks meanwhile
        return "value"

    out.write_text(scenes._made_once(folder, "key", make))


def test_processes_sharing_a_folder_make_a_value_once(tmp_path: Path) -> None:
    """The xdist workers' shared cache: two processes ask at once; one makes, the other loads."""
    made = tmp_path / "made.log"
    outs = [tmp_path / f"out-{i}.txt" for i in range(2)]
    context = multiprocessing.get_context("fork")
    workers = [context.Process(target=_ask, args=(tmp_path / "shared", made, out)) for out in outs]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(timeout=60)
        assert worker.exitcode == 0
    assert made.read_text() == "made\n"
    assert [out.read_text() for out in outs] == ["value", "value"]
