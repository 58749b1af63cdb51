"""A force log uploaded through the API with an mp4 and a depth value (issue 31): a real ``eigenscope
serve`` (embedded broker, its own worker process), the Python client sending the robot's force sensor as a
CSV log with the job and no excitation. The push, hold and release (or the strike) in the log gives
stiffness and mass within 5 % of the scene's truth and the result names the log; a log that shows no
excitation fails the job with its problem, one on another clock is refused at the request. The log's
column and its summary also survive a PostgreSQL job store made before they existed."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import service_harness as h
from eigenscope_client import Client, ForceLog, InvalidRequestError

from tests.robot_force import FPS, RELEASE_FRAME, pushed_spring, robot_force
from workers.pipeline.clipio import writers as w
from workers.pipeline.synth import Scene, render

pytestmark = [pytest.mark.integration, pytest.mark.slow]

RATE_HZ = 500.0
#: The robot's clock when the clip's first frame was taken: the log is sent with offset_s = minus it.
ROBOT_CLOCK_AT_FIRST_FRAME_S = 1234.5
#: The force in the sensor's frame (no transform recorded: its magnitude along this direction is used).
SENSOR_DIRECTION = np.array([0.3, -0.8, 0.52]) / np.linalg.norm([0.3, -0.8, 0.52])


def _write_log(path: Path, force: np.ndarray, t_robot: np.ndarray) -> Path:
    """A CSV as a robot logs its wrist sensor: its own clock, three components in the sensor's frame."""
    xyz = np.outer(force, SENSOR_DIRECTION)
    samples = zip(t_robot.tolist(), xyz.tolist(), strict=True)
    rows = [f"{ti!r},{fx!r},{fy!r},{fz!r}" for ti, (fx, fy, fz) in samples]
    path.write_text("# frame_id: ft_sensor_link\ntime_s,fx,fy,fz\n" + "\n".join(rows) + "\n")
    return path


def _recording(folder: Path, excitation: str) -> tuple[Scene, Path, Path]:
    """The scene as an mp4 (no depth, no intrinsics) and its force log on the robot's clock."""
    scene = pushed_spring(excitation, seed=21)
    clip = w.write_video(folder / f"{excitation}.mp4", render(scene).rgb, fps=FPS)
    t = np.arange(-0.9, scene.frames / FPS + 0.2, 1 / RATE_HZ)
    force = robot_force(scene.objects[0], t, np.random.default_rng(7))
    log = _write_log(folder / f"{excitation}.csv", force, t + ROBOT_CLOCK_AT_FIRST_FRAME_S)
    return scene, clip, log


def _camera(scene: Scene) -> dict[str, Any]:
    """What the user knows of the camera of a clip without depth: its focal length and the distance."""
    fx, fy, _, _ = scene.intrinsics
    return {"fx": fx, "fy": fy, "depth_m": scene.objects[0].depth_m}


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    live = h.start_embedded(tmp_path_factory.mktemp("force-log"))
    yield live
    live.stop()


@pytest.fixture
def client(service: h.LiveService) -> Iterator[Client]:
    with Client(service.base_url) as es:
        yield es


@pytest.mark.parametrize("excitation", ["step_release", "impulse"])
def test_a_force_log_sent_with_an_mp4_and_a_depth_gives_k_and_m_within_5_percent(
    service: h.LiveService, client: Client, tmp_path: Path, excitation: str
) -> None:
    scene, clip, log_file = _recording(tmp_path, excitation)
    log = ForceLog.from_file(log_file, offset_s=-ROBOT_CLOCK_AT_FIRST_FRAME_S)
    job = client.analyze(clip, force_log=log, parameters=_camera(scene), timeout=240)
    assert job.status == "succeeded", (job.error, service.logs()[-3000:])
    assert job.excitation is None
    assert job.force_log is not None
    assert (job.force_log.name, job.force_log.samples) == (log_file.name, len(log.time_s))
    assert job.force_log.start_s == pytest.approx(-0.9, abs=1e-6)
    assert job.result is not None
    main = job.result.main
    assert main is not None
    truth = scene.objects[0]
    used = main.excitation
    assert used is not None
    assert used.source == f"log {log_file.name}"
    assert used.type == excitation
    assert any("dominant direction" in note for note in used.notes), used.notes
    assert main.stiffness_n_per_m is not None, main.null_reasons
    assert main.mass_kg is not None, main.null_reasons
    k_err = main.stiffness_n_per_m / truth.stiffness_n_per_m - 1
    m_err = main.mass_kg / truth.mass_kg - 1
    print(
        f"\nFORCE LOG {excitation}: k {main.stiffness_n_per_m:.4g} N/m ({k_err:+.2%}), "
        f"m {main.mass_kg:.4g} kg ({m_err:+.2%}), {used.type} {used.value:.4g} ± {used.uncertainty:.2g}, "
        f"at {used.release_time_s:.4f} s"
    )
    assert main.stiffness_n_per_m == pytest.approx(truth.stiffness_n_per_m, rel=0.05)
    assert main.mass_kg == pytest.approx(truth.mass_kg, rel=0.05)
    assert used.release_time_s == pytest.approx(RELEASE_FRAME / FPS, abs=1 / FPS)
    # The job shows the log's summary, never its samples.
    polled = service.client.get(f"/v1/jobs/{job.id}").json()
    assert "time_s" not in polled["force_log"]


def test_a_log_without_an_excitation_fails_the_job_with_its_problem(
    service: h.LiveService, client: Client, tmp_path: Path
) -> None:
    scene, clip, _ = _recording(tmp_path, "step_release")
    t = np.arange(-0.5, scene.frames / FPS, 1 / RATE_HZ)
    quiet = ForceLog(time_s=t.tolist(), force_n=np.random.default_rng(1).normal(0, 0.03, t.size).tolist())
    job = client.analyze(clip, force_log=quiet, parameters=_camera(scene), timeout=240)
    assert job.status == "failed"
    assert job.attempts == 1
    assert job.error is not None
    assert job.error.status == 422
    assert job.error.type.endswith("/invalid-force")
    assert "shows no hold, release or strike" in (job.error.detail or "")
    assert "Traceback" not in (job.error.detail or "")


def test_a_log_on_another_clock_is_refused_at_the_request(client: Client, tmp_path: Path) -> None:
    scene, clip, log_file = _recording(tmp_path, "step_release")
    uploaded = client.upload_clip(clip)
    with pytest.raises(InvalidRequestError) as refused:
        client.create_job(uploaded.id, force_log=ForceLog.from_file(log_file), parameters=_camera(scene))
    assert refused.value.errors is not None
    assert refused.value.errors[0]["loc"] == ["body", "force_log", "offset_s"]
    assert "set offset_s to minus the log's time at the clip's first frame" in (refused.value.detail or "")


def test_a_postgresql_store_made_before_force_logs_takes_them() -> None:
    """An existing PostgreSQL job store gains the columns on start, and a minute of a 500 Hz log goes in
    and comes back whole, apart from the record."""
    from sqlalchemy import create_engine, text

    from api_schemas import ForceLog as Log
    from backend.store import NewClip, NewJob, Store
    from backend.store.schema import Base

    with h.postgres_database() as url:
        old = create_engine(url.replace("postgresql://", "postgresql+psycopg://"))
        Base.metadata.create_all(old)
        with old.begin() as conn:  # as a release before force logs left it
            conn.execute(
                text("ALTER TABLE eigenscope_jobs DROP COLUMN force_log, DROP COLUMN force_log_summary")
            )
        old.dispose()
        store = Store(url)
        try:
            store.create_schema()
            store.add_clip(
                NewClip(clip_id="c1", filename="a.mp4", path="clips/c1/a.mp4", info={}, size_bytes=1)
            )
            n = round(60 * RATE_HZ)
            log = Log(
                time_s=[i / RATE_HZ for i in range(n)],
                fx=[math.sin(i / 50) * 3.141592653589793 for i in range(n)],
                fy=[1e-300] * n,
                fz=[-2.2250738585072014e-308] * n,
                offset_s=-0.25,
                name="wrist.csv",
            )
            sent: dict[str, Any] = log.model_dump(mode="json")
            job, _ = store.create_job(
                NewJob(
                    clip_id="c1",
                    excitation=None,
                    parameters={},
                    force_log=sent,
                    force_log_summary=log.summary().model_dump(mode="json"),
                )
            )
            assert store.get_job(job.id).force_log_summary == log.summary().model_dump(mode="json")
            assert store.job_force_log(job.id) == sent
        finally:
            store.dispose()
