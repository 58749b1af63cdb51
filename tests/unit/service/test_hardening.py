"""The hardening review's findings, in-process (TestClient): bounded and finite JSON, cursors, readiness
without exception text, the metrics token, throttled failed authentication, bounded uploads in flight,
problems without server paths, and the safety checks of ``eigenscope serve``."""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.errors import InvalidClipError, QuotaExceededError, redact_paths
from backend.settings import Settings
from backend.store import NewClip, NewJob
from backend.strict_json import NonFiniteNumberError, strict_json_loads
from service.app import create_app
from service.auth import FailedAuthLimiter
from tests.unit.service.helpers import make_client

KEY = "hardening-key-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {KEY}"}


class BrokenQueue:
    """A broker that fails with text naming its host (which must not reach a client)."""

    def publish(self, job_id: str) -> None:
        raise ConnectionError("Error 111 connecting to secret-broker.internal:6379. Connection refused.")

    def ping(self) -> None:
        self.publish("")

    def held_job_ids(self) -> set[str] | None:
        return None

    def close(self) -> None:
        pass


def client_for(settings: Settings) -> TestClient:
    return make_client(settings, BrokenQueue())


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with client_for(settings) as c:
        yield c


def upload(client: TestClient, path: Path, headers: dict[str, str] | None = None) -> dict[str, Any]:
    with path.open("rb") as fh:
        response = client.post("/v1/clips", files={"file": (path.name, fh)}, headers=headers or {})
    assert response.status_code == 201, response.text
    body: dict[str, Any] = response.json()
    return body


NON_FINITE_BODIES = [
    '{"clip_id": "%s", "excitation": {"type": "step_release", "force_n": Infinity}}',
    '{"clip_id": "%s", "excitation": {"type": "step_release", "force_n": 1e309}}',
    '{"clip_id": "%s", "excitation": {"type": "step_release", "force_n": -Infinity}}',
    '{"clip_id": "%s", "excitation": {"type": "impulse", "impulse_ns": NaN}}',
    '{"clip_id": "%s", "excitation": {"type": "step_release", "force_n": 5, "point_px": [NaN, Infinity]}}',
    '{"clip_id": "%s", "parameters": {"fps": 1e400}}',
    '{"clip_id": "%s", "parameters": {"frames": 1e309}}',
    '{"clip_id": "%s", "excitation": {"type": "step_release", "force_n": 5, "object_id": 1%s}}',
]


def check_non_finite_refused(client: TestClient, clip_id: str, headers: dict[str, str]) -> None:
    """Every non-finite or overflowing number is a 422 problem, and no job is created."""
    for template in NON_FINITE_BODIES:
        body = template % ((clip_id, "0" * 30) if template.count("%s") == 2 else clip_id)
        response = client.post(
            "/v1/jobs", content=body, headers={**headers, "content-type": "application/json"}
        )
        assert response.status_code == 422, (body, response.status_code, response.text)
        assert response.headers["content-type"] == "application/problem+json"
        assert response.json()["status"] == 422
        assert response.json()["errors"], body
    assert client.get("/v1/jobs", headers=headers).json()["items"] == []


def test_non_finite_numbers_are_422(client: TestClient, small_clip: Path) -> None:
    check_non_finite_refused(client, upload(client, small_clip)["id"], {})


def test_store_refuses_non_finite_json(client: TestClient) -> None:
    """Defence in depth: a non-finite number never reaches a JSON column (PostgreSQL refused it with a
    500; SQLite stored it and served it back as null)."""
    store = client.app.state.ctx.store  # type: ignore[attr-defined]
    store.add_clip(NewClip(clip_id="c1", filename="a.npz", path="clips/c1/clip.npz", info={}, size_bytes=1))
    with pytest.raises(Exception, match="Out of range float values are not JSON compliant"):
        store.create_job(NewJob(clip_id="c1", excitation=None, parameters={"fps": float("inf")}))


def test_strict_json() -> None:
    assert strict_json_loads(b'{"a": [1.5, -2, 9223372036854775807, 1e308]}') == {
        "a": [1.5, -2, 9223372036854775807, 1e308]
    }
    for text in ("NaN", "[Infinity]", "-Infinity", "1e309", "-1e400", "9223372036854775808", "-" + "9" * 40):
        with pytest.raises(NonFiniteNumberError):
            strict_json_loads(text)


def test_json_body_over_the_cap_is_413(tmp_path: Path, small_clip: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", max_json_body_kb=64, max_job_body_kb=64)
    with client_for(settings) as client:
        clip_id = upload(client, small_clip)["id"]
        padded = json.dumps({"clip_id": clip_id}) + " " * (65 * 1024)  # valid JSON, over the cap
        response = client.post("/v1/jobs", content=padded, headers={"content-type": "application/json"})
        assert response.status_code == 413
        assert response.headers["content-type"] == "application/problem+json"
        assert response.json()["type"].endswith("/body-too-large")
        # A job request has a cap of its own (it may carry a force log), named in the answer.
        assert "EIGENSCOPE_MAX_JOB_BODY_KB" in response.json()["detail"]
        stream = client.post("/v1/streams", content=b"{}" + b" " * (65 * 1024))
        assert stream.status_code == 413
        assert "EIGENSCOPE_MAX_JSON_BODY_KB" in stream.json()["detail"]
        # Any content type, and bodies without a Content-Length (streamed in chunks), are capped too.
        chunks = iter([b"{" + b" " * 40_000, b" " * 40_000 + b"}"])
        streamed = client.post("/v1/jobs", content=chunks, headers={"content-type": "text/plain"})
        assert streamed.status_code == 413
        assert client.get("/v1/jobs").json()["items"] == []
        # Under the cap all is as before.
        ok = client.post(
            "/v1/jobs", content=json.dumps({"clip_id": clip_id}), headers={"content-type": "application/json"}
        )
        assert ok.status_code == 202, ok.text


@pytest.mark.parametrize("seq", ["9" * 40, "99999999999999999999", "0", "-5", "1.5", "1e3", " 7", "\u0661"])
def test_absurd_cursor_is_422(client: TestClient, seq: str) -> None:
    cursor = base64.urlsafe_b64encode(("s" + seq).encode()).decode().rstrip("=")
    response = client.get("/v1/jobs", params={"cursor": cursor})
    assert response.status_code == 422, response.text
    assert response.json()["type"].endswith("/invalid-cursor")


def test_readyz_names_the_component_without_its_error(client: TestClient) -> None:
    ready = client.get("/readyz")
    assert ready.status_code == 503
    assert ready.json()["checks"] == {"database": "ok", "broker": "failed", "storage": "ok"}
    assert "secret-broker" not in ready.text
    assert "Connection" not in ready.text


def test_metrics_token(tmp_path: Path) -> None:
    open_server = Settings(data_dir=tmp_path / "open")
    with client_for(open_server) as client:
        assert client.get("/metrics").status_code == 200  # no keys, no token: open, as before
    keyed = Settings(data_dir=tmp_path / "keyed", api_keys=KEY)
    with client_for(keyed) as client:
        refused = client.get("/metrics", headers=AUTH)  # an API key is not enough: counts span tenants
        assert refused.status_code == 401
        assert "EIGENSCOPE_METRICS_TOKEN" in refused.json()["detail"]
    token = "metrics-token-0123456789"
    with client_for(Settings(data_dir=tmp_path / "token", api_keys=KEY, metrics_token=token)) as client:
        assert client.get("/metrics").status_code == 401
        assert client.get("/metrics", headers={"Authorization": "Bearer wrong"}).status_code == 401
        scraped = client.get("/metrics", headers={"Authorization": f"Bearer {token}"})
        assert scraped.status_code == 200
        assert "eigenscope_jobs" in scraped.text


def test_failed_authentication_is_throttled(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEY, auth_failures_per_window=5)
    with client_for(settings) as client:
        for _ in range(3):  # no key at all is not a guess: never throttled
            assert client.get("/v1/jobs").status_code == 401
        for i in range(5):
            wrong = client.get("/v1/jobs", headers={"Authorization": f"Bearer guess-{i:020d}"})
            assert wrong.status_code == 401
        throttled = client.get("/v1/jobs", headers={"Authorization": "Bearer guess-again-00000000"})
        assert throttled.status_code == 429
        assert throttled.headers["content-type"] == "application/problem+json"
        assert 1 <= int(throttled.headers["retry-after"]) <= 60
        assert throttled.json()["type"].endswith("/too-many-failed-authentications")
        # Even the right key gets nothing from this client until the window has passed: a lucky guess
        # must look like any other.
        assert client.get("/v1/jobs", headers=AUTH).status_code == 429
        assert client.get("/healthz").status_code == 200


def test_limiter_is_per_client_and_forgets() -> None:
    limiter = FailedAuthLimiter(limit=2, window_s=0.2)
    limiter.failed("a")
    limiter.failed("a")
    with pytest.raises(QuotaExceededError):
        limiter.check("a")
    limiter.check("b")
    import time

    time.sleep(0.25)
    limiter.check("a")  # the window has passed


def test_uploads_in_flight_are_bounded(tmp_path: Path, small_clip: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", max_uploads_in_flight=2)
    with client_for(settings) as client:
        ctx = client.app.state.ctx  # type: ignore[attr-defined]
        ctx.uploads_in_flight = 2  # two uploads are being received
        with small_clip.open("rb") as fh:
            busy = client.post("/v1/clips", files={"file": ("a.npz", fh)})
        assert busy.status_code == 503
        assert busy.json()["type"].endswith("/too-many-uploads")
        assert int(busy.headers["retry-after"]) > 0
        ctx.uploads_in_flight = 1
        upload(client, small_clip)
        assert ctx.uploads_in_flight == 1  # counted down again after the upload
        assert list((ctx.storage.root / "tmp").glob("upload-*")) == []


def test_stalled_upload_is_408_and_leaves_nothing(tmp_path: Path) -> None:
    """The body idle timeout, on the upload route, through the ASGI app (the live test sends 40)."""
    settings = Settings(data_dir=tmp_path / "data", body_idle_timeout_s=0.3)
    app = create_app(settings)
    sent: list[dict[str, Any]] = []

    async def run() -> None:
        head = b'--zz\r\nContent-Disposition: form-data; name="file"; filename="a.npz"\r\n\r\n' + b"\0" * 1024
        messages = [{"type": "http.request", "body": head, "more_body": True}]

        async def receive() -> dict[str, Any]:
            if messages:
                return messages.pop(0)
            await asyncio.sleep(3600)  # the client stalls
            raise AssertionError("not reached")

        async def send(message: dict[str, Any]) -> None:
            sent.append(message)

        scope = {
            "type": "http",
            "asgi": {"version": "3.0"},
            "http_version": "1.1",
            "method": "POST",
            "path": "/v1/clips",
            "raw_path": b"/v1/clips",
            "root_path": "",
            "scheme": "http",
            "query_string": b"",
            "headers": [
                (b"content-type", b"multipart/form-data; boundary=zz"),
                (b"content-length", b"10000000"),
            ],
            "client": ("127.0.0.1", 1234),
            "server": ("127.0.0.1", 8000),
        }
        await asyncio.wait_for(app(scope, receive, send), 30)

    with TestClient(app):  # runs the lifespan (storage, tables)
        asyncio.run(run())
        start = next(m for m in sent if m["type"] == "http.response.start")
        assert start["status"] == 408
        assert (b"connection", b"close") in start["headers"]
        body = json.loads(b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body"))
        assert body["type"].endswith("/request-timeout")
        assert list((settings.data_path / "tmp").iterdir()) == []
        assert app.state.ctx.uploads_in_flight == 0


def test_problems_carry_no_server_paths(tmp_path: Path) -> None:
    error = InvalidClipError(f"cannot read {tmp_path}/data/tmp/upload-1.d/clip.npz: [Errno 5] I/O error")
    detail = error.problem(instance="/v1/clips")["detail"]
    assert str(tmp_path) not in detail
    assert "clip.npz" in detail
    assert redact_paths("upload it with POST /v1/clips; see https://eigenscope.dev/problems/x") == (
        "upload it with POST /v1/clips; see https://eigenscope.dev/problems/x"
    )
    assert redact_paths("No such file: '/srv/eigenscope/var/clips/ab/clip.mp4'") == "No such file: 'clip.mp4'"


def test_serve_refuses_an_open_api_on_a_public_address(tmp_path: Path) -> None:
    from eigenscope.cli import UsageError
    from eigenscope.commands.serve import check_exposure

    open_settings = Settings(data_dir=tmp_path)
    for host in ("0.0.0.0", "::", "192.0.2.7", "eigenscope.example"):
        with pytest.raises(UsageError, match="without API keys"):
            check_exposure(host, open_settings, keys=False)
    for host in ("127.0.0.1", "localhost", "::1", "[::1]", "127.0.0.2"):
        check_exposure(host, open_settings, keys=False)
    check_exposure("0.0.0.0", open_settings, keys=True)
    check_exposure("0.0.0.0", Settings(data_dir=tmp_path, allow_open_api=True), keys=False)
    # In a container the API listens on 0.0.0.0; where compose publishes the port decides.
    check_exposure("0.0.0.0", Settings(data_dir=tmp_path, published_host="127.0.0.1"), keys=False)
    with pytest.raises(UsageError):
        check_exposure("0.0.0.0", Settings(data_dir=tmp_path, published_host="0.0.0.0"), keys=False)


def test_serve_exits_with_one_line_on_an_open_public_bind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import subprocess
    import sys

    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("EIGENSCOPE_")}
    env["EIGENSCOPE_DATA_DIR"] = str(tmp_path / "data")
    run = subprocess.run(
        [sys.executable, "-m", "eigenscope", "serve", "--host", "0.0.0.0", "--port", "18999"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
        check=False,
    )
    assert run.returncode == 2
    assert "without API keys" in run.stderr
    assert "Traceback" not in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "data").exists()  # refused before anything was created


def test_uvicorn_limits_are_set_on_purpose(tmp_path: Path) -> None:
    """Every limit ``eigenscope serve`` passes is an option uvicorn's command line accepts, with the
    settings' values."""
    from uvicorn.main import main as uvicorn_main

    from eigenscope.commands.serve import uvicorn_limits

    settings = Settings(
        data_dir=tmp_path, http_timeout_keep_alive_s=7, http_limit_concurrency=99, http_backlog=77
    )
    args = uvicorn_limits(settings)
    context = uvicorn_main.make_context("uvicorn", ["service.app:create_app", "--factory", *args])
    assert context.params["timeout_keep_alive"] == 7
    assert context.params["limit_concurrency"] == 99
    assert context.params["backlog"] == 77
    assert context.params["h11_max_incomplete_event_size"] == settings.http_max_header_kb * 1024
    # Frames are images: compressing WebSocket messages would cost a live stream the CPU it needs.
    assert context.params["ws_per_message_deflate"] is False


def test_the_server_keeps_an_idle_connection_longer_than_clients_and_proxies_do(tmp_path: Path) -> None:
    """A server that closes an idle keep-alive connection first races the client that reuses it: the
    request meets a reset (httpx.ReadError) instead of an answer. uvicorn's 5 s equals httpx's own
    expiry, and a load run lost a request to it; the default outlasts httpx and common proxies (60 s)."""
    import httpx

    default = Settings(data_dir=tmp_path).http_timeout_keep_alive_s
    assert default > (httpx.Limits().keepalive_expiry or 0.0)
    assert default > 60


def test_large_bodies_read_at_once_are_bounded_and_the_rest_told_to_retry() -> None:
    """A job request with a force log may be 20 MiB and take several times that while it is parsed: at most
    EIGENSCOPE_MAX_LARGE_BODIES_IN_FLIGHT such bodies are read and handled at once; one more is answered 503
    with Retry-After (declared or sent in chunks), small bodies pass meanwhile, and a freed place is taken
    again."""
    import asyncio

    import httpx

    from service.bodies import BodyCap, BodyLimits

    release = asyncio.Event()
    entered: list[int] = []

    async def app(scope, receive, send):  # type: ignore[no-untyped-def]
        body = b""
        while True:
            message = await receive()
            body += message.get("body", b"")
            if not message.get("more_body"):
                break
        entered.append(len(body))
        if len(body) > 1024:
            await release.wait()
        await send(
            {"type": "http.response.start", "status": 200, "headers": [(b"content-type", b"text/plain")]}
        )
        await send({"type": "http.response.body", "body": b"ok"})

    limits = BodyLimits(
        app,
        max_body_bytes=1024,
        idle_timeout_s=5,
        route_caps={("POST", "/big"): BodyCap(1 << 20, "X")},
        max_large_bodies=2,
    )

    async def chunks(n: int):  # type: ignore[no-untyped-def]
        for _ in range(n):
            yield b"x" * 1000

    async def scenario() -> None:
        transport = httpx.ASGITransport(app=limits)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            big = b"x" * 50_000
            first = asyncio.create_task(client.post("/big", content=big))
            second = asyncio.create_task(client.post("/big", content=chunks(40)))
            while len(entered) < 2:
                await asyncio.sleep(0.01)
            assert limits.large_in_flight == 2
            third = await client.post("/big", content=big)
            assert third.status_code == 503
            assert third.headers["retry-after"] == "1"
            assert third.headers["content-type"] == "application/problem+json"
            assert third.json()["type"].endswith("/too-many-large-requests")
            assert "EIGENSCOPE_MAX_LARGE_BODIES_IN_FLIGHT" in third.json()["detail"]
            chunked = await client.post("/big", content=chunks(40))
            assert chunked.status_code == 503
            small = await client.post("/big", content=b"{}")
            assert small.status_code == 200  # under the general cap: no place needed
            release.set()
            assert (await first).status_code == 200
            assert (await second).status_code == 200
            assert limits.large_in_flight == 0
            again = await client.post("/big", content=big)
            assert again.status_code == 200

    asyncio.run(scenario())
