"""The hardening review's findings against real processes: ``eigenscope serve`` over real HTTP, SQLite and
PostgreSQL job stores. Memory is read from ``/proc`` (the API process's peak resident set), never
inferred from timings."""

from __future__ import annotations

import base64
import json
import socket
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import service_harness as h
from fastapi.testclient import TestClient

from backend.settings import Settings
from service.app import create_app
from tests.unit.clipio.bombs import npz_bomb, png_bomb_zip
from tests.unit.service.test_hardening import BrokenQueue, check_non_finite_refused

pytestmark = [pytest.mark.integration, pytest.mark.slow]

KEY = "hardening-live-key-0123456789"
AUTH = {"Authorization": f"Bearer {KEY}"}
IDLE_S = 2.0


@pytest.fixture(scope="module")
def hardened(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """``eigenscope serve`` with a key, a 2 s body idle timeout and room for 64 uploads at once."""
    service = h.start_embedded(
        tmp_path_factory.mktemp("hardened"),
        api_keys=KEY,
        max_upload_mb="64",
        body_idle_timeout_s=str(IDLE_S),
        max_uploads_in_flight="64",
    )
    service.client.headers.update(AUTH)
    yield service
    service.stop()


def descendants(pid: int) -> list[int]:
    found = []
    for child in h.children_of(pid):
        found.append(child)
        found.extend(descendants(child))
    return found


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def api_pid(service: h.LiveService) -> int:
    return next(p for p in descendants(service.procs[0].pid) if "uvicorn" in cmdline(p))


def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no VmHWM for {pid}")


def uploads_left(service: h.LiveService) -> list[Path]:
    return list((service.data_dir / "tmp").glob("upload-*"))


def test_bombs_are_refused_at_upload(hardened: h.LiveService, tmp_path: Path) -> None:
    """Both bombs of the review are 413 at upload (they were accepted, then cost a worker 3.9 GB and
    2.8 GB); no job can be made of them and nothing is left on disk."""
    for path, message in (
        (png_bomb_zip(tmp_path / "frames.zip"), "declares 16000x16000 pixels"),
        (npz_bomb(tmp_path / "bomb.npz"), "decompression bomb"),
    ):
        response = hardened.upload(path)
        assert response.status_code == 413, response.text
        problem = response.json()
        assert problem["type"].endswith("/clip-too-large")
        assert message in problem["detail"]
        assert str(hardened.data_dir) not in problem["detail"]
    assert uploads_left(hardened) == []
    assert hardened.client.get("/v1/jobs").json()["items"] == []


@pytest.mark.parametrize("store", ["sqlite", "postgresql"])
def test_non_finite_numbers_and_cursors_on_both_stores(store: str, tmp_path: Path, truth_clip: Any) -> None:
    """`force_n: Infinity` was 202 (and GET showed null) on SQLite and a 500 on PostgreSQL; an absurd
    cursor was a 500 on both."""

    def run(url: str | None) -> None:
        settings = Settings(data_dir=tmp_path / "data", database_url=url)
        app = create_app(settings)
        app.state.ctx.queue = BrokenQueue()
        with TestClient(app) as client, truth_clip[0].open("rb") as fh:
            clip = client.post("/v1/clips", files={"file": ("spring.npz", fh)})
            assert clip.status_code == 201, clip.text
            check_non_finite_refused(client, clip.json()["id"], {})
            for seq in ("9" * 40, "9" * 19, "0"):
                cursor = base64.urlsafe_b64encode(f"s{seq}".encode()).decode()
                response = client.get("/v1/jobs", params={"cursor": cursor})
                assert response.status_code == 422, (seq, response.text)
            ok = client.post("/v1/jobs", json={"clip_id": clip.json()["id"]})
            assert ok.status_code == 202, ok.text
            page = client.get("/v1/jobs", params={"limit": 1}).json()
            assert [j["id"] for j in page["items"]] == [ok.json()["id"]]

    if store == "sqlite":
        run(None)
    else:
        with h.postgres_database() as url:
            run(url)


def test_64_mb_json_body_is_413_without_growing_the_api(hardened: h.LiveService, truth_clip: Any) -> None:
    """A 400 MB body was accepted after 12 s and left the API 400 MB larger: now a body over the cap is
    answered 413 and the API's peak resident set does not grow by the body."""
    clip_id = hardened.upload(truth_clip[0]).json()["id"]
    pid = api_pid(hardened)
    before = peak_rss_mb(pid)
    body = json.dumps({"clip_id": clip_id}).encode() + b" " * (64 * 1024 * 1024)  # valid JSON
    response = hardened.client.post("/v1/jobs", content=body, headers={"content-type": "application/json"})
    assert response.status_code == 413, response.text[:500]
    assert response.json()["type"].endswith("/body-too-large")
    after = peak_rss_mb(pid)
    print(f"\nHARDENING 64 MB JSON body: 413, API peak resident {before:.0f} -> {after:.0f} MB")
    assert after - before < 16, (before, after)
    assert hardened.client.get("/v1/jobs", params={"clip_id": clip_id}).json()["items"] == []


def test_stalled_uploads_are_dropped_and_their_files_removed(hardened: h.LiveService) -> None:
    """40 uploads that declare 10 MB, send 1 KB and stall are answered 408 (or closed) within the idle
    timeout, and their temporary files are removed while the clients still hold their sockets."""
    host, port = hardened.base_url.removeprefix("http://").split(":")
    head = b'--zz\r\nContent-Disposition: form-data; name="file"; filename="a.npz"\r\n\r\n'
    request = (
        (
            f"POST /v1/clips HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {KEY}\r\n"
            "Content-Type: multipart/form-data; boundary=zz\r\nContent-Length: 10000000\r\n\r\n"
        ).encode()
        + head
        + b"\0" * 1024
    )
    sockets = []
    try:
        for _ in range(40):
            s = socket.create_connection((host, int(port)), timeout=60)
            s.sendall(request)
            sockets.append(s)
        started = time.monotonic()
        answers = []
        for s in sockets:  # each is answered or closed by the server; the clients never send more
            data = b""
            while chunk := s.recv(65536):
                data += chunk
            answers.append(data.split(b"\r\n", 1)[0])
        released_s = time.monotonic() - started
        assert answers == [b"HTTP/1.1 408 Request Timeout"] * 40, set(answers)
        deadline = time.monotonic() + 10
        while uploads_left(hardened) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert uploads_left(hardened) == []
        print(f"\nHARDENING 40 stalled uploads: all 408 and closed {released_s:.1f} s after the last sent")
    finally:
        for s in sockets:
            s.close()
    assert hardened.client.get("/healthz").status_code == 200


def test_api_and_workers_never_see_plain_keys(hardened: h.LiveService) -> None:
    serve = hardened.procs[0].pid
    children = descendants(serve)
    assert len(children) >= 3  # uvicorn, the Celery worker and its pool process
    for pid in children:
        environ = Path(f"/proc/{pid}/environ").read_bytes()
        assert KEY.encode() not in environ, cmdline(pid)
        variables = dict(v.split(b"=", 1) for v in environ.split(b"\0") if b"=" in v)
        assert b"EIGENSCOPE_API_KEYS" not in variables
        digests = Path(variables[b"EIGENSCOPE_API_KEYS_FILE"].decode())
        assert stat.S_IMODE(digests.stat().st_mode) == 0o600
        assert KEY not in digests.read_text()
        assert any(line.startswith("sha256:") for line in digests.read_text().splitlines())
    assert hardened.client.get("/v1/jobs").status_code == 200  # the API knows the key by its digest
    assert hardened.client.get("/v1/jobs", headers={"Authorization": "Bearer x" * 3}).status_code == 401


def test_zipped_ros2_bag_of_25_mb_is_accepted(hardened: h.LiveService, tmp_path: Path) -> None:
    """The upload check unpacked zipped bags under a 16 MiB file-size cap (`File too large`); it now reads
    them under the analysis's caps, in the data directory."""
    from workers.pipeline.clipio.bag_writer import write_ros2_zip

    frames = 116
    rgb = np.random.default_rng(5).integers(0, 255, (frames, 240, 320, 3), dtype=np.uint8)
    stamps = 1_700_000_000_000_000_000 + np.arange(frames, dtype=np.int64) * 33_333_333
    path = write_ros2_zip(
        tmp_path / "bag.zip", rgb, stamps_ns=stamps, intrinsics=(300.0, 300.0, 160.0, 120.0)
    )
    assert path.stat().st_size > 25 * 1024 * 1024
    response = hardened.upload(path)
    assert response.status_code == 201, response.text
    clip = response.json()
    assert (clip["format"], clip["frames"], clip["width"], clip["height"]) == ("ros2-bag", frames, 320, 240)
    assert list((hardened.data_dir / "tmp").iterdir()) == []
    print(f"\nHARDENING zipped ROS 2 bag of {path.stat().st_size / 2**20:.1f} MiB: accepted")


def test_job_over_the_memory_budget_fails_once_in_a_real_worker(
    tmp_path: Path, truth_clip: tuple[Path, Any]
) -> None:
    """The worker applies EIGENSCOPE_JOB_MEMORY_MB: a budget below what the worker already uses fails the
    job at once with `resources-exhausted`, one attempt, and the worker lives on."""
    service = h.start_embedded(tmp_path, job_memory_mb="64")
    try:
        clip_id = service.upload(truth_clip[0]).json()["id"]
        job_id = service.client.post("/v1/jobs", json={"clip_id": clip_id}).json()["id"]
        job = service.wait_job(job_id)
        assert (job["status"], job["attempts"]) == ("failed", 1), job
        assert job["error"]["type"].endswith("/resources-exhausted")
        assert "EIGENSCOPE_JOB_MEMORY_MB" in job["error"]["detail"]
        assert service.procs[0].alive()
    finally:
        service.stop()
