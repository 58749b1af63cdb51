"""What robots and lab scripts lean on, in-process: long-poll, ETag and 304, deleting jobs, listing clips,
idempotent uploads and callback URLs checked against the operator's allow-list."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.settings import Settings
from tests.unit.service.helpers import finish, make_client, upload

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path / "data", long_poll_max_s=5)
    with make_client(settings) as c:
        yield c


def _ctx(client: TestClient) -> Any:
    return client.app.state.ctx  # type: ignore[attr-defined]


def _job(client: TestClient, clip: Path, **body: Any) -> dict[str, Any]:
    clip_id = upload(client, clip).json()["id"]
    response = client.post("/v1/jobs", json={"clip_id": clip_id, **body})
    assert response.status_code == 202, response.text
    return dict(response.json())


def _later(delay_s: float, action: Any) -> threading.Thread:
    thread = threading.Thread(target=lambda: (time.sleep(delay_s), action()), daemon=True)
    thread.start()
    return thread


# ------------------------------------------------------------------------------------------- long-poll


def test_long_poll_answers_when_the_job_ends(client: TestClient, small_clip: Path) -> None:
    job = _job(client, small_clip)
    worker = _later(0.3, lambda: finish(client, job["id"]))
    response = client.get(f"/v1/jobs/{job['id']}", params={"wait": 30})
    worker.join()
    assert response.status_code == 200
    assert response.json()["status"] == "succeeded"  # it waited for the end rather than answer "queued"
    assert "retry-after" not in response.headers
    assert response.headers["etag"].startswith('"')


def test_long_poll_gives_the_job_as_it_is_when_the_wait_runs_out(
    client: TestClient, small_clip: Path
) -> None:
    job = _job(client, small_clip)
    response = client.get(f"/v1/jobs/{job['id']}", params={"wait": 0.2})
    assert response.status_code == 200
    assert response.json()["status"] == "queued"
    assert response.headers["retry-after"] == "1"
    # A wait above the server's cap (5 s here) is cut to it, not refused.
    capped = client.get(f"/v1/jobs/{job['id']}", params={"wait": 10_000})
    assert capped.status_code == 200
    assert capped.json()["status"] == "queued"
    negative = client.get(f"/v1/jobs/{job['id']}", params={"wait": -1})
    assert negative.status_code == 422
    assert negative.headers["content-type"] == "application/problem+json"


def test_long_poll_with_an_etag_answers_on_any_change(client: TestClient, small_clip: Path) -> None:
    job = _job(client, small_clip)
    ctx = _ctx(client)
    assert ctx.store.claim_job(job["id"], "me/1/x").job is not None
    etag = client.get(f"/v1/jobs/{job['id']}").headers["etag"]
    progressed = _later(0.3, lambda: ctx.store.report_progress(job["id"], "me/1/x", "flow", 0.4))
    changed = client.get(f"/v1/jobs/{job['id']}", params={"wait": 30}, headers={"If-None-Match": etag})
    progressed.join()
    assert changed.status_code == 200
    assert changed.headers["etag"] != etag
    assert (changed.json()["stage"], changed.json()["progress"]) == ("flow", 0.4)  # it waited for the change
    latest = changed.headers["etag"]
    unchanged = client.get(f"/v1/jobs/{job['id']}", params={"wait": 0.2}, headers={"If-None-Match": latest})
    assert unchanged.status_code == 304
    assert unchanged.content == b""
    assert unchanged.headers["etag"] == latest


# --------------------------------------------------------------------------------------------- ETag


def test_job_etag_and_304(client: TestClient, small_clip: Path) -> None:
    job = _job(client, small_clip)
    first = client.get(f"/v1/jobs/{job['id']}")
    etag = first.headers["etag"]
    assert client.get(f"/v1/jobs/{job['id']}").headers["etag"] == etag  # stable while nothing changes
    not_modified = client.get(f"/v1/jobs/{job['id']}", headers={"If-None-Match": etag})
    assert not_modified.status_code == 304
    assert (
        client.get(f"/v1/jobs/{job['id']}", headers={"If-None-Match": f'W/{etag}, "other"'}).status_code
        == 304
    )
    assert client.get(f"/v1/jobs/{job['id']}", headers={"If-None-Match": '"stale"'}).status_code == 200
    finish(client, job["id"])
    done = client.get(f"/v1/jobs/{job['id']}", headers={"If-None-Match": etag})
    assert done.status_code == 200
    assert done.headers["etag"] != etag


def test_artifacts_answer_304_for_their_etag(client: TestClient, small_clip: Path) -> None:
    job = _job(client, small_clip)
    finish(client, job["id"], output=b"\x89PNG\r\n\x1a\n-mask-")
    url = f"/v1/jobs/{job['id']}/artifacts/mask.png"
    first = client.get(url)
    assert first.status_code == 200
    assert first.content == b"\x89PNG\r\n\x1a\n-mask-"
    etag = first.headers["etag"]
    assert "private" in first.headers["cache-control"]
    again = client.get(url, headers={"If-None-Match": etag})
    assert again.status_code == 304
    assert again.content == b""
    assert again.headers["etag"] == etag
    assert client.get(url, headers={"If-None-Match": '"other"'}).status_code == 200


# ------------------------------------------------------------------------------------ delete and list


def test_delete_job_removes_record_and_artifacts(client: TestClient, small_clip: Path) -> None:
    job = _job(client, small_clip)
    finish(client, job["id"])
    folder = _ctx(client).storage.job_dir(job["id"])
    assert folder.is_dir()
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    assert client.get(f"/v1/jobs/{job['id']}").status_code == 404
    assert not folder.exists()
    gone = client.delete(f"/v1/jobs/{job['id']}")
    assert gone.status_code == 404
    assert gone.json()["type"].endswith("/job-not-found")


def test_delete_of_a_running_job_cancels_it_first(client: TestClient, small_clip: Path) -> None:
    job = _job(client, small_clip)
    ctx = _ctx(client)
    assert ctx.store.claim_job(job["id"], "worker/1/x").job is not None
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204
    # The worker's next write no longer lands: it stops.
    assert not ctx.store.report_progress(job["id"], "worker/1/x", "flow", 0.5)
    assert ctx.store.find_job(job["id"]) is None


def test_list_clips_pages_newest_first(client: TestClient, small_clip: Path) -> None:
    ids = [upload(client, small_clip).json()["id"] for _ in range(5)]
    seen: list[str] = []
    cursor = None
    pages = 0
    while True:
        params: dict[str, Any] = {"limit": 2}
        if cursor:
            params["cursor"] = cursor
        page = client.get("/v1/clips", params=params).json()
        pages += 1
        seen += [c["id"] for c in page["items"]]
        assert all(c["format"] == "npz" for c in page["items"])
        cursor = page["next_cursor"]
        if cursor is None:
            break
    assert pages == 3
    assert seen == list(reversed(ids))
    bad = client.get("/v1/clips", params={"cursor": "nonsense"})
    assert bad.status_code == 422
    assert bad.json()["type"].endswith("/invalid-cursor")


# ---------------------------------------------------------------------------------- idempotent uploads


def test_upload_with_idempotency_key_is_safe_to_retry(
    client: TestClient, small_clip: Path, tmp_path: Path
) -> None:
    key = {"Idempotency-Key": "upload-7"}
    first = upload(client, small_clip, headers=key)
    assert first.status_code == 201
    assert "idempotent-replayed" not in first.headers
    again = upload(client, small_clip, headers=key)
    assert again.status_code == 201
    assert again.headers["idempotent-replayed"] == "true"
    assert again.json() == first.json()
    listed = client.get("/v1/clips").json()["items"]
    assert [c["id"] for c in listed] == [first.json()["id"]]  # one clip, not two
    other = tmp_path / "other.npz"
    other.write_bytes(small_clip.read_bytes() + b"\0")  # other content under the same key
    reused = upload(client, other, headers=key)
    assert reused.status_code == 422
    assert reused.json()["type"].endswith("/idempotency-key-reused")
    fresh = upload(client, small_clip, headers={"Idempotency-Key": "upload-8"})
    assert fresh.json()["id"] != first.json()["id"]


# ---------------------------------------------------------------------------------------- callbacks


def test_callback_url_refused_when_the_operator_allows_none(client: TestClient, small_clip: Path) -> None:
    clip_id = upload(client, small_clip).json()["id"]
    response = client.post("/v1/jobs", json={"clip_id": clip_id, "callback_url": "http://127.0.0.1:9/hook"})
    assert response.status_code == 422
    assert response.json()["type"].endswith("/callbacks-disabled")


@pytest.fixture
def hooked(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(
        data_dir=tmp_path / "data",
        callback_hosts="robot.lab, *.example.org, 127.0.0.1:9100",
        callback_secret="s3cret-0123456789",
        callback_poll_interval_s=30,  # no delivery during these tests
    )
    with make_client(settings) as c:
        yield c


@pytest.mark.parametrize(
    ("url", "code"),
    [
        ("http://evil.example.com/hook", "callback-host-not-allowed"),
        ("http://127.0.0.1:9101/hook", "callback-host-not-allowed"),
        ("http://169.254.169.254/latest/meta-data", "callback-host-not-allowed"),
        ("http://example.org/hook", "callback-host-not-allowed"),
        ("ftp://robot.lab/hook", "invalid-callback-url"),
        ("http://user:pw@robot.lab/hook", "invalid-callback-url"),
    ],
)
def test_callback_host_must_be_allowed(hooked: TestClient, small_clip: Path, url: str, code: str) -> None:
    clip_id = upload(hooked, small_clip).json()["id"]
    response = hooked.post("/v1/jobs", json={"clip_id": clip_id, "callback_url": url})
    assert response.status_code == 422, response.text
    assert response.json()["type"].endswith(f"/{code}")
    assert response.json()["errors"][0]["loc"] == ["body", "callback_url"]


@pytest.mark.parametrize(
    "url",
    [
        "https://robot.lab/done",
        "http://ROBOT.lab:8080/x",
        "https://a.b.example.org/hook",
        "http://127.0.0.1:9100/",
    ],
)
def test_allowed_callback_is_recorded_and_shown(hooked: TestClient, small_clip: Path, url: str) -> None:
    job = _job(hooked, small_clip, callback_url=url)
    assert job["callback"] == {"url": url, "status": "waiting", "attempts": 0, "last_error": None}
    finish(hooked, job["id"])
    assert hooked.get(f"/v1/jobs/{job['id']}").json()["callback"]["status"] == "pending"


def test_callback_hosts_need_a_secret(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="CALLBACK_SECRET"):
        Settings(data_dir=tmp_path, callback_hosts="robot.lab")
