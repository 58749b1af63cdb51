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
