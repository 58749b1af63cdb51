"""The client's HTTP behaviour against scripted responses (httpx's MockTransport): retries and
Retry-After, problem documents as exceptions, idempotency keys kept across retries, long-polls."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from typing import Any

import eigenscope_client._client as client_module
import httpx
import pytest
from eigenscope_client import (
    APIError,
    Client,
    NotFoundError,
    RateLimitError,
    ServerError,
    ServiceUnavailableError,
    StepRelease,
    TransportError,
    WaitTimeoutError,
)

JOB = {
    "id": "j1",
    "clip_id": "c1",
    "status": "queued",
    "progress": 0.0,
    "parameters": {},
    "created_at": "2026-01-01T00:00:00Z",
}


@pytest.fixture
def sleeps(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """``time.sleep`` of the client, recorded instead of slept."""
    slept: list[float] = []
    monkeypatch.setattr(client_module.time, "sleep", slept.append)
    return slept


def scripted(responses: list[Any]) -> tuple[Client, list[httpx.Request]]:
    """A client whose server answers with ``responses`` in turn (an exception instance is raised)."""
    seen: list[httpx.Request] = []
    queue: Iterator[Any] = iter(responses)

    def handler(request: httpx.Request) -> httpx.Response:
        request.read()
        seen.append(request)
        item = next(queue)
        if isinstance(item, Exception):
            raise item
        assert isinstance(item, httpx.Response)
        return item

    http = httpx.Client(transport=httpx.MockTransport(handler))
    return Client("http://eigenscope.test", http_client=http, max_retries=3), seen


def problem(status: int, code: str, **headers: str) -> httpx.Response:
    doc = {"type": f"https://eigenscope.dev/problems/{code}", "title": "T", "status": status, "detail": "why"}
    return httpx.Response(
        status, content=json.dumps(doc), headers={"content-type": "application/problem+json", **headers}
    )


def test_retry_after_is_waited_before_trying_again(sleeps: list[float]) -> None:
    client, seen = scripted(
        [
            problem(503, "database-unavailable", **{"retry-after": "2"}),
            problem(429, "too-many-jobs", **{"retry-after": "7"}),
            httpx.Response(202, json=JOB),
        ]
    )
    job = client.create_job("c1", excitation=StepRelease(force_n=3))
    assert job.id == "j1"
    assert sleeps == [2.0, 7.0]
    # The three tries are one request: the same Idempotency-Key makes the retries safe.
    keys = {r.headers["idempotency-key"] for r in seen}
    assert len(seen) == 3
    assert len(keys) == 1
    body = json.loads(seen[0].content)
    assert body == {"clip_id": "c1", "excitation": {"type": "step_release", "force_n": 3}}


def test_retries_run_out_into_the_exception(sleeps: list[float]) -> None:
    client, _seen = scripted([problem(429, "too-many-jobs", **{"retry-after": "1"})] * 4)
    with pytest.raises(RateLimitError) as error:
        client.get_job("j1")
    assert error.value.retry_after == 1
    assert error.value.code == "too-many-jobs"
    assert sleeps == [1.0, 1.0, 1.0]


def test_a_long_retry_after_is_capped(sleeps: list[float]) -> None:
    client, _ = scripted([problem(503, "x", **{"retry-after": "86400"}), httpx.Response(200, json=JOB)])
    client.get_job("j1")
    assert sleeps == [client_module.MAX_RETRY_WAIT_S]


def test_connection_failures_are_retried_then_reported(sleeps: list[float]) -> None:
    boom = httpx.ConnectError("connection refused")
    client, _ = scripted([boom, boom, httpx.Response(200, json=JOB)])
    assert client.get_job("j1").status == "queued"
    assert sleeps == [0.5, 1.0]
    client, _ = scripted([boom] * 4)
    with pytest.raises(TransportError, match="connection refused"):
        client.get_job("j1")


def test_problem_documents_become_typed_exceptions(sleeps: list[float]) -> None:
    client, _ = scripted([problem(404, "job-not-found", **{"x-request-id": "r-1"})])
    with pytest.raises(NotFoundError) as missing:
        client.get_job("nope")
    error = missing.value
    assert (error.status, error.title, error.detail, error.code, error.request_id) == (
        404,
        "T",
        "why",
        "job-not-found",
        "r-1",
    )
    assert str(error) == "404 T: why"
    client, _ = scripted([httpx.Response(500, text="<html>proxy error</html>")])
    with pytest.raises(ServerError) as broken:
        client.get_job("j1")
    assert "proxy error" in (broken.value.detail or "")
    assert not isinstance(broken.value, ServiceUnavailableError)
    assert isinstance(broken.value, APIError)
    assert sleeps == []


def test_wait_long_polls_and_does_not_hammer_a_server_that_ignores_it(sleeps: list[float]) -> None:
    running = {**JOB, "status": "running", "progress": 0.5}
    done = {**JOB, "status": "succeeded", "progress": 1.0}
    answers = [httpx.Response(200, json=running, headers={"etag": '"a"', "retry-after": "1"})] * 3
    client, seen = scripted([*answers, httpx.Response(200, json=done, headers={"etag": '"b"'})])
    job = client.wait("j1", timeout=600)
    assert job.status == "succeeded"
    assert [r.url.params.get("wait") for r in seen] == [None, "60", "60", "60"]
    # The answers came back at once, unchanged: the client slept Retry-After between them.
    assert sleeps == [1.0, 1.0]


def test_wait_with_progress_asks_for_changes(sleeps: list[float]) -> None:
    running = {**JOB, "status": "running", "progress": 0.5}
    done = {**JOB, "status": "succeeded", "progress": 1.0}
    client, seen = scripted(
        [
            httpx.Response(200, json=JOB, headers={"etag": '"q"'}),
            httpx.Response(200, json=running, headers={"etag": '"r"'}),
            httpx.Response(304, headers={"etag": '"r"'}),
            httpx.Response(200, json=done, headers={"etag": '"d"'}),
        ]
    )
    progress: list[str] = []
    job = client.wait("j1", on_progress=lambda j: progress.append(j.status))
    assert job.status == "succeeded"
    assert progress == ["queued", "running", "succeeded"]
    assert [r.headers.get("if-none-match") for r in seen] == [None, '"q"', '"r"', '"r"']


def test_wait_gives_up_at_its_timeout(monkeypatch: pytest.MonkeyPatch) -> None:
    clock = iter(float(t) for t in range(0, 1000, 5))
    monkeypatch.setattr(client_module.time, "monotonic", lambda: next(clock))
    monkeypatch.setattr(client_module.time, "sleep", lambda _s: None)
    running = httpx.Response(200, json={**JOB, "status": "running"}, headers={"etag": '"a"'})
    client, _ = scripted([running] * 50)
    with pytest.raises(WaitTimeoutError) as late:
        client.wait("j1", timeout=12)
    assert late.value.job.status == "running"
    assert isinstance(late.value, TimeoutError)


def test_upload_streams_a_multipart_body_with_progress(tmp_path: Any, sleeps: list[float]) -> None:
    data = bytes(range(256)) * 4096  # 1 MiB: several chunks
    path = tmp_path / 'we"ird name.npz'
    path.write_bytes(data)
    clip = {
        "id": "c1",
        "format": "npz",
        "frames": 8,
        "fps": 30.0,
        "width": 16,
        "height": 16,
        "has_depth": False,
        "size_bytes": len(data),
        "created_at": "2026-01-01T00:00:00+00:00",
    }
    client, seen = scripted([httpx.Response(201, json=clip)])
    calls: list[tuple[int, int]] = []
    assert client.upload_clip(path, progress=lambda a, b: calls.append((a, b))).id == "c1"
    request = seen[0]
    body = request.content
    assert int(request.headers["content-length"]) == len(body) == calls[-1][0] == calls[-1][1]
    assert len(calls) > 4
    boundary = request.headers["content-type"].split("boundary=")[1]
    head, _, rest = body.partition(b"\r\n\r\n")
    assert head.startswith(f"--{boundary}\r\n".encode())
    assert b'name="file"; filename="we%22ird name.npz"' in head
    assert rest == data + f"\r\n--{boundary}--\r\n".encode()
    assert request.headers["idempotency-key"]


def test_client_and_async_client_cover_every_operation() -> None:
    """Each spec operation has a method of both clients (the mapping itself is checked against the spec
    in tests/contract/test_client_spec.py)."""
    from eigenscope_client import OPERATIONS, AsyncClient

    for method in OPERATIONS.values():
        assert callable(getattr(Client, method)), method
        assert callable(getattr(AsyncClient, method)), method


def _names(fn: Callable[..., Any]) -> list[str]:
    import inspect

    return list(inspect.signature(fn).parameters)


def test_async_methods_take_the_same_arguments() -> None:
    from eigenscope_client import AsyncClient

    for name in dir(Client):
        if name.startswith("_") or name in ("close",):
            continue
        if callable(getattr(Client, name)) and hasattr(AsyncClient, name):
            assert _names(getattr(Client, name)) == _names(getattr(AsyncClient, name)), name
