"""The AsyncAPI 3 document of the live-stream WebSocket protocol, generated from the message models.

``eigenscope export-openapi`` writes it beside the OpenAPI spec (``openapi/asyncapi.json``); the app
serves it at ``/asyncapi.json`` with the server's own address; a contract test keeps the committed file
equal to this, the messages the server sends valid against it, and streams a clip with a client written
from the document alone (``tests/contract/asyncapi_client.py``).

It shares with the OpenAPI document the schemas' names (each model's title: ``LiveEstimate``,
``RejectedPeak``, ``AnalysisResult`` ...), the server (the host serving both) and the security scheme
(``ApiKey``: HTTP bearer).
"""

from __future__ import annotations

import re
from typing import Any

from pydantic import BaseModel

from api_schemas.stream import (
    FLOW_CONTROL,
    AcceptedMessage,
    BackpressureMessage,
    ConvergedMessage,
    EndMessage,
    ErrorMessage,
    EstimateMessage,
    FrameHeader,
    ReadyMessage,
    ResultMessage,
)
from service.openapi import rename_to_titles

#: Server -> client messages, by name.
SERVER_MESSAGES: dict[str, type[BaseModel]] = {
    "ready": ReadyMessage,
    "accepted": AcceptedMessage,
    "backpressure": BackpressureMessage,
    "estimate": EstimateMessage,
    "converged": ConvergedMessage,
    "result": ResultMessage,
    "error": ErrorMessage,
}

#: How a binary frame message is laid out, stated as data (``x-framing`` of its payload schema).
FRAMING: dict[str, Any] = {
    "parts": [
        {
            "name": "header_length",
            "bytes": 4,
            "type": "uint32",
            "byteOrder": "big-endian",
            "description": "L, the length in bytes of the header that follows.",
        },
        {
            "name": "header",
            "bytes": "header_length",
            "contentType": "application/json",
            "charset": "utf-8",
            "schema": {"$ref": "#/components/schemas/FrameHeader"},
        },
        {
            "name": "image",
            "bytes": "rest",
            "contentType": {"jpeg": "image/jpeg", "png": "image/png", "raw": "application/octet-stream"},
            "description": "The image, as the header's `encoding` says: colour as JPEG or PNG; depth as a "
            "16-bit PNG or `raw` little-endian uint16, width x height x 2 bytes.",
        },
    ]
}

FRAME_DESCRIPTION = (
    "A binary WebSocket message (uncompressed: the server negotiates no permessage-deflate): a 4-byte "
    "big-endian unsigned length L, then L bytes of UTF-8 JSON (the `FrameHeader` schema), then the image "
    "bytes: JPEG or PNG colour, or depth as a 16-bit PNG or raw little-endian uint16 (width x height x 2 "
    "bytes). Send a frame's colour message, then its depth message with the same `frame`. " + FLOW_CONTROL
)

#: The payload of a frame message: its three parts in order (``x-framing`` says how many bytes each is).
FRAME_PAYLOAD: dict[str, Any] = {
    "title": "FrameMessage",
    "description": "The bytes of a frame message, as three consecutive parts (see `x-framing`).",
    "type": "string",
    "format": "binary",
    "contentMediaType": "application/octet-stream",
    "x-framing": FRAMING,
}

SECURITY_SCHEME: dict[str, Any] = {
    "type": "http",
    "scheme": "bearer",
    "description": "`Authorization: Bearer <API key>`, when the server is configured with keys (the same "
    "scheme, `ApiKey`, as the OpenAPI document's).",
}


def _summary(model: type[BaseModel]) -> str:
    """The first sentence of the model's docstring, whole (it may run over several lines)."""
    text = " ".join((model.__doc__ or "").split())
    match = re.match(r"(.+?[.!?])(\s|$)", text)
    return match.group(1) if match else text


def _description(model: type[BaseModel]) -> str:
    return " ".join((model.__doc__ or "").split())


def _schemas() -> dict[str, Any]:
    """Every message schema, with the models they refer to, under ``components.schemas``."""
    from pydantic.json_schema import models_json_schema

    models = [(m, "serialization") for m in (*SERVER_MESSAGES.values(), EndMessage, FrameHeader)]
    _, top = models_json_schema(models, ref_template="#/components/schemas/{model}")  # type: ignore[arg-type]
    defs: dict[str, Any] = top.get("$defs", {})
    return dict(sorted(defs.items()))


def _message(name: str, model: type[BaseModel]) -> dict[str, Any]:
    return {
        "name": name,
        "title": str(model.model_config.get("title", name)),
        "summary": _summary(model),
        "description": _description(model),
        "contentType": "application/json",
        "payload": {"$ref": f"#/components/schemas/{model.__name__}"},
    }


def _messages() -> dict[str, Any]:
    messages = {name: _message(name, model) for name, model in SERVER_MESSAGES.items()}
    messages["end"] = _message("end", EndMessage)
    messages["frame"] = {
        "name": "frame",
        "title": "Frame",
        "summary": "One colour or depth image of a frame, after its JSON header.",
        "description": FRAME_DESCRIPTION,
        "contentType": "application/octet-stream",
        "payload": FRAME_PAYLOAD,
    }
    return messages


INFO_DESCRIPTION = (
    "Stream RGB-D frames while recording and get estimates as they improve, `converged` when the robot may "
    "stop, and the final `AnalysisResult` a fraction of a second after the last frame. Open a session "
    "with `POST /v1/streams` (OpenAPI), then connect to its `websocket_url`, with the same "
    "`Authorization: Bearer <API key>` header when the server has keys. To reconnect after a dropped "
    "connection add `?resume_token=<token>`: `ready` then says which frame to send next. The server closes "
    "after `result` or a fatal `error` (close code 4000 + the problem's status when the connection is "
    "refused). " + FLOW_CONTROL
)


def asyncapi_document(*, version: str, host: str | None = None, secure: bool = False) -> dict[str, Any]:
    """The AsyncAPI 3.0 document of ``/v1/streams/{stream_id}``; ``host`` (``host:port``) names the server
    serving it (else the document keeps a ``{host}`` variable)."""
    messages = _messages()
    channel_messages = {name: {"$ref": f"#/components/messages/{name}"} for name in messages}
    server: dict[str, Any] = {
        "host": host or "{host}",
        "protocol": "wss" if secure else "ws",
        "description": "The Eigenscope API serving this document and the OpenAPI one (`/openapi.json`, "
        "server `/`): the WebSocket is on the same host and port as the HTTP API (wss behind TLS).",
        "security": [{"$ref": "#/components/securitySchemes/ApiKey"}],
    }
    if host is None:
        server["variables"] = {
            "host": {"default": "localhost:8000", "description": "The API's host and port."}
        }
    doc = {
        "asyncapi": "3.0.0",
        "info": {"title": "Eigenscope live streams", "version": version, "description": INFO_DESCRIPTION},
        "defaultContentType": "application/json",
        "servers": {"eigenscope": server},
        "channels": {
            "stream": {
                "address": "/v1/streams/{stream_id}",
                "parameters": {"stream_id": {"description": "The `id` returned by `POST /v1/streams`."}},
                "messages": channel_messages,
                "bindings": {
                    "ws": {
                        "query": {
                            "type": "object",
                            "properties": {
                                "resume_token": {
                                    "type": "string",
                                    "description": "The session's resume token, to reconnect.",
                                }
                            },
                        }
                    }
                },
            }
        },
        "operations": {
            "sendFrame": {
                "action": "send",
                "channel": {"$ref": "#/channels/stream"},
                "summary": "The client sends frames (binary messages) and finally `end` (text).",
                "messages": [
                    {"$ref": "#/channels/stream/messages/frame"},
                    {"$ref": "#/channels/stream/messages/end"},
                ],
            },
            "receiveMessages": {
                "action": "receive",
                "channel": {"$ref": "#/channels/stream"},
                "summary": "The client receives the server's JSON messages (text).",
                "messages": [{"$ref": f"#/channels/stream/messages/{name}"} for name in SERVER_MESSAGES],
            },
        },
        "components": {
            "messages": messages,
            "schemas": _schemas(),
            "securitySchemes": {"ApiKey": SECURITY_SCHEME},
        },
    }
    return rename_to_titles(doc)
