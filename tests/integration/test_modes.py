"""A job end to end over HTTP in every deployment mode: right numbers and a mask artifact.

Modes: embedded broker with the job store on SQLite and on PostgreSQL; Redis broker with separate
uvicorn and Celery worker processes, job store on SQLite and on PostgreSQL.
"""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Any

import pytest
import service_harness as h

pytestmark = [
    pytest.mark.integration,
    pytest.mark.xdist_group("shared-redis"),  # uses the Redis test database, which the harness flushes
    pytest.mark.slow,
]


def run_job_and_check(service: h.LiveService, clip: Path, truth: dict[str, Any]) -> dict[str, float]:
    """Upload, analyse, check the numbers and the mask; return latency figures (seconds)."""
    from PIL import Image

    up = service.upload(clip)
    assert up.status_code == 201, up.text
    info = up.json()
    assert (info["format"], info["frames"], info["width"], info["height"]) == ("npz", 64, 160, 120)
    assert info["has_depth"] is True
    assert info["fps"] == pytest.approx(30.0)

    obj = truth["objects"][0]
    t0 = time.monotonic()
    created = service.client.post(
        "/v1/jobs", json={"clip_id": info["id"], "excitation": {"type": "step_release", "force_n": 5.0}}
    )
    assert created.status_code == 202, created.text
    assert created.headers["location"] == f"/v1/jobs/{created.json()['id']}"
    job = service.wait_job(created.json()["id"])
    wall = time.monotonic() - t0
    assert job["status"] == "succeeded", (job, service.logs())
    assert job["attempts"] == 1
    assert job["progress"] == 1.0

    result = job["result"]
    assert result["eigenfrequency_hz"] == pytest.approx(obj["eigenfrequency_hz"], rel=0.02)
    main = result["objects"][0]
    assert main["mass_kg"] == pytest.approx(obj["mass_kg"], rel=0.2)
    assert main["stiffness_n_per_m"] == pytest.approx(obj["stiffness_n_per_m"], rel=0.2)

    mask_url = result["artifacts"]["mask"]
    assert mask_url == f"/v1/jobs/{job['id']}/artifacts/mask.png"
    mask = service.client.get(mask_url)
    assert mask.status_code == 200
    assert mask.headers["content-type"] == "image/png"
    image = Image.open(io.BytesIO(mask.content))
    assert image.size == (160, 120)
    assert image.getextrema()[1] >= 1  # the object is labelled

    analysis = sum(result.get("timings_s", {}).values())
    return {"wall_s": wall, "analysis_s": analysis, "overhead_s": wall - analysis}


def report(mode: str, figures: dict[str, float]) -> None:
    print(
        f"\nLATENCY {mode}: end-to-end {figures['wall_s'] * 1000:.0f} ms, analysis "
        f"{figures['analysis_s'] * 1000:.0f} ms, overhead {figures['overhead_s'] * 1000:.0f} ms"
    )


def best_of(service: h.LiveService, clip: Path, truth: dict[str, Any], runs: int = 2) -> dict[str, float]:
    """Two jobs (a worker's first, and one with matplotlib already loaded); the figures of the faster.
    The latency is printed, never asserted: ``bench/overhead.py`` measures it."""
    figures = [run_job_and_check(service, clip, truth) for _ in range(runs)]
    return min(figures, key=lambda f: f["overhead_s"])


def test_embedded_sqlite(embedded: h.LiveService, truth_clip: tuple[Path, dict[str, Any]]) -> None:
    report("embedded+sqlite", best_of(embedded, *truth_clip))


def test_embedded_postgres(tmp_path: Path, truth_clip: tuple[Path, dict[str, Any]]) -> None:
    with h.postgres_database() as url:
        service = h.start_embedded(tmp_path, database_url=url)
        try:
            report("embedded+postgres", best_of(service, *truth_clip))
        finally:
            service.stop()


@pytest.mark.parametrize("store", ["sqlite", "postgres"])
def test_redis(store: str, tmp_path: Path, truth_clip: tuple[Path, dict[str, Any]]) -> None:
    redis_url = h.redis_url()
    if store == "postgres":
        with h.postgres_database() as url:
            service = h.start_split(tmp_path, redis_url=redis_url, database_url=url)
            try:
                report(f"redis+{store}", best_of(service, *truth_clip))
            finally:
                service.stop()
        return
    service = h.start_split(tmp_path, redis_url=redis_url)
    try:
        report(f"redis+{store}", best_of(service, *truth_clip))
    finally:
        service.stop()
