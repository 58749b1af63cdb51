"""Keys and tenants, per-key limits, retention and half-written uploads, in-process (TestClient)."""

from __future__ import annotations

import hashlib
import io
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.errors import UnauthorizedError
from backend.settings import Settings
from service.auth import KeyConfigError, KeyRing, key_digest
from service.retention import cleanup
from tests.unit.service.helpers import finish, make_client, upload

KEY_A = "alpha-key-0123456789abcdef"
KEY_B = "bravo-key-0123456789abcdef"
A = {"Authorization": f"Bearer {KEY_A}"}
B = {"Authorization": f"Bearer {KEY_B}"}


@pytest.fixture
def keyed(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path / "data", api_keys=f"{KEY_A}, {KEY_B}", max_active_jobs_per_key=2)
    with make_client(settings) as client:
        yield client


def test_keys_are_required_on_v1_but_not_on_health(keyed: TestClient) -> None:
    for method, path in (
        ("get", "/v1/jobs"),
        ("get", "/v1/jobs/x"),
        ("get", "/v1/clips/x"),
        ("post", "/v1/jobs"),
    ):
        for headers in ({}, {"Authorization": "Bearer wrong-key-0123456789"}, {"Authorization": KEY_A}):
            response = keyed.request(method, path, headers=headers)
            assert response.status_code == 401, (method, path, headers)
            assert response.headers["content-type"] == "application/problem+json"
            assert response.headers["www-authenticate"].startswith("Bearer")
            assert response.json()["status"] == 401
    # Uploads are refused before the body is read.
    refused = keyed.post("/v1/clips", files={"file": ("a.npz", b"123")})
    assert refused.status_code == 401
    assert keyed.get("/healthz").status_code == 200
    assert keyed.get("/readyz").status_code == 200
    assert keyed.get("/v1/jobs", headers=A).status_code == 200
    assert keyed.get("/v1/jobs", headers={"Authorization": f"bearer  {KEY_B} "}).status_code == 200


def test_each_key_sees_only_its_own(keyed: TestClient, small_clip: Path) -> None:
    clip = upload(keyed, small_clip, A).json()
    job = keyed.post("/v1/jobs", json={"clip_id": clip["id"]}, headers=A).json()
    finish(keyed, job["id"])
    # B: 404 on A's ids, empty lists, no job on A's clip, no cancel or delete either.
    assert keyed.get(f"/v1/clips/{clip['id']}", headers=B).status_code == 404
    assert keyed.get(f"/v1/jobs/{job['id']}", headers=B).status_code == 404
    assert keyed.get(f"/v1/jobs/{job['id']}/artifacts/mask.png", headers=B).status_code == 404
    assert keyed.post(f"/v1/jobs/{job['id']}/cancel", headers=B).status_code == 404
    assert keyed.delete(f"/v1/clips/{clip['id']}", headers=B).status_code == 404
    assert keyed.get("/v1/jobs", headers=B).json()["items"] == []
    assert keyed.get("/v1/jobs", params={"clip_id": clip["id"]}, headers=B).json()["items"] == []
    stolen = keyed.post("/v1/jobs", json={"clip_id": clip["id"]}, headers=B)
    assert stolen.status_code == 422
    assert "does not exist" in stolen.json()["detail"]
    # A still has everything.
    assert keyed.get(f"/v1/clips/{clip['id']}", headers=A).status_code == 200
    assert [j["id"] for j in keyed.get("/v1/jobs", headers=A).json()["items"]] == [job["id"]]
    assert keyed.get(f"/v1/jobs/{job['id']}/artifacts/mask.png", headers=A).status_code == 200


def test_idempotency_keys_are_per_tenant(keyed: TestClient, small_clip: Path) -> None:
    clip_a = upload(keyed, small_clip, A).json()["id"]
    clip_b = upload(keyed, small_clip, B).json()["id"]
    same = {"Idempotency-Key": "job-1"}
    job_a = keyed.post("/v1/jobs", json={"clip_id": clip_a}, headers={**A, **same})
    job_b = keyed.post("/v1/jobs", json={"clip_id": clip_b}, headers={**B, **same})
    assert job_a.status_code == job_b.status_code == 202
    assert job_a.json()["id"] != job_b.json()["id"]
    again = keyed.post("/v1/jobs", json={"clip_id": clip_a}, headers={**A, **same})
    assert again.json()["id"] == job_a.json()["id"]


def test_active_job_limit_is_429_with_retry_after(keyed: TestClient, small_clip: Path) -> None:
    clip = upload(keyed, small_clip, A).json()["id"]
    ids = [keyed.post("/v1/jobs", json={"clip_id": clip}, headers=A).json()["id"] for _ in range(2)]
    over = keyed.post("/v1/jobs", json={"clip_id": clip}, headers=A)
    assert over.status_code == 429
    assert over.headers["content-type"] == "application/problem+json"
    assert int(over.headers["retry-after"]) >= 1
    assert "EIGENSCOPE_MAX_ACTIVE_JOBS_PER_KEY" in over.json()["detail"]
    # Another key is not affected; finishing a job frees a slot.
    clip_b = upload(keyed, small_clip, B).json()["id"]
    assert keyed.post("/v1/jobs", json={"clip_id": clip_b}, headers=B).status_code == 202
    finish(keyed, ids[0])
    assert keyed.post("/v1/jobs", json={"clip_id": clip}, headers=A).status_code == 202


def test_stored_bytes_limit_is_429(tmp_path: Path, small_clip: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", api_keys=KEY_A, max_stored_mb_per_key=1)
    size = small_clip.stat().st_size
    with make_client(settings) as client:
        fits = (1024 * 1024) // size
        for _ in range(fits):
            assert upload(client, small_clip, A).status_code == 201
        over = upload(client, small_clip, A)
        assert over.status_code == 429, over.text
        assert over.json()["type"].endswith("storage-quota-exceeded")
        assert "retry-after" in over.headers
        ctx = client.app.state.ctx  # type: ignore[attr-defined]
        assert len(list((ctx.storage.root / "clips").iterdir())) == fits
        assert list((ctx.storage.root / "tmp").glob("upload-*")) == []


def test_open_service_warns_in_its_log(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with (
        caplog.at_level(logging.WARNING, logger="service.app"),
        make_client(Settings(data_dir=tmp_path)) as c,
    ):
        assert c.get("/v1/jobs").status_code == 200
    assert "API is OPEN" in caplog.text


def test_keys_file_holds_keys_or_digests(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    keys.write_text(f"# lab\n{KEY_A}\nsha256:{key_digest(KEY_B)}  # robot\n\n")
    ring = KeyRing.from_settings(Settings(data_dir=tmp_path, api_keys_file=keys))
    assert ring.enabled
    assert ring.tenant(f"Bearer {KEY_A}") != ring.tenant(f"Bearer {KEY_B}")
    # Only digests are kept, and the tenant id reveals neither the key nor its digest.
    assert KEY_A not in repr(ring)
    assert all(hashlib.sha256(KEY_A.encode()).hexdigest() not in t for t in ring.tenants.values())
    with pytest.raises(UnauthorizedError):
        ring.tenant("Bearer nope-nope-nope-nope")
    keys.write_text("short\n")
    with pytest.raises(KeyConfigError, match="too short"):
        KeyRing.from_settings(Settings(data_dir=tmp_path, api_keys_file=keys))
    with pytest.raises(KeyConfigError, match="cannot read"):
        KeyRing.from_settings(Settings(data_dir=tmp_path, api_keys_file=tmp_path / "missing"))


def test_upload_names_are_never_paths(keyed: TestClient, small_clip: Path) -> None:
    clip = upload(keyed, small_clip, A, name="../../etc/\x1bpasswd.npz").json()
    assert clip["filename"] == "passwd.npz"
    ctx = keyed.app.state.ctx  # type: ignore[attr-defined]
    stored = [p.relative_to(ctx.storage.root).as_posix() for p in ctx.storage.root.rglob("*") if p.is_file()]
    assert f"clips/{clip['id']}/clip.npz" in stored
    assert not any("passwd" in p for p in stored)
    assert len(clip["id"]) == 32


def test_retention_removes_records_and_files_together(tmp_path: Path, small_clip: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", retention_s=60, orphan_grace_s=0)
    with make_client(settings) as client:
        ctx = client.app.state.ctx  # type: ignore[attr-defined]
        old_clip = upload(client, small_clip, {}).json()["id"]
        done = client.post("/v1/jobs", json={"clip_id": old_clip}).json()["id"]
        finish(client, done)
        busy_clip = upload(client, small_clip, {}).json()["id"]
        busy = client.post("/v1/jobs", json={"clip_id": busy_clip}).json()["id"]
        # Leftovers of a crash: files without records.
        (ctx.storage.root / "clips" / ("f" * 32)).mkdir()
        (ctx.storage.root / "jobs" / "deadbeef").mkdir()
        (ctx.storage.root / "jobs" / "deadbeef" / "mask.png").write_bytes(b"x")

        now = time.time()
        report = cleanup(ctx.store, ctx.storage, now=now + 1, orphan_grace_s=0)
        assert (report.jobs, report.clips, report.orphans) == (0, 0, 2)  # nothing expired yet
        report = cleanup(ctx.store, ctx.storage, now=now + 120, orphan_grace_s=0)
        assert (report.jobs, report.clips) == (1, 1)  # the running job and its clip stay
        assert client.get(f"/v1/jobs/{done}").status_code == 404
        assert client.get(f"/v1/clips/{old_clip}").status_code == 404
        assert client.get(f"/v1/jobs/{busy}").status_code == 200
        assert client.get(f"/v1/clips/{busy_clip}").status_code == 200
        assert sorted(p.name for p in (ctx.storage.root / "clips").iterdir()) == [busy_clip]
        assert list((ctx.storage.root / "jobs").iterdir()) == []
        # Once the job is over, both go.
        client.post(f"/v1/jobs/{busy}/cancel")
        report = cleanup(ctx.store, ctx.storage, now=now + 120, orphan_grace_s=0)
        assert (report.jobs, report.clips) == (1, 1)
        assert list((ctx.storage.root / "clips").iterdir()) == []
        assert ctx.store.count_jobs_by_status() == {}


def test_failed_record_write_leaves_no_file(
    tmp_path: Path, small_clip: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from backend.errors import DatabaseUnavailableError

    with make_client(Settings(data_dir=tmp_path / "data")) as client:
        ctx = client.app.state.ctx  # type: ignore[attr-defined]

        def broken(*_: Any, **__: Any) -> None:
            raise DatabaseUnavailableError("the job database is unavailable (test)")

        monkeypatch.setattr(ctx.store, "add_clip", broken)
        response = upload(client, small_clip, {})
        assert response.status_code == 503
        assert response.headers["retry-after"]
        assert list((ctx.storage.root / "clips").iterdir()) == []
        assert list((ctx.storage.root / "tmp").iterdir()) == []


def test_unwritable_storage_is_503(tmp_path: Path, small_clip: Path) -> None:
    import shutil

    with make_client(Settings(data_dir=tmp_path / "data")) as client:
        ctx = client.app.state.ctx  # type: ignore[attr-defined]
        shutil.rmtree(ctx.storage.root / "tmp")
        ready = client.get("/readyz")
        assert ready.status_code == 503
        assert ready.json()["checks"]["storage"].startswith("failed")
        assert ready.json()["checks"]["database"] == "ok"
        response = client.post("/v1/clips", files={"file": ("a.npz", io.BytesIO(small_clip.read_bytes()))})
        assert response.status_code == 503
        assert response.json()["type"].endswith("storage-unavailable")
        assert list((ctx.storage.root / "clips").iterdir()) == []


def test_odd_bodies_are_4xx_problems(keyed: TestClient, small_clip: Path) -> None:
    """Found by schemathesis: a non-UTF-8 JSON body and a non-Latin-1 form field name were 400/500."""
    bad = keyed.post("/v1/jobs", content=b"4\xff\xfe", headers={**A, "content-type": "application/json"})
    assert bad.status_code == 422
    assert bad.headers["content-type"] == "application/problem+json"
    boundary = "b0undary"
    body = (
        (
            f'--{boundary}\r\nContent-Disposition: form-data; name="\u00da\ue34d"\r\n\r\nx\r\n'
            f"--{boundary}\r\nContent-Disposition: form-data; "
            'name="file"; filename="\u6e2c\u8a66.npz"\r\n\r\n'
        ).encode()
        + small_clip.read_bytes()
        + f"\r\n--{boundary}--\r\n".encode()
    )
    up = keyed.post(
        "/v1/clips", content=body, headers={**A, "content-type": f"multipart/form-data; boundary={boundary}"}
    )
    assert up.status_code == 201, up.text
    assert up.json()["filename"] == "\u6e2c\u8a66.npz"
