"""The Python client (``client/``, ``eigenscope_client``) against a live ``eigenscope serve`` (real HTTP, real
worker): every operation, errors as exceptions, Retry-After, long-polls, progress, downloads, the async
client, and webhooks signed and retried to a real receiver."""

from __future__ import annotations

import asyncio
import base64
import hashlib
import hmac
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import service_harness as h
from eigenscope_client import (
    AsyncClient,
    AuthenticationError,
    Client,
    ConflictError,
    Impulse,
    InvalidRequestError,
    Job,
    JobFailedError,
    NotFoundError,
    RateLimitError,
    StepRelease,
    UnsupportedMediaTypeError,
)

from tests.webhook_receiver import Receiver

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(300)]

KEY = "client-test-key-0123456789"
SECRET = "webhook-secret-0123456789"


@pytest.fixture(scope="module")
def receiver() -> Iterator[Receiver]:
    r = Receiver.failing_first()
    yield r
    r.close()


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory, receiver: Receiver) -> Iterator[h.LiveService]:
    svc = h.start_embedded(
        tmp_path_factory.mktemp("client"),
        api_keys=KEY,
        max_upload_mb="16",
        quota_retry_after_s="1",
        max_active_jobs_per_key="3",
        callback_hosts=f"127.0.0.1:{receiver.port}",
        callback_secret=SECRET,
        callback_retry_base_s="0.2",
    )
    yield svc
    svc.stop()


@pytest.fixture
def client(service: h.LiveService) -> Iterator[Client]:
    with Client(service.base_url, api_key=KEY, timeout=30) as c:
        yield c


def test_a_robot_measures_a_clip(
    client: Client, truth_clip: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    path, truth = truth_clip
    assert client.health()["status"] == "ok"
    assert client.ready()["status"] == "ready"
    sent: list[tuple[int, int]] = []
    clip = client.upload_clip(path, progress=lambda done, total: sent.append((done, total)))
    assert (clip.format, clip.frames, clip.width, clip.height, clip.has_depth) == ("npz", 64, 160, 120, True)
    assert clip.intrinsics is not None
    assert sent[-1][0] == sent[-1][1] > path.stat().st_size  # the whole body, multipart framing included
    assert len(sent) >= 3
    assert [a for a, _ in sent] == sorted(a for a, _ in sent)
    assert client.get_clip(clip.id) == clip
    assert clip.id in [c.id for c in client.iter_clips(page_size=1)]

    seen: list[Job] = []
    job = client.create_job(clip.id, excitation=StepRelease(force_n=5.0), parameters={"method": "default"})
    assert job.status == "queued"
    done = client.wait(job, timeout=180, on_progress=seen.append)
    assert done.status == "succeeded", done.error
    assert done.raise_for_status() is done
    assert done.result is not None
    assert done.result.eigenfrequency_hz == pytest.approx(truth["objects"][0]["eigenfrequency_hz"], rel=0.02)
    main = done.result.main
    assert main is not None
    assert main.mass_kg == pytest.approx(truth["objects"][0]["mass_kg"], rel=0.2)
    # Progress reached the caller: several states, the last one final.
    assert len(seen) >= 2
    assert seen[-1].status == "succeeded"
    assert {s.status for s in seen} >= {"running", "succeeded"}

    mask = client.download_artifact(done, "mask")
    assert isinstance(mask, bytes)
    assert mask.startswith(b"\x89PNG")
    saved = client.download_artifact(done, "result", tmp_path)
    assert isinstance(saved, Path)
    assert json.loads(saved.read_text())["eigenfrequency_hz"] == done.result.eigenfrequency_hz
    overlay = client.download_artifact(done.id, "overlay.png", tmp_path / "o.png")
    assert Path(overlay).read_bytes().startswith(b"\x89PNG")

    # A finished job does not change: the long-poll with its ETag answers 304, the client keeps the job.
    assert client.wait_for_change(done, timeout=1).etag == done.etag
    assert client.get_job(done.id, wait=5).status == "succeeded"
    listed = client.list_jobs(status="succeeded", clip_id=clip.id)
    assert [j.id for j in listed.items] == [done.id]

    client.delete_job(done.id)
    with pytest.raises(NotFoundError) as gone:
        client.get_job(done.id)
    assert gone.value.code == "job-not-found"
    assert gone.value.status == 404
    assert gone.value.request_id
    client.delete_clip(clip.id)
    with pytest.raises(NotFoundError):
        client.get_clip(clip.id)


def test_problems_become_exceptions(service: h.LiveService, client: Client, tmp_path: Path) -> None:
    with Client(service.base_url, timeout=10) as anonymous, pytest.raises(AuthenticationError) as denied:
        anonymous.get_job("x")
    assert denied.value.status == 401
    with pytest.raises(InvalidRequestError) as invalid:
        client.create_job("no-such-clip", excitation=Impulse(impulse_ns=0.2))
    assert invalid.value.code == "unknown-clip"
    assert invalid.value.errors is not None
    assert invalid.value.errors[0]["loc"] == ["body", "clip_id"]
    bogus = tmp_path / "notes.txt"
    bogus.write_text("not a clip " * 100)
    with pytest.raises(UnsupportedMediaTypeError) as unsupported:
        client.upload_clip(bogus)
    assert unsupported.value.detail is not None
    assert "notes.txt" in unsupported.value.detail


def test_failed_and_cancelled_jobs(
    client: Client, service: h.LiveService, truth_clip: tuple[Path, dict[str, Any]]
) -> None:
    # A job whose clip file vanished fails in the worker (clip-gone): raise_for_status says so.
    gone = client.upload_clip(truth_clip[0])
    for file in (service.data_dir / "clips" / gone.id).iterdir():
        file.unlink()
    failed = client.wait(client.create_job(gone.id), timeout=120)
    assert failed.status == "failed"
    with pytest.raises(JobFailedError) as error:
        failed.raise_for_status()
    assert error.value.problem is not None
    assert error.value.problem.type.endswith("/clip-gone")
    # One worker: the second job waits behind the first, and is cancelled there.
    clip = client.upload_clip(truth_clip[0])
    first = client.create_job(clip.id)
    second = client.create_job(clip.id)
    cancelled = client.cancel_job(second.id)
    assert cancelled.status == "cancelled"
    with pytest.raises(JobFailedError):
        cancelled.raise_for_status()
    assert client.wait(first, timeout=120).status == "succeeded"
    with pytest.raises(ConflictError) as conflict:
        client.cancel_job(first.id)
    assert conflict.value.code == "job-finished"


def test_retry_after_is_honoured(
    client: Client, service: h.LiveService, truth_clip: tuple[Path, Any]
) -> None:
    """Three active jobs at most (quota): a fourth gets 429 with Retry-After 1; the client waits and
    tries again until a slot frees (the worker runs one at a time), or, with no retries, raises."""
    clip = client.upload_clip(truth_clip[0])
    jobs = [client.create_job(clip.id) for _ in range(3)]
    with (
        Client(service.base_url, api_key=KEY, max_retries=0) as impatient,
        pytest.raises(RateLimitError) as limited,
    ):
        impatient.create_job(clip.id)
    assert limited.value.retry_after == 1
    assert limited.value.code == "too-many-jobs"
    with Client(service.base_url, api_key=KEY, max_retries=60) as patient:
        fourth = patient.create_job(clip.id)  # waits Retry-After between tries until a job has ended
    for job in [*jobs, fourth]:
        assert client.wait(job, timeout=180).done


def test_async_client(service: h.LiveService, truth_clip: tuple[Path, dict[str, Any]]) -> None:
    path, truth = truth_clip

    async def run() -> Job:
        async with AsyncClient(service.base_url, api_key=KEY, timeout=30) as es:
            job = await es.analyze(path, excitation=StepRelease(force_n=5.0), timeout=180)
            data = await es.download_artifact(job, "mask")
            assert isinstance(data, bytes)
            assert data.startswith(b"\x89PNG")
            ids = [c.id async for c in es.iter_clips(page_size=2)]
            assert job.clip_id in ids
            return job

    job = asyncio.run(run())
    assert job.status == "succeeded"
    assert job.result is not None
    assert job.result.eigenfrequency_hz == pytest.approx(truth["objects"][0]["eigenfrequency_hz"], rel=0.02)


def _signature_ok(headers: dict[str, str], body: bytes) -> bool:
    """The Standard Webhooks check a receiver makes, written out here (not the server's code)."""
    signed = f"{headers['webhook-id']}.{headers['webhook-timestamp']}.".encode() + body
    expected = "v1," + base64.b64encode(hmac.new(SECRET.encode(), signed, hashlib.sha256).digest()).decode()
    fresh = abs(time.time() - int(headers["webhook-timestamp"])) < 300
    return fresh and any(hmac.compare_digest(expected, s) for s in headers["webhook-signature"].split())


def test_webhook_is_signed_and_retried(
    client: Client, receiver: Receiver, truth_clip: tuple[Path, Any]
) -> None:
    clip = client.upload_clip(truth_clip[0])
    url = f"http://127.0.0.1:{receiver.port}/eigenscope"
    job = client.create_job(clip.id, excitation=StepRelease(force_n=5.0), callback_url=url)
    assert job.callback is not None
    assert job.callback.status == "waiting"
    done = client.wait(job, timeout=180)
    deadline = time.monotonic() + 60
    while len(receiver.of(job.id)) < 2:
        assert time.monotonic() < deadline, client.get_job(job.id).callback
        time.sleep(0.1)
    deliveries = receiver.of(job.id)
    assert len({d[0]["webhook-id"] for d in deliveries}) == 1  # one event, tried twice
    for headers, body in deliveries:
        assert _signature_ok(headers, body)
        event = json.loads(body)
        assert event["type"] == f"job.{done.status}"
        assert event["data"]["id"] == job.id
        assert event["data"]["status"] == done.status
    tampered = deliveries[0][1].replace(b'"status"', b'"STATUS"', 1)
    assert not _signature_ok(deliveries[0][0], tampered)
    deadline = time.monotonic() + 30
    while (state := client.get_job(job.id).callback) is not None and state.status != "delivered":
        assert time.monotonic() < deadline, state
        time.sleep(0.1)
    assert state is not None
    assert state.attempts == 2


def test_webhook_to_a_host_off_the_allow_list_is_refused(
    client: Client, truth_clip: tuple[Path, Any]
) -> None:
    clip = client.upload_clip(truth_clip[0])
    for url in (
        "http://169.254.169.254/latest/meta-data",
        "http://127.0.0.1:1/other-port",
        "http://example.com/",
    ):
        with pytest.raises(InvalidRequestError) as refused:
            client.create_job(clip.id, callback_url=url)
        assert refused.value.code == "callback-host-not-allowed"
