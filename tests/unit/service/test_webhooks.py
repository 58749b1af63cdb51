"""Webhooks: the allow-list, Standard Webhooks signatures, and deliveries with retries to a real HTTP
receiver on this machine."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from backend.settings import Settings
from backend.store import NewClip, NewJob, Store
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


def _ended_job(store: Store, url: str, n: int = 1) -> str:
    store.add_clip(
        NewClip(clip_id=f"c{n}", filename="a.npz", path=f"clips/c{n}/clip.npz", info={}, size_bytes=1)
    )
    job, _ = store.create_job(NewJob(clip_id=f"c{n}", excitation=None, parameters={}, callback_url=url))
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


# Issue 27, item 4: URLs validated by the parser that delivers them; every error recorded ------------


@pytest.mark.parametrize(
    "url",
    [
        "http://127.0.0.1\t:19261/tab",
        "http://127.0.0.1:19261/x\r\nX-Injected: 1",
        "http://127.0.0.1:19261/a b",
        "http://127.0.0.1:19261/\x00",
        " http://127.0.0.1:19261/x",
        "http://127.0.0.1:99999/x",
        "http://127.0.0.1:19261\n/x",
    ],
)
def test_a_callback_url_httpx_would_refuse_is_422_at_creation(
    tmp_path: Path, small_clip: Path, url: str
) -> None:
    from tests.unit.service.helpers import make_client, upload

    settings = Settings(data_dir=tmp_path / "data", callback_hosts="127.0.0.1:19261", callback_secret=SECRET)
    with make_client(settings) as client:
        clip = upload(client, small_clip).json()
        response = client.post("/v1/jobs", json={"clip_id": clip["id"], "callback_url": url})
        assert response.status_code == 422, (url, response.text)
        assert response.json()["type"].endswith("/invalid-callback-url")
        ok = client.post(
            "/v1/jobs", json={"clip_id": clip["id"], "callback_url": "http://127.0.0.1:19261/ok"}
        )
        assert ok.status_code == 202, ok.text


def _wait(predicate: Callable[[], bool], timeout_s: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def _dispatch_until_settled(store: Store, settings: Settings, job_id: str) -> Dispatcher:
    dispatcher = Dispatcher(store, settings, lambda job: {"id": job.id})
    dispatcher.start()
    try:
        assert _wait(lambda: store.get_job(job_id).callback_status in ("failed", "delivered"))
    finally:
        dispatcher.stop()
    return dispatcher


def _settings(tmp_path: Path, **extra: Any) -> Settings:
    """Callbacks to 127.0.0.1:19261 (unless ``extra`` says otherwise), retried at once, 3 attempts."""
    values: dict[str, Any] = {
        "callback_hosts": "127.0.0.1:19261",
        "callback_retry_base_s": 0.01,
        "callback_max_attempts": 3,
        "callback_poll_interval_s": 0.01,
    }
    return Settings(data_dir=tmp_path / "data", callback_secret=SECRET, **{**values, **extra})


def test_a_stored_url_httpx_refuses_fails_its_callback_with_the_reason(store: Store, tmp_path: Path) -> None:
    """A URL accepted before the creation check (the tab the allow-list's parser stripped) is failed at
    its first attempt, with the reason, instead of escaping the delivery and being retried forever."""
    job_id = _ended_job(store, "http://127.0.0.1\t:19261/tab")
    _dispatch_until_settled(store, _settings(tmp_path), job_id)
    record = store.get_job(job_id)
    assert (record.callback_status, record.callback_attempts) == ("failed", 1)
    assert record.callback_error is not None
    assert "not usable" in record.callback_error


def test_every_delivery_error_is_recorded_and_the_attempts_stop_at_the_maximum(
    store: Store, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Whatever an attempt raises (here httpx's InvalidURL, which is no httpx.HTTPError) is recorded and
    counted; the callback is given up at the maximum."""

    def refuse(*_args: Any, **_kwargs: Any) -> Any:
        raise httpx.InvalidURL("Invalid non-printable ASCII character in URL")

    monkeypatch.setattr(httpx.Client, "send", refuse)
    job_id = _ended_job(store, "http://127.0.0.1:19261/hook")
    _dispatch_until_settled(store, _settings(tmp_path), job_id)
    record = store.get_job(job_id)
    assert (record.callback_status, record.callback_attempts) == ("failed", 3)
    assert record.callback_error is not None
    assert record.callback_error.startswith("InvalidURL")


def test_a_callback_whose_last_attempt_never_reported_is_given_up(store: Store) -> None:
    job_id = _ended_job(store, "http://robot.lab/x")
    for _ in range(2):  # two attempts claimed, their processes died before recording anything
        assert store.claim_callback(job_id, lease_s=-1, max_attempts=2) is not None
    assert store.claim_callback(job_id, lease_s=30, max_attempts=2) is None
    record = store.get_job(job_id)
    assert (record.callback_status, record.callback_attempts) == ("failed", 2)
    assert record.callback_error is not None


# Issue 27, item 12: deliveries that cannot block one another ----------------------------------------


def _leased(store: Store, job_id: str) -> bool:
    from sqlalchemy import select

    from backend.store.schema import JobRow

    with store.engine.connect() as conn:
        until = conn.execute(select(JobRow.callback_lease_until).where(JobRow.id == job_id)).scalar()
    return until is not None and until > time.time()


class Hanging:
    """A receiver whose answers wait for ``release``; counts deliveries under way at once."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.now = 0
        self.most = 0
        self.lock = threading.Lock()

        def policy(_headers: dict[str, str], _seen: list[tuple[dict[str, str], bytes]]) -> int:
            return 204

        self.receiver = Receiver(policy)
        handler = self.receiver.server.RequestHandlerClass
        outer = self
        original = handler.do_POST  # type: ignore[attr-defined]

        def do_post(handler_self: Any) -> None:
            with outer.lock:
                outer.now += 1
                outer.most = max(outer.most, outer.now)
            outer.release.wait(60)
            with outer.lock:
                outer.now -= 1
            original(handler_self)

        handler.do_POST = do_post  # type: ignore[attr-defined]


def test_a_hanging_receiver_delays_only_its_own_callbacks(store: Store, tmp_path: Path) -> None:
    slow, fast = Hanging(), Receiver.scripted([])
    try:
        hosts = f"127.0.0.1:{slow.receiver.port},localhost:{fast.port}"
        settings = _settings(tmp_path, callback_hosts=hosts, callback_timeout_s=60, callback_per_host=2)
        hanging = [_ended_job(store, f"http://127.0.0.1:{slow.receiver.port}/h", n) for n in range(5)]
        other = _ended_job(store, f"http://localhost:{fast.port}/f", 9)
        dispatcher = Dispatcher(store, settings, lambda job: {"id": job.id})
        dispatcher.start()
        try:
            # The other tenant's callback is delivered while the hanging receiver holds two deliveries.
            assert _wait(lambda: store.get_job(other).callback_status == "delivered")
            assert slow.now == 2
            # Only what is being delivered is leased: the rest stays free for any API process.
            leased = [_leased(store, j) for j in hanging]
            assert sum(leased) == 2, leased
            slow.release.set()
            assert _wait(lambda: all(store.get_job(j).callback_status == "delivered" for j in hanging))
        finally:
            slow.release.set()
            dispatcher.stop()
        assert slow.most == 2  # never more than callback_per_host at once to one host
        assert [store.get_job(j).callback_attempts for j in [*hanging, other]] == [1] * 6
        assert len(slow.receiver.deliveries) == 5  # each delivered once
        assert dispatcher.lease_s > 3 * settings.callback_timeout_s
    finally:
        slow.receiver.close()
        fast.close()


def test_a_delivery_is_what_the_documents_webhook_says(
    store: Store, tmp_path: Path, receiver: Receiver
) -> None:
    """The body is a JobEvent (the OpenAPI document's ``webhooks``), the headers those it names, and the
    signature checks out by the scheme its description gives."""
    import base64
    import hashlib
    import hmac

    from api_schemas import JobEvent
    from service.context import _webhook_view

    spec = json.loads((Path(__file__).resolve().parents[3] / "openapi" / "openapi.json").read_text())
    hook = spec["webhooks"]["jobEnded"]["post"]
    settings = Settings(
        data_dir=tmp_path / "data", callback_hosts=f"127.0.0.1:{receiver.port}", callback_secret=SECRET
    )
    job_id = _ended_job(store, f"http://127.0.0.1:{receiver.port}/hook")
    dispatcher = Dispatcher(store, settings, _webhook_view(settings))
    with httpx.Client() as client:
        for _ in range(20):
            if any(dispatcher.deliver(client, job) for job in store.claim_due_callbacks(limit=5, lease_s=30)):
                break
            time.sleep(0.06)
    headers, body = receiver.deliveries[-1]
    event = JobEvent.model_validate_json(body)
    assert (event.type, event.data.id) == ("job.failed", job_id)
    named = {p["name"] for p in hook["parameters"] if p["in"] == "header"}
    assert named <= {k.lower() for k in headers}
    signed = f"{headers['webhook-id']}.{headers['webhook-timestamp']}.".encode() + body
    key = base64.b64decode(SECRET.removeprefix("whsec_")) if SECRET.startswith("whsec_") else SECRET.encode()
    expected = base64.b64encode(hmac.new(key, signed, hashlib.sha256).digest()).decode()
    assert f"v1,{expected}" in headers["webhook-signature"].split()
