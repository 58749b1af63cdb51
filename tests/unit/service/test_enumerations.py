"""The API's enumerations hold every value the code can produce: a value missing from one would fail a
response's validation, and a generated client's enum parsing (openapi-python-client raises on one)."""

from __future__ import annotations

import ast
import sys
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def _calls(folder: Path, name: str) -> list[ast.Call]:
    found = []
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                func = node.func
                called = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
                if called == name:
                    found.append(node)
    return found


def _constant(node: ast.AST | None) -> str:
    assert isinstance(node, ast.Constant), ast.dump(node) if node else node
    assert isinstance(node.value, str)
    return node.value


def test_quality_codes_are_every_code_the_analysis_writes() -> None:
    from api_schemas.result import QualityCode

    calls = _calls(ROOT / "workers", "QualityNote")
    assert len(calls) > 15
    written = {
        _constant(c.args[0] if c.args else next(k.value for k in c.keywords if k.arg == "code"))
        for c in calls
    }
    assert written == set(typing.get_args(QualityCode))


def test_evidence_is_every_reason_a_peak_is_rejected_for() -> None:
    from api_schemas.result import Evidence

    calls = _calls(ROOT / "workers" / "pipeline", "RejectedPeak")
    given = {_constant(c.args[2]) for c in calls if len(c.args) > 2 and isinstance(c.args[2], ast.Constant)}
    source = (ROOT / "workers" / "pipeline" / "verdicts.py").read_text()
    artefacts = ast.literal_eval(source.split("ARTEFACT_EVIDENCE = ", 1)[1].split("\n", 1)[0])
    assert given | set(artefacts) | {"incoherent"} == set(typing.get_args(Evidence))


def test_stages_are_every_stage_reported_timed_or_recorded() -> None:
    from api_schemas import JobStage

    reported = {
        _constant(c.args[0])
        for folder in ("workers", "service", "backend")
        for name in ("progress", "report")
        for c in _calls(ROOT / folder, name)
        if c.args and isinstance(c.args[0], ast.Constant) and isinstance(c.args[0].value, str)
    }
    timed = {
        _constant(c.args[0])
        for c in _calls(ROOT / "workers", "lap")
        if c.args and isinstance(c.args[0], ast.Constant)
    }
    timed |= {"survey", "decode", "flow", "rendering"}  # stream_lap's, and workers.runner's own
    store = "".join(path.read_text() for path in sorted((ROOT / "backend" / "store").glob("*.py")))
    recorded = {
        s
        for s in ("queued", "starting", "requeued", "retrying", "done", "failed", "cancelled")
        if f'"{s}"' in store
    }
    assert reported | timed | recorded <= set(typing.get_args(JobStage)), (reported | timed | recorded) - set(
        typing.get_args(JobStage)
    )


def test_clip_formats_and_fps_sources_are_every_one_the_readers_give(tmp_path: Path) -> None:
    from api_schemas.clip import ClipFormat, ClipFpsSource
    from api_schemas.result import FpsSource

    sys.path.insert(0, str(ROOT / "tests" / "fuzz"))
    try:
        from seeds import write_seeds
    finally:
        sys.path.remove(str(ROOT / "tests" / "fuzz"))
    from workers.pipeline.clipio import open_clip

    formats, sources = set(), set()
    for path in write_seeds(tmp_path):
        with open_clip(path) as reader:
            info = reader.info.to_dict()
        formats.add(info["format"])
        if info.get("fps_source") is not None:
            sources.add(info["fps_source"])
    assert formats | {"stream"} == set(typing.get_args(ClipFormat)), formats
    assert sources <= set(typing.get_args(ClipFpsSource))
    assert set(typing.get_args(ClipFpsSource)) | {"unknown"} == set(typing.get_args(FpsSource))
