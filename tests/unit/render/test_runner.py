"""The shared runner (CLI and service) writes every image and lists it in the result's artifacts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from api_schemas import AnalysisParameters, StepReleaseExcitation
from tests.unit.render.conftest import Analysed
from tests.unit.render.helpers import decode, gif_frames
from workers.pipeline.figures import ARTIFACT_FILES
from workers.runner import MASK_FILE, RESULT_FILE, run_analysis


def test_run_analysis_lists_every_image(small: Analysed, tmp_path: Path):
    result = run_analysis(
        small.clip_path,
        tmp_path,
        excitation=StepReleaseExcitation(type="step_release", force_n=10.0),
        parameters=AnalysisParameters(),
    )
    artifacts = result.artifacts.model_dump()
    # Every file, the result itself included.
    assert artifacts == {**ARTIFACT_FILES, "result": RESULT_FILE}
    assert artifacts["mask"] == MASK_FILE
    for name in ARTIFACT_FILES.values():
        if name.endswith(".npz"):
            np.load(tmp_path / name)  # the mode shapes: an archive, not an image
        elif name.endswith(".gif"):
            frames, _ = gif_frames(tmp_path / name)  # their animation
            assert len(frames) > 1
        else:
            decode(tmp_path / name)
    written = json.loads((tmp_path / RESULT_FILE).read_text())
    assert written["artifacts"] == artifacts
    assert written["timings_s"]["rendering"] > 0


def test_a_force_log_on_another_clock_is_refused_with_the_fix(small_clip: Path) -> None:
    """A log whose times do not overlap the clip's frames (kept on the robot's clock, no offset given) is
    a ForceError saying to give the offset; with the offset, the push in it is the excitation."""
    import math

    import pytest

    from api_schemas import ForceLog
    from workers.pipeline.clipio import open_clip
    from workers.pipeline.errors import ForceError
    from workers.runner import recorded_force

    times = [1234.4 + i / 500 for i in range(400)]  # the robot's clock: 1234.5 s at the clip's first frame
    held = [(6.0 if t < 1234.8 else 0.0) + 0.02 * math.sin(7.0 * i) for i, t in enumerate(times)]
    log = ForceLog(time_s=times, force_n=held, name="push.csv")
    with open_clip(small_clip) as reader:
        with pytest.raises(ForceError, match=r"another clock; give its offset \(--force-log-offset-s"):
            recorded_force(reader, AnalysisParameters(), log)
        found, _ = recorded_force(reader, AnalysisParameters(), log.model_copy(update={"offset_s": -1234.5}))
    assert found is not None
    assert found.kind == "step_release"
    assert abs(found.value - 6.0) < 0.05
    assert found.release_time_s is not None
    assert abs(found.release_time_s - 0.3) < 0.003
