"""``openapi/asyncapi.json`` is the live-stream protocol the server speaks.

The document is generated from the message models (``api_schemas.stream``); the server's messages are
built to those models and the integration tests parse every message a real server sends with them
(``tests/integration/stream_helpers.py``), so a message the document does not describe fails a test.
"""

from __future__ import annotations

import json
from pathlib import Path

from eigenscope.commands.export_openapi import render_asyncapi
from service.app import create_app
from service.asyncapi import SERVER_MESSAGES
from service.settings import Settings

DOC_PATH = Path(__file__).resolve().parents[2] / "openapi" / "asyncapi.json"


def test_committed_document_equals_the_generated_one() -> None:
    assert DOC_PATH.read_text() == render_asyncapi(), "run `eigenscope export-openapi` and commit the result"


def test_document_describes_the_servers_channel_and_messages(tmp_path: Path) -> None:
    doc = json.loads(DOC_PATH.read_text())
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
        schema = doc["components"]["schemas"][model.__name__]
        assert schema["properties"]["type"]["const"] == name
        assert model.__name__ in kinds
    received = next(op["messages"] for op in doc["operations"].values() if op["action"] == "receive")
    assert {m["$ref"].rsplit("/", 1)[1] for m in received} == set(SERVER_MESSAGES)
