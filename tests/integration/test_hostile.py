"""The malformed-clip corpus of the formats work, sent through ``POST /v1/clips`` of a live service.

Each clip is refused with the status of its error class (413 over a cap, 415 not a clip format, 422
malformed) and a problem document whose detail is one line. Validation reads only the start of a clip,
so a clip whose damage lies further in (a corrupt frame in the middle) may be accepted: its job must then
fail with the same kind of problem. No clip may crash a worker: the same worker processes run a good job
afterwards, and nothing of a refused upload is left on disk.
"""

from __future__ import annotations

import time
import zipfile
from pathlib import Path
from typing import Any

import httpx
import pytest
import service_harness as h

from tests.unit.clipio.test_clipio_malformed import CORPUS
from workers.pipeline.errors import ClipTooLargeError, UnsupportedFormatError

pytestmark = [pytest.mark.integration, pytest.mark.slow]

PROBLEM = "application/problem+json"


def expected_status(error: type[Exception]) -> int:
    if issubclass(error, ClipTooLargeError):
        return 413
    if issubclass(error, UnsupportedFormatError):
        return 415
    return 422


def as_upload(path: Path) -> Path:
    """A file to upload: a bag folder (ROS 2) goes as a zip of the folder."""
    if path.is_file():
        return path
    archive = path.with_suffix(".zip")
    with zipfile.ZipFile(archive, "w") as zf:
        for item in sorted(path.rglob("*")):
            zf.write(item, f"{path.name}/{item.relative_to(path).as_posix()}")
    return archive


def worker_pids(service: h.LiveService) -> set[int]:
    """The Celery worker started by ``eigenscope serve``, its pool process and its stream worker (once all
    three are up)."""
    deadline = time.monotonic() + 60
    while True:
        pids = set()
        for child in h.children_of(service.procs[0].pid):
            cmdline = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ")
            if b"eigenscope worker" in cmdline:
                pids.add(child)
                pids.update(h.children_of(child))
        if len(pids) >= 3 or time.monotonic() > deadline:
            return pids
        time.sleep(0.1)


def test_malformed_corpus_through_the_api(
    embedded: h.LiveService, tmp_path: Path, truth_clip: tuple[Path, Any]
) -> None:
    before = worker_pids(embedded)
    assert len(before) >= 2, before  # the Celery worker and its pool process
    refused: list[str] = []
    failed_jobs: list[str] = []
    valid_alone: list[str] = []
    for i, (build, error, message) in enumerate(CORPUS):
        work = tmp_path / str(i)
        work.mkdir()
        built, kwargs = build(work)
        path = as_upload(built)
        # A separate depth file the API upload does not carry: the main file alone may be a valid clip.
        companions = "depth" in kwargs
        # Cases built for tighter read limits than the server's: refused, but maybe for another reason.
        loose = companions or "limits" in kwargs
        name = build.__name__
        with path.open("rb") as fh:
            response = embedded.client.post("/v1/clips", files={"file": (path.name, fh)})
        if response.status_code == 201:
            # Validation only reads the first frame; the damage must then surface in the job.
            job_id = embedded.client.post(
                "/v1/jobs", json={"clip_id": response.json()["id"], "parameters": {"fps": 30}}
            ).json()["id"]
            job = embedded.wait_job(job_id, timeout_s=60)
            if companions and job["status"] == "succeeded":
                valid_alone.append(name)
                continue
            assert job["status"] == "failed", (name, job)
            problem = job["error"]
            assert problem["status"] in (413, 415, 422), (name, problem)
            if not loose:
                assert problem["status"] == expected_status(error), (name, problem)
                assert message in problem["detail"], (name, problem)
            failed_jobs.append(name)
            continue
        assert response.headers["content-type"].startswith(PROBLEM), (name, response.text)
        problem = response.json()
        assert problem["status"] == response.status_code
        assert "\n" not in problem["detail"], (name, problem)
        if loose or built.is_dir():
            assert response.status_code in (413, 415, 422), (name, problem)
        else:
            assert response.status_code == expected_status(error), (name, problem)
            assert message in problem["detail"], (name, problem)
        refused.append(name)
    print(
        f"\nHOSTILE {len(CORPUS)} malformed clips: {len(refused)} refused at upload, "
        f"{len(failed_jobs)} accepted then failed as jobs ({', '.join(failed_jobs) or 'none'}), "
        f"{len(valid_alone)} valid without their depth companion ({', '.join(valid_alone) or 'none'})"
    )
    assert len(refused) + len(failed_jobs) + len(valid_alone) == len(CORPUS)
    assert len(valid_alone) <= 1
    assert len(refused) >= len(CORPUS) - 3
    # Nothing of the refused uploads stayed; no worker process died.
    assert list((embedded.data_dir / "tmp").glob("upload-*")) == []
    assert worker_pids(embedded) == before, "a worker process was replaced"
    clip_id = embedded.upload(truth_clip[0]).json()["id"]
    good = embedded.client.post("/v1/jobs", json={"clip_id": clip_id}).json()["id"]
    assert embedded.wait_job(good)["status"] == "succeeded"
    assert not Path("/tmp/eigenscope-evil.png").exists()


def test_hostile_requests(embedded: h.LiveService) -> None:
    client = embedded.client
    # Path traversal in artifact names and ids.
    for path in (
        "/v1/jobs/..%2F..%2Fetc/artifacts/passwd",
        "/v1/jobs/x/artifacts/..%2F..%2Feigenscope.db",
        "/v1/jobs/x/artifacts/.%2E",
        "/v1/clips/..%2Feigenscope.db",
    ):
        response = client.get(path)
        assert response.status_code == 404, (path, response.text)
        assert response.headers["content-type"].startswith(PROBLEM)
    # Oversized and odd headers, huge query values, wrong methods.
    assert client.get("/v1/jobs", params={"limit": 10**30}).status_code == 422
    assert client.get("/v1/jobs", params={"clip_id": "x" * 10_000}).status_code == 422
    body = {"clip_id": "a" * 100_000}
    assert client.post("/v1/jobs", json=body).status_code == 422
    big_key = {"Idempotency-Key": "k" * 1000}
    assert client.post("/v1/jobs", json={"clip_id": "x"}, headers=big_key).status_code == 422
    # A multipart body cut off in the middle: refused, nothing left behind.
    raw = b'--zz\r\nContent-Disposition: form-data; name="file"; filename="a.npz"\r\n\r\n' + b"\0" * 50_000
    cut = client.post("/v1/clips", content=raw, headers={"content-type": "multipart/form-data; boundary=zz"})
    assert cut.status_code == 422
    # A client that disappears mid-upload leaves nothing behind either, once the server has seen the
    # connection close (which it learns after the client has given up: a short wait, not an instant; the
    # deadline only ends the wait, generously for a loaded machine).
    with pytest.raises(httpx.HTTPError):
        _abort_upload(embedded.base_url)
    deadline = time.monotonic() + 30.0
    while list((embedded.data_dir / "tmp").glob("upload-*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list((embedded.data_dir / "tmp").glob("upload-*")) == []


def _abort_upload(base_url: str) -> None:
    def body() -> Any:
        yield b'--zz\r\nContent-Disposition: form-data; name="file"; filename="a.npz"\r\n\r\n'
        yield b"\0" * 100_000
        raise httpx.ReadError("client gave up")

    with httpx.Client(base_url=base_url, timeout=10) as c:
        c.post(
            "/v1/clips",
            content=body(),
            headers={"content-type": "multipart/form-data; boundary=zz", "content-length": "10000000"},
        )
