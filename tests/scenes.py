"""Whole-pipeline analyses of rendered ground-truth scenes, shared by the accuracy tier.

A scene is rendered, written as an npz bundle and analysed once per test session: every later request for
the same scene with the same configuration and excitation gets the same :class:`SceneRun` (tests read it,
never change it). Under pytest-xdist the session's workers share them through the scene folder: the
first worker to ask renders or analyses under a file lock and stores the result there; another that
asks for it meanwhile waits for it, then loads it (:func:`_made_once`). Test modules use this module
directly (``from tests.scenes import run_scene``) or through the ``run_scene`` fixture of
``tests/accuracy/conftest.py``; nothing is imported from a conftest.

:data:`ACCURACY_ROWS` collects the ground-truth accuracy figures printed at the end of a run
(``tests/conftest.py``, which hands each test's new rows to its report, so they reach the controller
under pytest-xdist too).
"""

from __future__ import annotations

import fcntl
import hashlib
import itertools
import pickle
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from workers.pipeline.analysis import Analysis, AnalysisConfig, Excitation, analyze
from workers.pipeline.clipio import open_clip, write_npz
from workers.pipeline.synth import Scene, SyntheticClip, render

#: Rows printed at the end of the session (see tests/conftest.py::pytest_terminal_summary).
ACCURACY_ROWS: list[dict[str, Any]] = []


@dataclass(frozen=True)
class SceneRun:
    """A rendered scene and its analysis.

    ``clip`` keeps the truth, the true mask and the shadow mask; its frames are dropped once the clip is
    written (``path``), so that a session's cache holds analyses, not videos.
    """

    clip: SyntheticClip
    analysis: Analysis
    path: Path

    def iou(self, label: int = 1, true_label: int = 1) -> float:
        ours = self.analysis.labels == label
        truth = self.clip.mask == true_label
        return float((ours & truth).sum() / max((ours | truth).sum(), 1))

    def rel(self, key: str, obj: int = 1, true_obj: int | None = None) -> float:
        truth = self.clip.truth["objects"][(true_obj or obj) - 1][key]
        ours = getattr(self.analysis.objects[obj - 1], key)
        return float(abs(ours - truth) / abs(truth))


def excitation_of(scene: Scene, index: int = 0) -> Excitation:
    """The excitation the scene's object ``index`` really had."""
    obj = scene.objects[index]
    if obj.excitation == "impulse":
        return Excitation(kind="impulse", value=obj.impulse_ns)
    return Excitation(kind="step_release", value=obj.force_n)


#: Scene -> the npz bundle of its rendering (written once per session).
_CLIPS: dict[str, tuple[SyntheticClip, Path]] = {}
#: (scene, config, excitation) -> the analysis of the scene's own rendering.
_RUNS: dict[str, SceneRun] = {}
_CUSTOM = itertools.count()

_T = TypeVar("_T")


def _made_once(folder: Path, key: str, make: Callable[[], _T]) -> _T:
    """``make()``, made once among the processes that share ``folder`` (the session's xdist workers):
    the first to ask makes it under a lock on ``folder/key.lock`` and stores it in ``folder/key.pickle``;
    the others wait on the lock and load what it stored."""
    folder.mkdir(parents=True, exist_ok=True)
    stored = folder / f"{key}.pickle"
    with open(folder / f"{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, by a process that died too
        if stored.exists():
            stored_value: _T = pickle.loads(stored.read_bytes())  # written by this session's own workers
            return stored_value
        value = make()
        partial = stored.with_suffix(".partial")
        partial.write_bytes(pickle.dumps(value))
        partial.replace(stored)
        return value


def _slim(clip: SyntheticClip) -> SyntheticClip:
    """``clip`` without its frames (the truth and the masks stay). Empty arrays of their own: a slice
    (``rgb[:0]``) would be a view that keeps every frame alive."""
    return replace(clip, rgb=np.empty_like(clip.rgb[:0]), depth=np.empty_like(clip.depth[:0]))


def _name(*parts: Any) -> str:
    return hashlib.sha1(pickle.dumps(parts)).hexdigest()[:16]


def rendered(scene: Scene, folder: Path) -> tuple[SyntheticClip, Path]:
    """The scene's clip (frames dropped) and the npz bundle that holds it, rendered once per session."""
    key = _name(scene)
    if key not in _CLIPS:
        path = folder / f"scene-{scene.seed}-{key}.npz"

        def make() -> SyntheticClip:
            clip = render(scene)
            write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
            return _slim(clip)

        _CLIPS[key] = (_made_once(folder, f"clip-{key}", make), path)
    return _CLIPS[key]


def _analyse(path: Path, config: AnalysisConfig | None, excitation: Any) -> Analysis:
    with open_clip(path) as reader:
        return analyze(reader, config=config, excitation=excitation)


def run_scene(
    scene: Scene,
    folder: Path,
    *,
    config: AnalysisConfig | None = None,
    excitation: Excitation | list[Excitation] | str | None = "truth",
    clip: SyntheticClip | None = None,
) -> SceneRun:
    """Analyse ``scene`` (``excitation="truth"``: the one it was rendered with).

    Parameters
    ----------
    scene : Scene
    folder : Path
        Where the clips are written (a folder of the session's).
    config : AnalysisConfig, optional
    excitation : Excitation, list of Excitation, ``"truth"`` or None
    clip : SyntheticClip, optional
        A clip to analyse instead of the scene's own rendering (e.g. one with something pasted in): it is
        analysed afresh, never cached. The ``clip`` of a :class:`SceneRun` of the same scene counts as
        the scene's own.
    """
    exc = excitation_of(scene) if excitation == "truth" else excitation
    assert not isinstance(exc, str)
    own, path = rendered(scene, folder)
    if clip is not None and clip is not own:
        path = folder / f"custom-{scene.seed}-{next(_CUSTOM)}.npz"
        write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
        return SceneRun(clip=_slim(clip), analysis=_analyse(path, config, exc), path=path)
    key = _name(scene, config, exc)
    if key not in _RUNS:
        analysis = _made_once(folder, f"analysis-{key}", lambda: _analyse(path, config, exc))
        _RUNS[key] = SceneRun(clip=own, analysis=analysis, path=path)
    return _RUNS[key]
