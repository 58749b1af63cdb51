"""Generate a Python client from ``openapi/openapi.json`` with openapi-python-client and use it end to end
against a live server (as package ``eigenscope_generated``: ``eigenscope_client`` is the hand-written one):
an upload, a job whose excitation names no ``type_`` (the generator fills the discriminator in), a first
long-poll with the 202's ``ETag``, typed results, summaries in the list, artifacts by name."""

from __future__ import annotations

import importlib
import inspect
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import service_harness as h
from conftest import LIVE

pytestmark = [pytest.mark.slow, LIVE]

SPEC = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"


def generate_client(dest: Path) -> Any:
    exe = shutil.which("openapi-python-client") or str(
        Path(sys.executable).with_name("openapi-python-client")
    )
    package = dest / "eigenscope_generated"
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
        return importlib.import_module("eigenscope_generated")
    finally:
        sys.path.remove(str(dest))


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return generate_client(tmp_path_factory.mktemp("gen"))


def test_the_generated_signatures_are_the_contracts(generated: Any) -> None:
    """The server may run open: a plain Client is enough for every call; optional parameters take no
    None (a None would be sent); the excitation's discriminator is filled in."""
    from eigenscope_generated.api.clips import create_clip, get_clip
    from eigenscope_generated.api.jobs import create_job, get_job, get_job_artifact, get_job_result, list_jobs
    from eigenscope_generated.models import StepReleaseExcitation

    for fn in (
        create_clip.sync,
        get_clip.sync,
        create_job.sync_detailed,
        get_job.sync,
        get_job_artifact.sync,
    ):
        annotation = str(inspect.signature(fn).parameters["client"].annotation)
        assert "Client" in annotation.replace("AuthenticatedClient", ""), (fn.__module__, annotation)
    for fn, names in (
        (get_job.sync_detailed, ("wait", "if_none_match")),
        (list_jobs.sync_detailed, ("cursor", "clip_id", "status")),
        (create_job.sync_detailed, ("idempotency_key",)),
        (get_job_result.sync_detailed, ("if_none_match",)),
    ):
        for name in names:
            annotation = str(inspect.signature(fn).parameters[name].annotation)
            assert "None" not in annotation, (fn.__module__, name, annotation)
    assert StepReleaseExcitation(force_n=1.0).to_dict() == {"type": "step_release", "force_n": 1.0}


def test_generated_client_runs_a_job(
    generated: Any, live_service: h.LiveService, truth_clip: tuple[Path, dict[str, Any]]
) -> None:
    from eigenscope_generated import Client
    from eigenscope_generated.api.clips import create_clip, get_clip
    from eigenscope_generated.api.jobs import create_job, get_job, get_job_artifact, get_job_result, list_jobs
    from eigenscope_generated.models import (
        AnalysisResult,
        Clip,
        ClipFormat,
        ClipUpload,
        GetJobArtifactName,
        Job,
        JobCreate,
        JobList,
        JobStatus,
        ParametersUsed,
        Problem,
        QualityFlagCode,
        StepReleaseExcitation,
    )
    from eigenscope_generated.types import File

    client = Client(base_url=live_service.base_url, timeout=None)
    clip_path, truth = truth_clip
    with clip_path.open("rb") as fh:
        clip = create_clip.sync(
            client=client, body=ClipUpload(file=File(payload=fh, file_name=clip_path.name))
        )
    assert isinstance(clip, Clip), clip
    assert clip.format_ == ClipFormat.NPZ
    assert clip.has_depth
    missing = get_clip.sync(client=client, clip_id="does-not-exist")
    assert isinstance(missing, Problem)
    assert missing.status == 404

    body = JobCreate(clip_id=clip.id, excitation=StepReleaseExcitation(force_n=5.0))
    created = create_job.sync_detailed(client=client, body=body, idempotency_key="generated-client")
    assert created.status_code == 202
    assert isinstance(created.parsed, Job)
    job: Any = created.parsed
    etag = created.headers["ETag"]
    # A first poll with the 202's tag waits for the job to change; 304 while it has not.
    statuses = []
    deadline = time.monotonic() + 180
    while job.status in (JobStatus.QUEUED, JobStatus.RUNNING):
        assert time.monotonic() < deadline, live_service.logs()[-3000:]
        polled = get_job.sync_detailed(client=client, job_id=job.id, wait=10, if_none_match=etag)
        statuses.append(polled.status_code)
        if polled.status_code == 304:
            continue
        assert isinstance(polled.parsed, Job)
        job, etag = polled.parsed, polled.headers["ETag"]
    assert set(statuses) <= {200, 304}
    assert job.status == JobStatus.SUCCEEDED, job
    # The whole result parses into the generated models (a member it could not parse leaves a dict).
    assert isinstance(job.result, AnalysisResult), job.result
    freq = job.result.eigenfrequency_hz
    assert freq == pytest.approx(truth["objects"][0]["eigenfrequency_hz"], rel=0.02)
    assert all(isinstance(q.code, QualityFlagCode) for q in job.result.quality)

    result = get_job_result.sync(client=client, job_id=job.id)
    assert isinstance(result, AnalysisResult)
    assert isinstance(result.parameters, ParametersUsed)
    assert result.eigenfrequency_hz == freq
    listed = list_jobs.sync(client=client, clip_id=clip.id)
    assert isinstance(listed, JobList)
    assert [item.id for item in listed.items] == [job.id]
    assert listed.items[0].summary.eigenfrequency_hz == freq
    assert listed.items[0].result_url == f"/v1/jobs/{job.id}/result"

    mask = get_job_artifact.sync_detailed(client=client, job_id=job.id, name=GetJobArtifactName.MASK_PNG)
    assert mask.status_code == 200
    assert mask.content.startswith(b"\x89PNG")
    again = get_job_artifact.sync_detailed(
        client=client, job_id=job.id, name=GetJobArtifactName.MASK_PNG, if_none_match=mask.headers["ETag"]
    )
    assert again.status_code == 304

    bad = create_job.sync(client=client, body=JobCreate(clip_id="nope"))
    assert isinstance(bad, Problem)
    assert bad.status == 422
