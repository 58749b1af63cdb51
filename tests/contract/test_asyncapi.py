"""``openapi/asyncapi.json`` is the live-stream protocol the server speaks.

The document is generated from the message models (``api_schemas.stream``); the server's messages are
built to those models and the integration tests parse every message a real server sends with them
(``tests/integration/stream_helpers.py``), so a message the document does not describe fails a test. A
client written from the document alone (``asyncapi_client.py``, importing nothing of the project)
streams a clip to a live server here, validating every message against the document.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import service_harness as h
from conftest import LIVE

from api_schemas.stream import FLOW_CONTROL
from backend.settings import Settings
from eigenscope.commands.export_openapi import render_asyncapi
from service.app import create_app
from service.asyncapi import SERVER_MESSAGES

ROOT = Path(__file__).resolve().parents[2]
DOC_PATH = ROOT / "openapi" / "asyncapi.json"
OPENAPI = json.loads((ROOT / "openapi" / "openapi.json").read_text())
CLIENT = Path(__file__).with_name("asyncapi_client.py")


@pytest.fixture(scope="module")
def doc() -> dict[str, Any]:
    document: dict[str, Any] = json.loads(DOC_PATH.read_text())
    return document


def test_committed_document_equals_the_generated_one() -> None:
    assert DOC_PATH.read_text() == render_asyncapi(), "run `eigenscope export-openapi` and commit the result"


def test_document_describes_the_servers_channel_and_messages(tmp_path: Path, doc: dict[str, Any]) -> None:
    assert doc["asyncapi"].startswith("3.")
    channel = doc["channels"]["stream"]
    from fastapi.routing import APIWebSocketRoute

    from service.routes import streams

    create_app(Settings(data_dir=tmp_path))  # the app includes this router
    socket_paths = {r.path for r in streams.router.routes if isinstance(r, APIWebSocketRoute)}
    assert socket_paths == {channel["address"]}
    kinds = {
        m["payload"]["$ref"].rsplit("/", 1)[1]
        for m in doc["components"]["messages"].values()
        if "$ref" in m["payload"]
    }
    for name, model in SERVER_MESSAGES.items():
        title = str(model.model_config["title"])
        schema = doc["components"]["schemas"][title]
        assert schema["properties"]["type"]["const"] == name
        assert title in kinds
    received = next(op["messages"] for op in doc["operations"].values() if op["action"] == "receive")
    assert {m["$ref"].rsplit("/", 1)[1] for m in received} == set(SERVER_MESSAGES)


def test_summaries_are_whole_sentences(doc: dict[str, Any]) -> None:
    """Each summary is a whole sentence, the first of the message's description (which says all of it)."""
    for name, message in doc["components"]["messages"].items():
        summary = message["summary"]
        assert re.fullmatch(r"[A-Z].*[.!?]", summary), (name, summary)
        assert message["description"].startswith(summary.rstrip(".")) or name == "frame", name
        assert summary.count("(") == summary.count(")"), (name, summary)
    backpressure = doc["components"]["messages"]["backpressure"]["description"]
    assert "`dropped`" in backpressure
    assert "refused" in backpressure


def test_the_frame_header_is_part_of_the_payload_and_the_framing_is_stated(doc: dict[str, Any]) -> None:
    frame = doc["components"]["messages"]["frame"]
    assert "headers" not in frame, "AsyncAPI reserves `headers` for protocol headers"
    payload = frame["payload"]
    parts = payload["x-framing"]["parts"]
    assert [p["name"] for p in parts] == ["header_length", "header", "image"]
    assert parts[0] == {
        "name": "header_length",
        "bytes": 4,
        "type": "uint32",
        "byteOrder": "big-endian",
        "description": parts[0]["description"],
    }
    assert parts[1]["schema"] == {"$ref": "#/components/schemas/FrameHeader"}
    assert parts[1]["contentType"] == "application/json"
    assert set(parts[2]["contentType"]) == set(
        doc["components"]["schemas"]["FrameHeader"]["properties"]["encoding"]["enum"]
    )


def test_one_flow_control_rule_in_the_document(doc: dict[str, Any]) -> None:
    assert FLOW_CONTROL in doc["info"]["description"]
    assert FLOW_CONTROL in doc["components"]["messages"]["frame"]["description"]
    schemas = doc["components"]["schemas"]
    for name in ("AcceptedMessage", "BackpressureMessage"):
        assert "acked" in schemas[name]["required"], name
    assert "acked" in schemas["ErrorMessage"]["properties"]
    assert "window" in schemas["ReadyMessage"]["required"]


def test_shares_names_server_and_auth_with_the_openapi_document(doc: dict[str, Any], tmp_path: Path) -> None:
    messages = {str(m.model_config["title"]) for m in SERVER_MESSAGES.values()} | {
        "EndMessage",
        "FrameHeader",
    }
    models = set(doc["components"]["schemas"]) - messages
    assert models <= set(OPENAPI["components"]["schemas"]), models - set(OPENAPI["components"]["schemas"])
    assert {"LiveEstimate", "RejectedPeak", "AnalysisResult"} <= models
    assert not [n for n in doc["components"]["schemas"] if n.endswith("Model")]
    scheme = doc["components"]["securitySchemes"]["ApiKey"]
    assert (scheme["type"], scheme["scheme"]) == ("http", "bearer")
    assert {k: OPENAPI["components"]["securitySchemes"]["ApiKey"][k] for k in ("type", "scheme")} == {
        "type": "http",
        "scheme": "bearer",
    }
    server = doc["servers"]["eigenscope"]
    assert server["host"] == "{host}"
    assert "localhost:8000" not in json.dumps({k: v for k, v in server.items() if k != "variables"})
    # Served, the document names the server it comes from (as the OpenAPI document's `/` does).
    from fastapi.testclient import TestClient

    with TestClient(create_app(Settings(data_dir=tmp_path)), base_url="https://robots.lab:8443") as client:
        served = client.get("/asyncapi.json").json()["servers"]["eigenscope"]
    assert (served["host"], served["protocol"]) == ("robots.lab:8443", "wss")
    assert "variables" not in served


@LIVE
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_client_written_from_the_document_alone_streams_a_clip(
    live_service: h.LiveService, tmp_path: Path
) -> None:
    from stream_helpers import scene_frames

    scene = scene_frames(frames=60)
    fx, fy, cx, cy = scene.intrinsics
    request = {
        "excitation": {"type": "step_release", "force_n": 6.0},
        "parameters": {"fps": scene.fps, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "depth_scale": 0.001},
        "width": scene.width,
        "height": scene.height,
    }
    meta = {"request": request, "fps": scene.fps, "width": scene.width, "height": scene.height}
    (tmp_path / "stream.json").write_text(json.dumps(meta))
    for i, f in enumerate(scene.frames):
        (tmp_path / f"{i:06d}.png").write_bytes(f.color_png)
        (tmp_path / f"{i:06d}.raw").write_bytes(f.depth_raw)
    run = subprocess.run(
        [sys.executable, "-I", str(CLIENT), live_service.base_url, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:] + live_service.logs()[-3000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["sent"] == 2 * len(scene.frames)
    assert report["acked"] == report["sent"]
    assert report["dropped"] == 0, "a client that keeps the rule is never dropped"
    assert report["max_in_flight"] <= report["window"]
    assert report["accepted"] == len(scene.frames)
    assert {"ready", "accepted", "result"} <= set(report["kinds"])
    assert report["eigenfrequency_hz"] == pytest.approx(scene.truth["eigenfrequency_hz"], rel=0.02)
