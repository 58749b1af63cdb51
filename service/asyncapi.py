"""The AsyncAPI 3 document of the live-stream WebSocket protocol, generated from the message models.

``eigenscope export-openapi`` writes it beside the OpenAPI spec (``openapi/asyncapi.json``); the app
serves it at ``/asyncapi.json``; a contract test keeps the committed file equal to this and the messages
the server sends valid against it.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel

from api_schemas.stream import (
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

FRAME_DESCRIPTION = (
    "A binary message: a 4-byte big-endian unsigned length L, then L bytes of UTF-8 JSON (the "
    "`FrameHeader` schema), then the image bytes: JPEG or PNG colour, or depth as a 16-bit PNG or raw "
    "little-endian uint16 (width x height x 2 bytes). Send a frame's colour message, then its depth "
    "message with the same `frame`. Keep at most `window` frame messages in flight (sent, minus those "
    "the latest `accepted` or `error` counts in `messages`, less the `messages` of `ready`)."
)


def _schemas() -> dict[str, Any]:
    """Every message schema, with the models they refer to, under ``components.schemas``."""
    from pydantic.json_schema import models_json_schema

    models = [(m, "serialization") for m in (*SERVER_MESSAGES.values(), EndMessage, FrameHeader)]
    _, top = models_json_schema(models, ref_template="#/components/schemas/{model}")  # type: ignore[arg-type]
    defs: dict[str, Any] = top.get("$defs", {})
    return dict(sorted(defs.items()))


def asyncapi_document(*, version: str) -> dict[str, Any]:
    """The AsyncAPI 3.0 document of ``/v1/streams/{stream_id}``."""
    messages: dict[str, Any] = {}
    for name, model in SERVER_MESSAGES.items():
        messages[name] = {
            "name": name,
            "title": model.model_config.get("title", name),
            "summary": (model.__doc__ or "").strip().splitlines()[0],
            "contentType": "application/json",
            "payload": {"$ref": f"#/components/schemas/{model.model_config.get('title', model.__name__)}"},
        }
    messages["end"] = {
        "name": "end",
        "title": "EndMessage",
        "summary": "No more frames: analyse and send the result.",
        "contentType": "application/json",
        "payload": {"$ref": "#/components/schemas/EndMessage"},
    }
    messages["frame"] = {
        "name": "frame",
        "title": "Frame",
        "summary": "One colour or depth image of a frame.",
        "description": FRAME_DESCRIPTION,
        "contentType": "application/octet-stream",
        "payload": {"type": "string", "format": "binary"},
        "headers": {"$ref": "#/components/schemas/FrameHeader"},
    }
    channel_messages = {name: {"$ref": f"#/components/messages/{name}"} for name in messages}
    return {
        "asyncapi": "3.0.0",
        "info": {
            "title": "Eigenscope live streams",
            "version": version,
            "description": (
                "Stream RGB-D frames while recording and get estimates as they improve, `converged` when the "
                "robot may stop, and the final `AnalysisResult` a fraction of a second after the last frame. "
                "Open a session with `POST /v1/streams` (OpenAPI), then connect to its `websocket_url`, with "
                "the same `Authorization: Bearer <API key>` header when the server has keys. To reconnect "
                "after a dropped connection add `?resume_token=<token>`: `ready` then says which frame to "
                "send next. The server closes after `result` or a fatal `error` (close code 4000 + the "
                "problem's status when the connection is refused)."
            ),
        },
        "defaultContentType": "application/json",
        "servers": {
            "eigenscope": {
                "host": "localhost:8000",
                "protocol": "ws",
                "description": "An `eigenscope serve` API (wss behind TLS).",
                "security": [{"$ref": "#/components/securitySchemes/ApiKey"}],
            }
        },
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
                "summary": "Client sends frames (binary) and finally `end` (text).",
                "messages": [
                    {"$ref": "#/channels/stream/messages/frame"},
                    {"$ref": "#/channels/stream/messages/end"},
                ],
            },
            "receiveMessages": {
                "action": "receive",
                "channel": {"$ref": "#/channels/stream"},
                "summary": "Client receives the server's JSON messages.",
                "messages": [{"$ref": f"#/channels/stream/messages/{name}"} for name in SERVER_MESSAGES],
            },
        },
        "components": {
            "messages": messages,
            "schemas": _schemas(),
            "securitySchemes": {
                "ApiKey": {
                    "type": "httpApiKey",
                    "name": "Authorization",
                    "in": "header",
                    "description": "`Bearer <API key>`, when the server is configured with keys.",
                }
            },
        },
    }
