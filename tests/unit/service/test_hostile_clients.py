"""What a hostile but careful client found after the first hardening pass (issue 27), in-process."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.settings import Settings
from tests.unit.service.helpers import make_client, upload

KEY_A = "alpha-key-0123456789abcdef"
KEY_B = "bravo-key-0123456789abcdef"
A = {"Authorization": f"Bearer {KEY_A}"}
B = {"Authorization": f"Bearer {KEY_B}"}


@pytest.fixture
def keyed(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path / "data", api_keys=f"{KEY_A},{KEY_B}")
    with make_client(settings) as client:
        yield client


@pytest.fixture(scope="module")
def ts_clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from workers.pipeline.clipio import writers as w

    rgb = np.random.default_rng(1).integers(0, 255, (20, 48, 64, 3), dtype=np.uint8)
    return w.write_video(tmp_path_factory.mktemp("ts") / "a.ts", rgb, fps=30.0, codec="mpeg4")


def _pointers(target: Path, relative: str | None = None) -> dict[str, str]:
    """HLS and concat lists naming ``target`` by absolute URL (and by ``relative`` path when given)."""
    hls = "#EXTM3U\n#EXT-X-TARGETDURATION:10\n#EXTINF:10,\n{}\n#EXT-X-ENDLIST\n"
    forms = {
        "abs.m3u8": hls.format(f"file://{target}"),
        "lying.mp4": hls.format(f"file://{target}"),
        "list.txt": f"ffconcat version 1.0\nfile 'file:{target}'\n",
    }
    if relative is not None:
        forms["relative.m3u8"] = hls.format(relative)
        forms["relative.ffconcat"] = f"ffconcat version 1.0\nfile '{relative}'\n"
    return forms


def test_playlists_cannot_read_the_servers_or_another_tenants_files(
    keyed: TestClient, ts_clip: Path, tmp_path: Path
) -> None:
    """Item 1: HLS and concat lists naming a file outside the data directory, or another tenant's clip
    (by absolute and by relative path), are refused with 422, and nothing is recorded."""
    ctx = keyed.app.state.ctx  # type: ignore[attr-defined]
    theirs = upload(keyed, ts_clip, A, name="a.ts").json()
    stored = ctx.storage.clip_path(ctx.store.find_clip(theirs["id"]).path)
    assert stored.is_file()
    outside = tmp_path / "outside" / "secret.ts"
    outside.parent.mkdir()
    outside.write_bytes(ts_clip.read_bytes())
    # The upload is validated in tmp/upload-<random>.d/: two levels below the data directory.
    relative = f"../../clips/{theirs['id']}/{stored.name}"
    forms = {**_pointers(stored, relative), **{f"out-{k}": v for k, v in _pointers(outside).items()}}
    for name, text in forms.items():
        path = tmp_path / name
        path.write_text(text)
        response = upload(keyed, path, B, name=name)
        assert response.status_code == 422, (name, response.status_code, response.text)
        problem = response.json()
        assert problem["type"].endswith("/invalid-clip"), (name, problem)
        assert "names other files" in problem["detail"], (name, problem)
        assert str(stored) not in problem["detail"]
    assert keyed.get("/v1/clips", headers=B).json()["items"] == []
    assert keyed.get(f"/v1/clips/{theirs['id']}", headers=B).status_code == 404


def test_the_stored_file_name_never_comes_from_the_client(
    keyed: TestClient, ts_clip: Path, small_clip: Path
) -> None:
    """Item 1: the stored clip's name and extension are the server's, from the content."""
    ctx = keyed.app.state.ctx  # type: ignore[attr-defined]
    for path, name, suffix in (
        (small_clip, "x.m3u8", ".npz"),
        (small_clip, "../../evil.txt", ".npz"),
        (ts_clip, "clip.mp4", ""),
        (ts_clip, "a.ts", ""),
    ):
        clip = upload(keyed, path, A, name=name).json()
        record = ctx.store.find_clip(clip["id"])
        assert record.path == f"clips/{clip['id']}/clip{suffix}", (name, record.path)
        assert clip["filename"] == Path(name).name  # shown as the client named it, never used as a path


# Item 3: one authentication path, one limiter, for HTTP and the WebSocket --------------------------


def ws_status(client: TestClient, headers: dict[str, str], stream_id: str = "no-such-stream") -> int:
    """The status of the fatal error a stream's WebSocket answers with these headers."""
    with client.websocket_connect(f"/v1/streams/{stream_id}", headers=headers) as ws:
        message = ws.receive_json()
    assert message["type"] == "error", message
    assert message["fatal"] is True, message
    status: int = message["problem"]["status"]
    return status


def wrong(i: int) -> dict[str, str]:
    return {"Authorization": f"Bearer guess-{i:020d}"}


def limited(tmp_path: Path, **extra: object) -> TestClient:
    settings = Settings(
        data_dir=tmp_path / "data", api_keys=f"{KEY_A},{KEY_B}", auth_failures_per_window=5, **extra
    )
    return make_client(settings)


def test_wrong_keys_on_the_websocket_are_throttled_on_both_paths(tmp_path: Path) -> None:
    with limited(tmp_path) as client:
        assert client.get("/v1/jobs", headers=A).status_code == 200  # A's robot works from here
        assert [ws_status(client, wrong(i)) for i in range(8)] == [401] * 5 + [429] * 3
        assert client.get("/v1/jobs", headers=wrong(9)).status_code == 429
        # A valid key first seen from the throttled address is refused on both paths (a right guess
        # must look like any other) ...
        assert client.get("/v1/jobs", headers=B).status_code == 429
        assert ws_status(client, B) == 429
        # ... but the key already working from here is not locked out by another client's failures.
        assert client.get("/v1/jobs", headers=A).status_code == 200
        assert ws_status(client, A) == 404  # admitted: the stream does not exist


def test_wrong_keys_over_http_throttle_the_websocket(tmp_path: Path) -> None:
    with limited(tmp_path) as client:
        for i in range(5):
            assert client.get("/v1/jobs", headers=wrong(i)).status_code == 401
        assert ws_status(client, wrong(5)) == 429
        assert ws_status(client, B) == 429  # the valid key on the WebSocket, while throttled
        assert ws_status(client, {}) == 429


def test_without_the_known_key_exemption_every_key_waits(tmp_path: Path) -> None:
    with limited(tmp_path, auth_known_key_s=0) as client:
        assert client.get("/v1/jobs", headers=A).status_code == 200
        for i in range(5):
            assert ws_status(client, wrong(i)) == 401
        assert client.get("/v1/jobs", headers=A).status_code == 429
        assert ws_status(client, A) == 429


def test_forty_wrong_websocket_keys_at_the_default_limit(tmp_path: Path) -> None:
    """The issue's count: forty wrong keys on a stream's WebSocket were 40 x 401 and no 429."""
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEY_A)
    with make_client(settings) as client:
        statuses = [ws_status(client, wrong(i)) for i in range(40)]
    assert statuses.count(401) == settings.auth_failures_per_window
    assert statuses.count(429) == 40 - settings.auth_failures_per_window


# Item 10: forwarded headers only from configured proxies -------------------------------------------


def behind_proxy(tmp_path: Path, trusted: str) -> TestClient:
    """The app behind uvicorn's proxy-header handling, trusting ``trusted`` (as ``eigenscope serve``
    configures it from EIGENSCOPE_TRUSTED_PROXIES); the test client's peer is ``testclient``."""
    from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

    from service.app import create_app
    from tests.unit.service.helpers import RecordingQueue

    settings = Settings(data_dir=tmp_path / "data", api_keys=f"{KEY_A},{KEY_B}", auth_failures_per_window=5)
    app = create_app(settings)
    app.state.ctx.queue = RecordingQueue()
    return TestClient(ProxyHeadersMiddleware(app, trusted_hosts=trusted))  # type: ignore[arg-type]


def test_a_rotating_forwarded_header_from_an_untrusted_peer_is_throttled(tmp_path: Path) -> None:
    with behind_proxy(tmp_path, trusted="10.9.9.9") as client:
        statuses = [
            client.get("/v1/jobs", headers={**wrong(i), "X-Forwarded-For": f"203.0.113.{i}"}).status_code
            for i in range(12)
        ]
        assert statuses == [401] * 5 + [429] * 7
        assert client.get("/v1/jobs", headers={**B, "X-Forwarded-For": "198.51.100.7"}).status_code == 429


def test_clients_behind_a_trusted_proxy_are_counted_apart(tmp_path: Path) -> None:
    """Twenty wrong keys from one client behind the proxy lock out that client only."""
    with behind_proxy(tmp_path, trusted="testclient") as client:
        x, y = {"X-Forwarded-For": "203.0.113.1"}, {"X-Forwarded-For": "203.0.113.2"}
        for i in range(20):
            client.get("/v1/jobs", headers={**wrong(i), **x})
        assert client.get("/v1/jobs", headers={**wrong(99), **x}).status_code == 429
        assert client.get("/v1/jobs", headers={**B, **x}).status_code == 429
        assert client.get("/v1/jobs", headers={**B, **y}).status_code == 200  # never used before either
        assert client.get("/v1/jobs", headers={**A, **y}).status_code == 200


def test_serve_trusts_forwarded_headers_from_the_configured_proxies_only(tmp_path: Path) -> None:
    from uvicorn.main import main as uvicorn_main

    from eigenscope.commands.serve import uvicorn_limits

    for trusted in (None, "10.0.0.0/8,127.0.0.1"):
        args = uvicorn_limits(Settings(data_dir=tmp_path, trusted_proxies=trusted))
        params = uvicorn_main.make_context("uvicorn", ["service.app:create_app", "--factory", *args]).params
        assert params["proxy_headers"] is (trusted is not None)
        if trusted is not None:
            assert params["forwarded_allow_ips"] == trusted


# Items 6, 9 and 16: stops that stop, and nothing left of a crash -----------------------------------


def test_the_stream_worker_is_not_respawned_once_its_stop_has_begun(tmp_path: Path) -> None:
    """Item 6: the watcher slept, then respawned the stream worker without looking whether it was
    stopping; now no child starts after ``stop()`` and the watcher is joined."""
    import sys
    import time

    from eigenscope.commands.worker import StreamWorkerChild

    marker = tmp_path / "spawned"
    child = StreamWorkerChild("INFO")
    # A stand-in child that says it started, then exits at once (as a stream worker that crashed).
    child.cmd = [sys.executable, "-c", f"open({str(marker)!r}, 'a').write('x')"]
    child.start()
    deadline = time.monotonic() + 10
    while child.proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.7)  # the watcher has seen the exit and waits a second before it restarts it
    child.stop()
    assert not child._thread.is_alive()
    time.sleep(1.5)
    assert marker.read_text() == "x", "a child was started after stop()"


def test_abandoned_uploads_go_at_start_and_after_their_idle_timeout(tmp_path: Path) -> None:
    """Items 9 and 16: an upload a crashed API process left is removed when the API starts, any upload
    idle longer than a body may stall plus a validation may last by the sweep; a live one stays."""
    import os
    import subprocess
    import sys
    import time

    from backend.storage import Storage

    settings = Settings(data_dir=tmp_path / "data", body_idle_timeout_s=30, probe_timeout_s=120)
    storage = Storage(settings.data_path)
    storage.ensure()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    dead_pid = int(dead.stdout)
    host = storage.new_upload(1024).path.name.split("-")[1]
    tmp = storage.root / "tmp"
    crashed = tmp / f"upload-{host}-{dead_pid}-{'a' * 32}"
    crashed.write_bytes(b"x" * 4096)  # half received when its API process died
    validating = tmp / f"upload-{host}-{dead_pid}-{'b' * 32}.d"
    validating.mkdir()
    idle = tmp / f"upload-{'0' * 8}-1-{'c' * 32}"  # another host's, untouched for 5 minutes
    idle.write_bytes(b"y")
    os.utime(idle, (time.time() - 300, time.time() - 300))
    live = storage.new_upload(1024)  # this process's, being received
    live.write(b"z")
    with make_client(settings) as client:  # the API starts
        assert not crashed.exists()
        assert not validating.exists()
        client.app.state.ctx.sweep()  # type: ignore[attr-defined]
        assert not idle.exists()
        assert live.path.exists()
    live.discard()


def test_the_websocket_message_limit_follows_the_stream_frame_limit(tmp_path: Path) -> None:
    """Item 7: uvicorn ran with its default 16 MiB message limit whatever STREAM_MAX_FRAME_MB said."""
    from uvicorn.main import main as uvicorn_main

    from eigenscope.commands.serve import uvicorn_limits

    for frame_mb in (8, 32, 100):
        settings = Settings(data_dir=tmp_path, stream_max_frame_mb=frame_mb)
        args = uvicorn_limits(settings)
        params = uvicorn_main.make_context("uvicorn", ["service.app:create_app", "--factory", *args]).params
        assert params["ws_max_size"] == (frame_mb + settings.stream_message_margin_mb) * 2**20
        assert params["ws_max_size"] > 20 * 2**20  # a 20 MiB frame reaches the app, even at 8 MiB
        assert params["ws_max_queue"] == settings.stream_message_queue


# Item 11: storage quotas on what a tenant stores, before any byte is written -----------------------


@pytest.fixture
def one_mib_quota(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(
        data_dir=tmp_path / "data", api_keys=f"{KEY_A},{KEY_B}", max_stored_mb_per_key=1, max_upload_mb=64
    )
    with make_client(settings) as client:
        yield client


def over_quota(client: TestClient, clip: Path) -> str:
    """Make A hold more than its 1 MiB: a clip and a finished job's 2 MiB of images. Returns the clip."""
    from tests.unit.service.helpers import finish

    clip_id: str = upload(client, clip, A).json()["id"]
    job = client.post("/v1/jobs", json={"clip_id": clip_id}, headers=A).json()
    finish(client, job["id"], output=b"\x89PNG" + bytes(2 * 2**20))
    return clip_id


def test_a_key_over_its_storage_quota_creates_no_job_and_no_stream(
    one_mib_quota: TestClient, small_clip: Path
) -> None:
    """Item 11: only active jobs were counted, so a key holding 15.9 MiB with a 10 MiB quota still
    created jobs (202); streams made clips with no check at all."""
    client = one_mib_quota
    clip_id = over_quota(client, small_clip)
    refused = client.post("/v1/jobs", json={"clip_id": clip_id}, headers=A)
    assert refused.status_code == 429, refused.text
    assert refused.json()["type"].endswith("/storage-quota-exceeded")
    assert "retry-after" in refused.headers
    stream = client.post("/v1/streams", json={"width": 320, "height": 240}, headers=A)
    assert stream.status_code == 429, stream.text
    # Another key is not affected.
    theirs = upload(client, small_clip, B).json()["id"]
    assert client.post("/v1/jobs", json={"clip_id": theirs}, headers=B).status_code == 202


def chunked_upload(client: TestClient, total: int, headers: dict[str, str]) -> Any:
    """An upload whose body comes in 64 KiB chunks with no Content-Length."""
    boundary = "b0undary"
    head = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="big.npz"\r\n\r\n'
    ).encode()

    def body() -> Iterator[bytes]:
        yield head
        for _ in range(total // 65536):
            yield bytes(65536)
        yield f"\r\n--{boundary}--\r\n".encode()

    return client.post(
        "/v1/clips",
        content=body(),
        headers={**headers, "content-type": f"multipart/form-data; boundary={boundary}"},
    )


def test_an_upload_without_content_length_stops_at_the_quota(
    one_mib_quota: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Item 11: four concurrent 49 MB bodies without Content-Length wrote about 185 MB before their
    429s; now the bytes are counted as they arrive, with the key's other uploads."""
    from backend.storage import Storage

    ctx = one_mib_quota.app.state.ctx  # type: ignore[attr-defined]
    written: list[Any] = []
    original = Storage.new_upload

    def recording(self: Storage, *args: Any, **kwargs: Any) -> Any:
        sink = original(self, *args, **kwargs)
        written.append(sink)
        return sink

    monkeypatch.setattr(Storage, "new_upload", recording)
    refused = chunked_upload(one_mib_quota, 8 * 2**20, A)
    assert refused.status_code == 429, refused.text
    assert refused.json()["type"].endswith("/storage-quota-exceeded")
    assert written[-1].size <= 2**20  # never past the quota
    assert ctx.upload_reservations.held(_tenant(KEY_A)) == 0  # nothing counted once it is refused
    # Another upload of A's under way holds half the quota: the next one stops at the other half.
    ctx.upload_reservations.take(_tenant(KEY_A), 2**19, 2**20, lambda held: RuntimeError(held))
    assert chunked_upload(one_mib_quota, 4 * 2**20, A).status_code == 429
    assert written[-1].size <= 2**19
    assert ctx.upload_reservations.held(_tenant(KEY_A)) == 2**19
    assert list((ctx.storage.root / "tmp").glob("upload-*")) == []


def _tenant(key: str) -> str:
    from service.auth import key_digest, tenant_of_digest

    return tenant_of_digest(key_digest(key))
