"""Run one analysis from a clip file to a result directory.

This is the single code path shared by ``eigenscope analyze`` and the Celery task: open the clip, run
:func:`workers.pipeline.analysis.analyze`, convert its dataclasses into :class:`api_schemas.AnalysisResult`,
and write ``result.json``, ``mask.png`` and the other images into the output directory.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from api_schemas import AnalysisParameters, AnalysisResult, ImpulseExcitation, StepReleaseExcitation

#: ``progress(stage, fraction)`` with fraction in [0, 1] over the whole analysis.
ProgressCallback = Callable[[str, float], None]


def run_analysis(
    clip_path: str | Path,
    out_dir: str | Path,
    *,
    excitation: StepReleaseExcitation | ImpulseExcitation | None = None,
    parameters: AnalysisParameters | None = None,
    progress: ProgressCallback | None = None,
) -> AnalysisResult:
    """Analyse the clip at ``clip_path`` and write the result files into ``out_dir``.

    Raises
    ------
    workers.pipeline.errors.EigenscopeError
        Subclasses for bad clips (``ClipError``), bad parameters (``ParameterError``) and clips that
        cannot be analysed (``AnalysisError``); their messages are meant for the user.
    """
    raise NotImplementedError("being written: see issue 2")
