"""What the service unit tests share: a queue that records publications, an app client, a job run by hand."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from backend.settings import Settings
from service.app import create_app

#: The result a job run by hand records (:func:`finish`).
RESULT: dict[str, Any] = {
    "eigenfrequency_hz": 4.0,
    "objects": [],
    "spectrum": {"frequencies_hz": [], "power": []},
    "artifacts": {"mask": "mask.png"},
    "method": "default",
    "parameters": {},
    "fps": 25.0,
    "fps_source": "bundle",
    "frames_used": [0, 16],
    "frame_size_px": [48, 32],
    "version": "test",
}


class RecordingQueue:
    """Stands in for the broker: remembers what was published; ``fail`` makes it refuse."""

    def __init__(self) -> None:
        self.published: list[str] = []
        self.fail = False

    def publish(self, job_id: str) -> None:
        if self.fail:
            raise ConnectionError("broker down")
        self.published.append(job_id)

    def ping(self) -> None:
        if self.fail:
            raise ConnectionError("broker down")

    def held_job_ids(self) -> set[str] | None:
        """What a broker that cannot list its messages answers (the embedded one)."""
        return None

    def close(self) -> None:
        pass


def make_client(settings: Settings, queue: Any = None) -> TestClient:
    """A TestClient of the app for ``settings``, publishing to ``queue`` (a new one when None)."""
    app = create_app(settings)
    app.state.ctx.queue = queue if queue is not None else RecordingQueue()
    return TestClient(app)


def upload(
    client: TestClient, path: Path, headers: dict[str, str] | None = None, name: str | None = None
) -> Any:
    """POST ``path`` to /v1/clips; returns the response."""
    with path.open("rb") as fh:
        return client.post("/v1/clips", files={"file": (name or path.name, fh)}, headers=headers or {})


def finish(client: TestClient, job_id: str, output: bytes = b"\x89PNG\r\n") -> None:
    """Run a job by hand: claim it, write an artifact and ``result.json`` (as a worker does), complete it."""
    ctx = client.app.state.ctx  # type: ignore[attr-defined]
    assert ctx.store.claim_job(job_id, "me/1/x").job is not None
    out = ctx.storage.job_dir(job_id)
    out.mkdir(parents=True)
    (out / "mask.png").write_bytes(output)
    (out / "result.json").write_text(json.dumps(RESULT))
    assert ctx.store.complete_job(job_id, "me/1/x", RESULT, output_bytes=len(output))
