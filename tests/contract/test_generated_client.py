"""Generate a Python client from ``openapi/openapi.json`` with openapi-python-client and run a job with it
against a live server."""

from __future__ import annotations

import importlib
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import service_harness as h

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SPEC = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"


def generate_client(dest: Path) -> Any:
    exe = shutil.which("openapi-python-client") or str(
        Path(sys.executable).with_name("openapi-python-client")
    )
    # Not `eigenscope_client`: that is the real client package (client/), installed with the server.
    package = dest / "eigenscope_generated_client"
    out = subprocess.run(
        [exe, "generate", "--path", str(SPEC), "--output-path", str(package), "--meta", "none"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    sys.path.insert(0, str(dest))
    try:
        return importlib.import_module("eigenscope_generated_client")
    finally:
        sys.path.remove(str(dest))


def test_generated_client_runs_a_job(tmp_path: Path, truth_clip: tuple[Path, dict[str, Any]]) -> None:
    generate_client(tmp_path / "gen")
    from eigenscope_generated_client import Client
    from eigenscope_generated_client.api.clips import create_clip, get_clip
    from eigenscope_generated_client.api.jobs import create_job, get_job, get_job_artifact
    from eigenscope_generated_client.models import (
        Clip,
        ClipUpload,
        Job,
        JobCreate,
        JobStatus,
        Problem,
        StepReleaseExcitation,
    )
    from eigenscope_generated_client.types import File

    service = h.start_embedded(tmp_path / "svc")
    try:
        client = Client(base_url=service.base_url, timeout=None)
        clip_path, truth = truth_clip
        with clip_path.open("rb") as fh:
            clip = create_clip.sync(
                client=client, body=ClipUpload(file=File(payload=fh, file_name=clip_path.name))
            )
        assert isinstance(clip, Clip), clip
        assert clip.frames == 64
        assert clip.has_depth
        missing = get_clip.sync(client=client, clip_id="does-not-exist")
        assert isinstance(missing, Problem)
        assert missing.status == 404

        body = JobCreate(clip_id=clip.id, excitation=StepReleaseExcitation(type_="step_release", force_n=5.0))
        created = create_job.sync_detailed(client=client, body=body, idempotency_key="client-test")
        assert created.status_code == 202
        assert isinstance(created.parsed, Job)
        job: Any = created.parsed
        deadline = time.monotonic() + 120
        while job.status in (JobStatus.QUEUED, JobStatus.RUNNING):
            assert time.monotonic() < deadline, service.logs()
            time.sleep(0.05)
            job = get_job.sync(client=client, job_id=job.id)
        assert job.status == JobStatus.SUCCEEDED, job
        freq = job.result.eigenfrequency_hz
        assert freq == pytest.approx(truth["objects"][0]["eigenfrequency_hz"], rel=0.02)

        name = job.result.artifacts.mask.rsplit("/", 1)[-1]
        artifact = get_job_artifact.sync_detailed(client=client, job_id=job.id, name=name)
        assert artifact.status_code == 200
        assert artifact.content.startswith(b"\x89PNG")

        bad = create_job.sync(client=client, body=JobCreate(clip_id="nope"))
        assert isinstance(bad, Problem)
        assert bad.status == 422
    finally:
        service.stop()
