"""Webhooks: the allow-list, Standard Webhooks signatures, and deliveries with retries to a real HTTP
receiver on this machine."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from service.settings import Settings
from service.store import Store
from service.webhooks import Dispatcher, allowed, retry_delay, sign, verify
from tests.webhook_receiver import Receiver

SECRET = "whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw"


def test_signature_matches_the_standard_webhooks_test_vector() -> None:
    """The specification's published vector: receivers can verify with any Standard Webhooks library."""
    body = b'{"test": 2432232314}'
    signature = sign(SECRET, "msg_p5jXN8AQM9LWM0D4loKWxJek", 1614265330, body)
    assert signature == "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="


def test_verify_refuses_altered_bodies_wrong_keys_and_stale_timestamps() -> None:
    now = int(time.time())
    body = b'{"type":"job.succeeded"}'
    headers = {"webhook-id": "j1.succeeded", "webhook-timestamp": str(now)}
    headers["webhook-signature"] = sign("plain-secret-value", "j1.succeeded", now, body)
    assert verify("plain-secret-value", headers, body)
    assert not verify("plain-secret-value", headers, body + b" ")
    assert not verify("another-secret-value", headers, body)
    old = {**headers, "webhook-timestamp": str(now - 3600)}
    old["webhook-signature"] = sign("plain-secret-value", "j1.succeeded", now - 3600, body)
    assert not verify("plain-secret-value", old, body)
    assert not verify("plain-secret-value", {}, body)


@pytest.mark.parametrize(
    ("url", "ok"),
    [
        ("https://robot.lab/done", True),
        ("http://ROBOT.LAB:9/x", True),
        ("https://a.example.org/x", True),
        ("https://example.org/x", False),
        ("https://example.org.evil.com/x", False),
        ("http://127.0.0.1:9100/x", True),
        ("http://127.0.0.1:9101/x", False),
        ("http://127.0.0.1/x", False),
        ("http://[::1]:7000/x", True),
        ("http://localhost/x", False),
        ("file:///etc/passwd", False),
        ("http://user:pw@robot.lab/x", False),
        ("http://robot.lab:99999/x", False),
    ],
)
def test_allow_list(url: str, ok: bool) -> None:
    assert allowed(url, "robot.lab, *.example.org, 127.0.0.1:9100, [::1]:7000") is ok
    assert not allowed(url, None)


def test_retry_delay_doubles_up_to_the_cap_and_honours_retry_after(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, callback_retry_base_s=2, callback_retry_max_s=20)
    assert [retry_delay(n, settings) for n in (1, 2, 3, 4, 5)] == [2, 4, 8, 16, 20]
    assert retry_delay(1, settings, "7") == 7
    assert retry_delay(1, settings, "999") == 20


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    r = Receiver.scripted([500, 503])
    yield r
    r.close()


def _ended_job(store: Store, url: str) -> str:
    store.add_clip(clip_id="c1", filename="a.npz", path="clips/c1/clip.npz", info={}, size_bytes=1)
    job, _ = store.create_job(clip_id="c1", excitation=None, parameters={}, callback_url=url)
    assert store.claim_job(job.id, "w/1/x").job is not None
    assert store.fail_job(
        job.id, "w/1/x", {"type": "about:blank", "title": "x", "status": 422, "detail": "d"}
    )
    return job.id


def test_dispatcher_retries_until_delivered_and_signs_each_try(
    store: Store, tmp_path: Path, receiver: Receiver
) -> None:
    settings = Settings(
        data_dir=tmp_path / "data",
        callback_hosts=f"127.0.0.1:{receiver.port}",
        callback_secret=SECRET,
        callback_retry_base_s=0.05,
    )
    job_id = _ended_job(store, f"http://127.0.0.1:{receiver.port}/hook")
    dispatcher = Dispatcher(store, settings, lambda job: {"id": job.id, "status": job.status})
    outcomes = []
    with httpx.Client() as client:
        for _ in range(20):
            for job in store.claim_due_callbacks(limit=5, lease_s=30):
                outcomes.append(dispatcher.deliver(client, job))
            if outcomes and outcomes[-1]:
                break
            time.sleep(0.06)
    assert outcomes == [False, False, True]  # 500, 503, then 204
    assert len(receiver.deliveries) == 3
    ids = set()
    for headers, body in receiver.deliveries:
        assert verify(SECRET, headers, body)
        ids.add(headers["webhook-id"])
        doc = json.loads(body)
        assert doc["type"] == "job.failed"
        assert doc["data"] == {"id": job_id, "status": "failed"}
    assert ids == {f"{job_id}.failed"}  # one event: receivers deduplicate retries by its id
    record = store.get_job(job_id)
    assert (record.callback_status, record.callback_attempts, record.callback_error) == ("delivered", 3, None)
    assert store.claim_due_callbacks(limit=5, lease_s=30) == []


def test_dispatcher_gives_up_after_max_attempts(store: Store, tmp_path: Path) -> None:
    receiver = Receiver.scripted([500] * 10)
    try:
        settings = Settings(
            data_dir=tmp_path / "data",
            callback_hosts=f"127.0.0.1:{receiver.port}",
            callback_secret=SECRET,
            callback_retry_base_s=0.01,
            callback_max_attempts=2,
        )
        job_id = _ended_job(store, f"http://127.0.0.1:{receiver.port}/hook")
        dispatcher = Dispatcher(store, settings, lambda job: {"id": job.id})
        with httpx.Client() as client:
            for _ in range(20):
                for job in store.claim_due_callbacks(limit=5, lease_s=30):
                    dispatcher.deliver(client, job)
                if store.get_job(job_id).callback_status == "failed":
                    break
                time.sleep(0.02)
    finally:
        receiver.close()
    record = store.get_job(job_id)
    assert (record.callback_status, record.callback_attempts, record.callback_error) == (
        "failed",
        2,
        "HTTP 500",
    )
    assert len(receiver.deliveries) == 2


def test_a_host_removed_from_the_allow_list_gets_nothing(
    store: Store, tmp_path: Path, receiver: Receiver
) -> None:
    settings = Settings(data_dir=tmp_path / "data", callback_hosts="robot.lab", callback_secret=SECRET)
    job_id = _ended_job(store, f"http://127.0.0.1:{receiver.port}/hook")
    dispatcher = Dispatcher(store, settings, lambda job: {"id": job.id})
    with httpx.Client() as client:
        (job,) = store.claim_due_callbacks(limit=5, lease_s=30)
        assert not dispatcher.deliver(client, job)
    assert receiver.deliveries == []
    assert store.get_job(job_id).callback_status == "failed"


def test_a_leased_callback_is_not_claimed_twice(store: Store) -> None:
    job_id = _ended_job(store, "http://robot.lab/x")
    (first,) = store.claim_due_callbacks(limit=5, lease_s=30)
    assert first.id == job_id
    assert store.claim_due_callbacks(limit=5, lease_s=30) == []  # another API process finds it leased
