"""A live-stream client written from the published documents alone: it imports nothing of Eigenscope.

``python asyncapi_client.py BASE_URL FRAMES_DIR`` fetches ``/asyncapi.json`` and ``/openapi.json`` from the
server and takes from them everything it needs: where the WebSocket is (the server and the channel's
address), how to authenticate (the security scheme), how a frame message is laid out (the payload's
``x-framing``: the length prefix's size and byte order, the header's schema, the image), which header
members to send (``FrameHeader``), how to count messages in flight (the flow-control rule: ``window`` of
``ready``, ``acked`` of the acknowledging messages), and what every server message must look like (it
validates each against its schema). ``FRAMES_DIR`` holds ``stream.json`` (the session's request body and
the frame size) and, per frame ``NNNNNN``, ``NNNNNN.png`` (colour) and ``NNNNNN.raw`` (uint16 depth).

It prints one JSON object: what it sent and received, and the result.
"""

from __future__ import annotations

import json
import struct
import sys
from pathlib import Path
from typing import Any

import httpx
import jsonschema_rs
from websockets.sync.client import connect

PROJECT = ("api_schemas", "backend", "service", "workers", "eigenscope", "eigenscope_client")


def validators(doc: dict[str, Any]) -> dict[str, Any]:
    """A validator of each message's payload, by the value of its ``type`` member."""
    out = {}
    for message in doc["components"]["messages"].values():
        payload = message["payload"]
        if "$ref" not in payload:
            continue
        schema = {"$ref": payload["$ref"], "components": doc["components"]}
        target = doc["components"]["schemas"][payload["$ref"].rsplit("/", 1)[1]]
        kind = target["properties"]["type"]["const"]
        out[kind] = jsonschema_rs.validator_for(schema)
    return out


class Framing:
    """Builds binary frame messages as the document's ``x-framing`` lays them out."""

    def __init__(self, doc: dict[str, Any]) -> None:
        frame = doc["components"]["messages"]["frame"]
        parts = {p["name"]: p for p in frame["payload"]["x-framing"]["parts"]}
        length = parts["header_length"]
        assert (length["type"], length["bytes"]) == ("uint32", 4), length
        self.prefix = ">I" if length["byteOrder"] == "big-endian" else "<I"
        header_ref = parts["header"]["schema"]["$ref"].rsplit("/", 1)[1]
        self.header_schema = doc["components"]["schemas"][header_ref]
        self.charset = parts["header"]["charset"]

    def message(self, header: dict[str, Any], image: bytes) -> bytes:
        unknown = set(header) - set(self.header_schema["properties"])
        missing = set(self.header_schema["required"]) - set(header)
        assert not unknown, unknown
        assert not missing, missing
        head = json.dumps(header).encode(self.charset)
        return struct.pack(self.prefix, len(head)) + head + image


def main(base_url: str, frames_dir: Path) -> dict[str, Any]:
    asyncapi = httpx.get(f"{base_url}/asyncapi.json").json()
    openapi = httpx.get(f"{base_url}/openapi.json").json()
    assert asyncapi["components"]["securitySchemes"]["ApiKey"]["scheme"] == "bearer"
    assert openapi["components"]["securitySchemes"]["ApiKey"]["scheme"] == "bearer"
    server = next(iter(asyncapi["servers"].values()))
    channel = asyncapi["channels"]["stream"]
    check = validators(asyncapi)
    framing = Framing(asyncapi)
    meta = json.loads((frames_dir / "stream.json").read_text())

    assert "/v1/streams" in openapi["paths"]
    created = httpx.post(f"{base_url}/v1/streams", json=meta["request"])
    assert created.status_code == 201, created.text
    stream = created.json()
    address = channel["address"].replace("{stream_id}", stream["id"])
    url = f"{server['protocol']}://{server['host']}{address}"
    assert url == stream["websocket_url"], (url, stream["websocket_url"])

    seen: list[dict[str, Any]] = []
    state = {"window": 0, "acked": 0, "sent": 0, "max_in_flight": 0, "stalls": 0}

    def take(text: str | bytes) -> dict[str, Any]:
        message: dict[str, Any] = json.loads(text)
        errors = [str(e) for e in check[message["type"]].iter_errors(message)]
        assert not errors, (message["type"], errors)
        seen.append(message)
        if message["type"] == "ready":
            state["window"] = message["window"]
        if message.get("acked") is not None:
            state["acked"] = max(state["acked"], message["acked"])
        assert not (message["type"] == "error" and message["fatal"]), message
        return message

    names = sorted(p.stem for p in frames_dir.glob("*.png"))
    with connect(url, max_size=None, compression=None) as ws:
        while not any(m["type"] == "ready" for m in seen):
            take(ws.recv(timeout=60))
        for i, name in enumerate(names):
            t = i / meta["fps"]
            color = {"frame": i, "kind": "color", "timestamp_s": t, "encoding": "png"}
            depth = {
                "frame": i,
                "kind": "depth",
                "timestamp_s": t,
                "encoding": "raw",
                "width": meta["width"],
                "height": meta["height"],
            }
            for header, image in (
                (color, (frames_dir / f"{name}.png").read_bytes()),
                (depth, (frames_dir / f"{name}.raw").read_bytes()),
            ):
                # The rule: send only while fewer than `window` frame messages are in flight.
                if state["sent"] - state["acked"] >= state["window"]:
                    state["stalls"] += 1
                while state["sent"] - state["acked"] >= state["window"]:
                    take(ws.recv(timeout=60))
                ws.send(framing.message(header, image))
                state["sent"] += 1
                state["max_in_flight"] = max(state["max_in_flight"], state["sent"] - state["acked"])
        ws.send(json.dumps({"type": "end"}))
        while not any(m["type"] == "result" for m in seen):
            take(ws.recv(timeout=120))
    loaded = sorted({m.split(".")[0] for m in sys.modules} & set(PROJECT))
    assert not loaded, f"the client imported {loaded}"
    result = next(m for m in seen if m["type"] == "result")["result"]
    return {
        "sent": state["sent"],
        "acked": state["acked"],
        "window": state["window"],
        "max_in_flight": state["max_in_flight"],
        "stalls": state["stalls"],
        "kinds": sorted({m["type"] for m in seen}),
        "validated": len(seen),
        "accepted": sum(m["type"] == "accepted" for m in seen),
        "dropped": sum(m["type"] == "backpressure" and m["action"] == "dropped" for m in seen),
        "eigenfrequency_hz": result["eigenfrequency_hz"],
        "job_id": stream["job_id"],
    }


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], Path(sys.argv[2]))))
