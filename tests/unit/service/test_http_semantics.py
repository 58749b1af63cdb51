"""What the server does at the HTTP level, as the OpenAPI document says it: HEAD wherever GET, a 405 whose
``Allow`` names every method of the path, the 202's ``ETag`` good for the first long-poll, job lists of
summaries with the result one link away, field errors in the user's words, one name per problem."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.errors import PROBLEM_BASE, PROBLEM_TYPES
from backend.settings import Settings
from tests.unit.service.helpers import RESULT, finish, make_client, upload

ROOT = Path(__file__).resolve().parents[3]
SPEC = json.loads((ROOT / "openapi" / "openapi.json").read_text())


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with make_client(settings) as c:
        yield c


def _job(client: TestClient, clip: Path, **body: Any) -> Any:
    clip_id = upload(client, clip).json()["id"]
    return client.post("/v1/jobs", json={"clip_id": clip_id, **body})


def test_head_answers_wherever_get_does(client: TestClient, small_clip: Path) -> None:
    created = _job(client, small_clip).json()
    finish(client, created["id"])
    paths = [
        "/healthz",
        "/v1/jobs",
        "/v1/clips",
        f"/v1/jobs/{created['id']}",
        f"/v1/clips/{created['clip_id']}",
        f"/v1/jobs/{created['id']}/artifacts/mask.png",
        "/openapi.json",
        "/",
    ]
    for path in paths:
        get, head = client.get(path), client.head(path)
        assert head.status_code == get.status_code == 200, (path, head.status_code)
        assert head.content == b"", path
        for name in ("content-type", "etag", "content-length"):
            assert head.headers.get(name) == get.headers.get(name), (path, name)
    missing = client.head("/v1/jobs/no-such-job")
    assert missing.status_code == 404
    assert missing.content == b""


def test_allow_lists_every_method_of_the_path(client: TestClient) -> None:
    for path in SPEC["paths"]:
        concrete = path.replace("{job_id}", "j").replace("{clip_id}", "c").replace("{stream_id}", "s")
        concrete = concrete.replace("{name}", "mask.png")
        methods = {m.upper() for m in SPEC["paths"][path]}
        if "GET" in methods:
            methods.add("HEAD")
        refused = client.request("PATCH", concrete)
        assert refused.status_code == 405, path
        assert set(refused.headers["allow"].split(", ")) == methods, path
        assert refused.headers["content-type"] == "application/problem+json"
        assert "PATCH is not allowed" in refused.json()["detail"]
    assert client.put("/v1/jobs").headers["allow"] == "GET, HEAD, POST"
    assert client.head("/v1/jobs/j/cancel").headers["allow"] == "POST"


def test_the_202_etag_is_the_jobs_and_long_polls_at_once(client: TestClient, small_clip: Path) -> None:
    created = _job(client, small_clip)
    assert created.status_code == 202
    etag = created.headers["etag"]
    job_url = created.headers["location"]
    assert client.get(job_url).headers["etag"] == etag
    # The tag of the 202 is current: the first poll may already wait for a change.
    assert client.get(job_url, headers={"If-None-Match": etag}).status_code == 304
    polled = client.get(job_url, params={"wait": 0.2}, headers={"If-None-Match": etag})
    assert polled.status_code == 304
    assert polled.headers["etag"] == etag
    assert polled.headers["retry-after"]


def test_job_lists_carry_summaries_and_the_result_is_one_link_away(
    client: TestClient, small_clip: Path
) -> None:
    done = _job(client, small_clip).json()
    waiting = _job(client, small_clip).json()
    finish(client, done["id"])
    page = client.get("/v1/jobs").json()
    items = {item["id"]: item for item in page["items"]}
    assert "result" not in items[done["id"]]
    assert items[done["id"]]["summary"] == {
        "eigenfrequency_hz": RESULT["eigenfrequency_hz"],
        "eigenfrequency_uncertainty_hz": None,
        "damping_ratio": None,
        "stiffness_n_per_m": None,
        "mass_kg": None,
        "objects": 0,
        "warnings": 0,
    }
    assert items[waiting["id"]]["summary"] is None
    assert items[waiting["id"]]["result_url"] is None
    assert items[done["id"]]["url"] == f"/v1/jobs/{done['id']}"
    whole = client.get(items[done["id"]]["result_url"])
    assert items[done["id"]]["result_url"] == f"/v1/jobs/{done['id']}/result"
    assert whole.status_code == 200
    assert whole.headers["content-type"] == "application/json"
    assert whole.json()["eigenfrequency_hz"] == RESULT["eigenfrequency_hz"]
    assert (
        client.get(
            items[done["id"]]["result_url"], headers={"If-None-Match": whole.headers["etag"]}
        ).status_code
        == 304
    )
    assert client.get(f"/v1/jobs/{waiting['id']}/result").json()["type"] == PROBLEM_BASE + "result-not-found"
    # The job's record lists every file, result.json too.
    job = client.get(f"/v1/jobs/{done['id']}").json()
    listed = job["result"]["artifacts"]["result"]
    assert listed == f"/v1/jobs/{done['id']}/artifacts/result.json"
    assert client.get(listed).json()["eigenfrequency_hz"] == RESULT["eigenfrequency_hz"]


@pytest.mark.parametrize(
    ("excitation", "loc", "words"),
    [
        ({"type": "step_release"}, ["body", "excitation", "force_n"], "force that held the object"),
        ([{"type": "impulse"}], ["body", "excitation", 0, "impulse_ns"], "impulse that struck the object"),
        ({"type": "kick", "force_n": 1}, ["body", "excitation"], "not 'kick'"),
        ({"force_n": 1}, ["body", "excitation"], "'step_release'"),
    ],
)
def test_field_errors_are_in_the_users_words(
    client: TestClient, small_clip: Path, excitation: Any, loc: list[Any], words: str
) -> None:
    refused = _job(client, small_clip, excitation=excitation)
    assert refused.status_code == 422
    problem = refused.json()
    assert [e["loc"] for e in problem["errors"]] == [loc]
    assert words in problem["errors"][0]["msg"]
    text = json.dumps(problem)
    for internal in ("tagged-union", "list[", "Input should be a valid list", "function-"):
        assert internal not in text, problem


def test_problem_types_follow_one_scheme(client: TestClient) -> None:
    from backend.errors import RENAMED

    for code, kind in PROBLEM_TYPES.items():
        if kind.status == 404:
            assert code == "not-found" or code.endswith("-not-found"), code
    assert set(RENAMED.values()) <= set(PROBLEM_TYPES)
    documented = (ROOT / "docs" / "problems.md").read_text()
    for old, new in RENAMED.items():
        assert f"| `{old}` | `{new}` |" in documented, (old, new)
    missing = client.get("/v1/clips/nope").json()
    assert missing["type"] == PROBLEM_BASE + "clip-not-found"
    unknown = client.post("/v1/jobs", json={"clip_id": "nope"}).json()
    assert unknown["type"] == PROBLEM_BASE + "unknown-clip"
    assert unknown["status"] == 422


def test_every_route_has_its_own_metric_label(client: TestClient) -> None:
    for path in ("/openapi.json", "/asyncapi.json", "/static/app.css", "/docs"):
        assert client.get(path).status_code == 200
    metrics = client.get("/metrics").text
    requests = [line for line in metrics.splitlines() if line.startswith("eigenscope_http_requests_total{")]
    assert not [line for line in requests if 'route="unmatched"' in line and 'status="200"' in line], requests
    assert any('route="/openapi.json"' in line for line in requests)
