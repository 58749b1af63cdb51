"""The hand-written client (``client/``) stays in step with ``openapi/openapi.json``: every operation has a
method, every model has exactly its schema's members, the request types send what the schemas take."""

from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path
from typing import Any

import eigenscope_client as ec
import pytest

from tests.unit.service.helpers import RESULT

SPEC = json.loads((Path(__file__).resolve().parents[2] / "openapi" / "openapi.json").read_text())
SCHEMAS: dict[str, Any] = SPEC["components"]["schemas"]

MODELS = [
    ec.Clip,
    ec.Job,
    ec.AnalysisResult,
    ec.ObjectResult,
    ec.Spectrum,
    ec.QualityFlag,
    ec.Ringdown,
    ec.Mode,
    ec.ModeHarmonic,
    ec.Callback,
    ec.CameraIntrinsics,
    ec.Problem,
    ec.Stream,
    ec.JobSummary,
    ec.ResultSummary,
    ec.Detection,
    ec.ForceLogSummary,
]
#: Client-side members that are not the resource's: its ETag (a header) and the document as received.
CLIENT_ONLY = {"etag", "raw"}


def test_every_operation_has_a_method() -> None:
    operations = {op["operationId"] for item in SPEC["paths"].values() for op in item.values()}
    assert set(ec.OPERATIONS) == operations


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.__name__)
def test_models_have_their_schemas_members(model: Any) -> None:
    schema = SCHEMAS[model.schema]
    fields = {f.name for f in dataclasses.fields(model)} - CLIENT_ONLY
    assert fields == set(schema["properties"]), model.schema
    required = {
        f.name
        for f in dataclasses.fields(model)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    }
    # A member the server always sends is required by the client; an optional one never is.
    assert required <= set(schema.get("required", [])), model.schema


def test_request_types_send_what_the_schemas_take() -> None:
    params = set(typing.get_type_hints(ec.AnalysisParameters))
    assert params == set(SCHEMAS["AnalysisParameters"]["properties"])
    for cls, name in ((ec.StepRelease, "StepReleaseExcitation"), (ec.Impulse, "ImpulseExcitation")):
        fields = {f.name for f in dataclasses.fields(cls)} | {"type"}
        assert fields == set(SCHEMAS[name]["properties"]), name
    body = ec.StepRelease(force_n=2.0, box_px=(1, 2, 3, 4)).to_dict()
    assert body == {"type": "step_release", "force_n": 2.0, "box_px": [1, 2, 3, 4]}
    assert set(SCHEMAS["JobCreate"]["properties"]) == {
        "clip_id",
        "excitation",
        "parameters",
        "callback_url",
        "force_log",
    }
    # The force log: every member of the schema, and what the client sends validates as the server's model.
    from api_schemas import ForceLog

    assert {f.name for f in dataclasses.fields(ec.ForceLog)} == set(SCHEMAS[ec.ForceLog.schema]["properties"])
    log = ec.ForceLog(time_s=[i / 500 for i in range(8)], force_n=[0.0] * 8, offset_s=-1.5, frame_id="ft")
    assert ForceLog.model_validate(log.to_dict()).model_dump() == {
        **log.to_dict(),
        "fx": None,
        "fy": None,
        "fz": None,
    }


def test_a_server_document_reads_back_whole() -> None:
    """A job as the server serves it (from the API models' own example data) becomes typed objects."""
    from api_schemas import JobModel

    doc = JobModel.model_validate(
        {
            "id": "j",
            "clip_id": "c",
            "status": "succeeded",
            "progress": 1.0,
            "parameters": {"method": "default"},
            "created_at": "2026-01-01T00:00:00Z",
            "finished_at": "2026-01-01T00:00:02Z",
            "callback": {"url": "https://robot.lab/x", "status": "delivered", "attempts": 1},
            "result": {
                **RESULT,
                "objects": [
                    {
                        "id": 1,
                        "eigenfrequency_hz": 4.0,
                        "angular_frequency_rad_s": 25.1,
                        "pixel_count": 100,
                        "bbox_px": [1, 2, 3, 4],
                        "mass_kg": 0.5,
                        "ringdown": {"times_s": [0.1], "amplitude_px": [2.0], "frequency_hz": [4.0]},
                    }
                ],
                "quality": [{"code": "low_snr", "message": "m"}],
            },
        }
    ).model_dump(mode="json")
    job = ec.Job.from_dict(doc)
    assert job.result is not None
    assert job.result.main is not None
    assert job.result.main.mass_kg == 0.5
    assert job.result.main.ringdown is not None
    assert job.result.quality[0].code == "low_snr"
    assert job.result.artifacts["mask"] == "mask.png"
    assert job.callback == ec.Callback(url="https://robot.lab/x", status="delivered", attempts=1)
    assert job.finished_at is not None
    assert job.finished_at.tzinfo is not None
    assert job.done
    assert job.succeeded
