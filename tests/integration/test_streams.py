"""Live streams end to end: real API, real worker processes, embedded mode and Redis.

Each test talks to ``eigenscope serve`` (embedded) or uvicorn plus ``eigenscope worker`` /
``eigenscope stream-worker`` processes on a real Redis, through the Python client or a bare WebSocket.
Receive timeouts only guard against hangs; nothing here asserts how long anything took.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import service_harness as h
from eigenscope_client import StreamError, StreamSession
from stream_helpers import RawSocket, scene_frames, send_scene, session_kwargs

pytestmark = [
    pytest.mark.integration,
    pytest.mark.xdist_group("shared-redis"),  # uses the Redis test database, which the harness flushes
    pytest.mark.slow,
]

#: Short timeouts, so that the failure paths end quickly.
STREAM_SETTINGS = {
    "stream_worker_timeout_s": "4",
    "stream_client_timeout_s": "4",
    "stream_resume_window_s": "6",
    "stream_start_timeout_s": "30",
}


@pytest.fixture(scope="module")
def embedded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    service = h.start_embedded(tmp_path_factory.mktemp("streams-embedded"), **STREAM_SETTINGS)
    yield service
    service.stop()


@pytest.fixture(scope="module")
def on_redis(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    url = h.redis_url()
    service = h.start_split(
        tmp_path_factory.mktemp("streams-redis"),
        workers=1,
        redis_url=url,
        queue="streams-e2e",
        **STREAM_SETTINGS,
    )
    h.wait_stream_worker(service)
    yield service
    service.stop()


def _check_result(
    service: h.LiveService, session: StreamSession, result: dict[str, Any], truth: dict[str, Any]
) -> None:
    f_true = truth["eigenfrequency_hz"]
    assert abs(result["eigenfrequency_hz"] - f_true) / f_true < 0.01
    obj = result["objects"][0]
    assert abs(obj["stiffness_n_per_m"] - truth["stiffness_n_per_m"]) / truth["stiffness_n_per_m"] < 0.1
    # The stream is a job, with the same images as an uploaded clip's (drawn after `result` was sent: the
    # job completes a moment later).
    job = service.client.get(f"/v1/jobs/{session.job_id}", params={"wait": 30}).json()
    assert job["status"] == "succeeded"
    assert job["source"] == "stream"
    assert job["result"]["eigenfrequency_hz"] == result["eigenfrequency_hz"]
    assert set(job["result"]["artifacts"]) >= {
        "mask",
        "overlay",
        "frequency_map",
        "spectrum",
        "displacement",
        "ringdown",
        "modes",
        "mode_shapes",
        "mode_animation",
        "result",
    }
    for key, url in job["result"]["artifacts"].items():
        response = service.client.get(url)
        assert response.status_code == 200
        if key == "result":
            assert response.json()["eigenfrequency_hz"] == result["eigenfrequency_hz"]
        elif key == "modes":
            assert response.content[:4] == b"PK\x03\x04"  # an npz archive
        elif key == "mode_animation":
            assert response.content[:6] == b"GIF89a"
        else:
            assert response.content[:8] == b"\x89PNG\r\n\x1a\n"
    listed = service.client.get("/v1/jobs", params={"limit": 100}).json()["items"]
    assert session.job_id in {j["id"] for j in listed}
    stream = service.wait_stream(session.stream_id)
    assert stream["status"] == "succeeded"
    assert stream["last_estimate"] is not None


def _reanalyse(service: h.LiveService, clip_id: str, frames: int) -> dict[str, Any]:
    """The stream's frames, kept as a clip, analysed again as an ordinary job."""
    clip = service.client.get(f"/v1/clips/{clip_id}").json()
    assert clip["frames"] == frames
    assert clip["has_depth"] is True
    created = service.client.post(
        "/v1/jobs", json={"clip_id": clip_id, "excitation": {"type": "step_release", "force_n": 6.0}}
    )
    assert created.status_code == 202, created.text
    return service.wait_job(created.json()["id"])


def test_stream_end_to_end_embedded(embedded: h.LiveService) -> None:
    scene = scene_frames()
    seen: list[dict[str, Any]] = []
    with StreamSession(embedded.base_url, on_message=seen.append, **session_kwargs(scene)) as session:
        send_scene(session, scene)
        result = session.finish(timeout_s=120)
    kinds = [m["type"] for m in seen]
    assert kinds[0] == "ready"
    assert kinds.count("accepted") == len(scene.frames)
    assert kinds.count("estimate") >= 1
    assert kinds.count("converged") == 1
    assert kinds[-1] == "result"
    converged = next(m for m in seen if m["type"] == "converged")
    assert converged["relative_uncertainty"] <= 0.01
    est = converged["estimate"]
    # The converged estimate's 95 % interval holds the truth (a single scene: the bench measures the rate).
    f_true = scene.truth["eigenfrequency_hz"]
    assert abs(est["eigenfrequency_hz"] - f_true) <= 1.96 * est["eigenfrequency_uncertainty_hz"] + 1e-9
    _check_result(embedded, session, result, scene.truth)
    job = _reanalyse(embedded, session.info["clip_id"], len(scene.frames))
    assert job["status"] == "succeeded", job["error"]
    assert abs(job["result"]["eigenfrequency_hz"] - f_true) / f_true < 0.01


def test_stream_end_to_end_on_redis(on_redis: h.LiveService) -> None:
    scene = scene_frames()
    with StreamSession(on_redis.base_url, **session_kwargs(scene)) as session:
        send_scene(session, scene)
        result = session.finish(timeout_s=120)
    assert session.converged
    _check_result(on_redis, session, result, scene.truth)
    # No frame stays in Redis after the session.
    import redis

    client = redis.Redis.from_url(on_redis.env["EIGENSCOPE_REDIS_URL"])
    try:
        assert not client.keys(f"eigenscope:stream:{session.stream_id}:*")
    finally:
        client.close()


def test_worker_killed_mid_stream_gets_an_error(tmp_path: Path) -> None:
    url = h.redis_url()
    service = h.start_split(tmp_path, workers=0, redis_url=url, queue="killed-stream", **STREAM_SETTINGS)
    try:
        with service.logs_on_failure():  # once, under load, the session never got its ready message
            worker = h.start_stream_worker(service, "sw")
            scene = scene_frames()
            session = StreamSession(service.base_url, **session_kwargs(scene))
            send_scene(session, scene, stop=20)
            os.killpg(worker.pid, signal.SIGKILL)

            def go_on() -> None:
                send_scene(session, scene, start=20)
                session.finish(timeout_s=60)

            with pytest.raises(StreamError) as caught:
                go_on()
            assert caught.value.problem["code"] == "worker-lost", caught.value.problem
            session.close()
            job = service.client.get(f"/v1/jobs/{session.job_id}").json()
            assert job["status"] == "failed"
            assert job["error"]["code"] == "worker-lost"
    finally:
        service.stop()


def test_slow_consumer_gets_backpressure(tmp_path: Path) -> None:
    service = h.start_embedded(tmp_path, stream_window="4", **STREAM_SETTINGS)
    try:
        scene = scene_frames()
        seen: list[dict[str, Any]] = []
        # A camera does not wait: realtime sessions send whatever the worker's pace. Bursts of 6 frames
        # (12 messages) into a window of 4 overflow it however fast the worker is; between bursts the
        # stream drains, so the analysis still gets frames.
        session = StreamSession(
            service.base_url, realtime=True, on_message=seen.append, **session_kwargs(scene)
        )
        for start in range(0, len(scene.frames), 6):
            send_scene(session, scene, start=start, stop=start + 6)
            deadline = time.monotonic() + 60
            while session.in_flight > 0:
                assert time.monotonic() < deadline, "the stream never drained"
                session.poll()
                time.sleep(0.01)
        result = session.finish(timeout_s=120)
        session.close()
        actions = [m["action"] for m in seen if m["type"] == "backpressure"]
        assert "slow_down" in actions
        dropped = [m for m in seen if m["type"] == "backpressure" and m["action"] == "dropped"]
        assert dropped, "the window of 4 should have overflowed"
        assert all(isinstance(m["frame"], int) for m in dropped)
        # Nothing lost silently: every frame is accepted, or dropped with a message, or named in an error.
        accepted = {m["frame"] for m in seen if m["type"] == "accepted"}
        refused = {m["frame"] for m in dropped} | {m["frame"] for m in seen if m["type"] == "error"}
        assert accepted | refused == set(range(len(scene.frames)))
        assert result["frames_used"][1] <= len(scene.frames)
        # Every frame message was acknowledged, the dropped ones included: none is left in flight.
        assert session.in_flight == 0

        # The same window, for a client that keeps the rule: it waits for room, is never dropped, and its
        # count of messages in flight is never below the server's (only what is on the wire differs).
        counts: list[tuple[int, int]] = []
        kept: list[dict[str, Any]] = []
        holder: dict[str, StreamSession] = {}

        def follow(m: dict[str, Any]) -> None:
            kept.append(m)
            if "acked" in m and m.get("in_flight") is not None and "s" in holder:
                counts.append((holder["s"].in_flight, int(m["in_flight"])))

        session = StreamSession(service.base_url, on_message=follow, **session_kwargs(scene))
        holder["s"] = session
        send_scene(session, scene, stop=40)
        session.finish(timeout_s=120)
        session.close()
        assert not [m for m in kept if m["type"] == "backpressure" and m["action"] == "dropped"]
        assert counts
        assert all(mine >= theirs for mine, theirs in counts), counts
        assert max(mine for mine, _ in counts) <= 4
        assert session.stalls > 0, "a window of 4 makes a client that keeps the rule wait"
        assert session.in_flight == 0
    finally:
        service.stop()


def test_bad_frames_each_get_an_error_naming_the_frame(embedded: h.LiveService) -> None:
    scene = scene_frames()
    body = {"parameters": {"fps": 30}, "width": scene.width, "height": scene.height}
    created = embedded.client.post("/v1/streams", json=body).json()
    ws = RawSocket(created["websocket_url"])
    try:
        assert ws.until("ready")["next_frame"] == 0
        good = scene.frames

        def send(i: int) -> None:
            ws.frame(good[i].color_png, frame=i, kind="color", timestamp_s=i / 30, encoding="png")
            ws.frame(
                good[i].depth_raw,
                frame=i,
                kind="depth",
                timestamp_s=i / 30,
                encoding="raw",
                width=scene.width,
                height=scene.height,
            )
            ws.until("accepted", frame=i)  # flow control: one frame in flight at a time

        for i in range(3):
            send(i)
        import cv2
        import numpy as np

        small = bytes(cv2.imencode(".png", np.zeros((10, 20, 3), np.uint8))[1])
        ws.frame(small, frame=3, kind="color", timestamp_s=3 / 30, encoding="png")  # wrong size
        ws.frame(
            b"not an image at all", frame=4, kind="color", timestamp_s=4 / 30, encoding="jpeg"
        )  # undecodable
        ws.frame(good[5].color_png, frame=5, kind="color", timestamp_s=0.01, encoding="png")  # backwards
        ws.frame(
            good[6].depth_raw,
            frame=6,
            kind="depth",
            timestamp_s=6 / 30,
            encoding="raw",
            width=scene.width,
            height=scene.height,
        )  # no colour
        ws.ws.send(b"\x00\x00")  # not even a header
        expected = {
            3: "wrong-size",
            4: "undecodable-frame",
            5: "timestamp-backwards",
            6: "depth-without-color",
        }
        errors = {}
        while len(errors) < len(expected) + 1:
            m = ws.until("error")
            assert m["fatal"] is False
            errors[m["frame"]] = m["problem"]
        for frame, code in expected.items():
            assert errors[frame]["code"] == code
            assert f"frame {frame}" in errors[frame]["detail"]
            assert errors[frame]["frame"] == frame
        assert "header" in errors[None]["detail"]
        # The stream goes on after bad frames.
        for i in range(7, 40):
            send(i)
        ws.ws.send('{"type": "end"}')
        result = ws.until("result", timeout=120)
        # 36 good frames reached the analysis (its window starts just before the motion).
        used = result["result"]["frames_used"]
        assert used[1] == 36
        assert 0 <= used[0] < 10
    finally:
        ws.close()


def test_silent_client_and_resume(embedded: h.LiveService) -> None:
    scene = scene_frames()
    session = StreamSession(embedded.base_url, **session_kwargs(scene))
    send_scene(session, scene, stop=30)
    # A second connection without the token is refused; with it the stream resumes where it was.
    intruder = RawSocket(session.info["websocket_url"])
    refused = intruder.until("error")
    assert refused["fatal"] is True
    assert refused["problem"]["code"] == "stream-connected"
    intruder.close()
    session.resume()
    assert session._state.next_frame == 30
    send_scene(session, scene, start=30, stop=60)
    # Then the client goes silent: the server says why and ends the stream with the frames it has.
    seen: list[dict[str, Any]] = []
    session._state.on_message = seen.append
    session._wait(lambda: session._state.result is not None, 60, "result")
    codes = [m["problem"]["code"] for m in seen if m["type"] == "error"]
    assert codes == ["client-timeout"]
    assert [m["fatal"] for m in seen if m["type"] == "error"] == [False]
    session.close()
    job = embedded.wait_job(session.job_id)
    assert job["status"] == "succeeded"
    assert job["result"]["frames_used"][1] == 60


def test_tenancy_of_streams(tmp_path: Path) -> None:
    key_a, key_b = "a" * 24, "b" * 24
    service = h.start_embedded(tmp_path, api_keys=f"{key_a},{key_b}", **STREAM_SETTINGS)
    try:
        a = {"Authorization": f"Bearer {key_a}"}
        b = {"Authorization": f"Bearer {key_b}"}
        assert service.client.post("/v1/streams", json={}).status_code == 401
        body = {"parameters": {"fps": 30}, "width": 320, "height": 240}
        created = service.client.post("/v1/streams", json=body, headers=a)
        assert created.status_code == 201, created.text
        stream = created.json()
        assert service.client.get(f"/v1/streams/{stream['id']}", headers=b).status_code == 404
        assert service.client.get(f"/v1/streams/{stream['id']}", headers=a).status_code == 200
        assert stream["id"] not in {
            s["id"] for s in service.client.get("/v1/streams", headers=b).json()["items"]
        }
        assert service.client.get(f"/v1/jobs/{stream['job_id']}", headers=b).status_code == 404
        for headers, code in ((b, 4404), ({}, 4401)):
            ws = RawSocket(stream["websocket_url"], headers)
            m = ws.until("error")
            assert m["fatal"] is True
            assert m["problem"]["status"] == code - 4000
            ws.close()
        owner = RawSocket(stream["websocket_url"], a)
        assert owner.until("ready")["job_id"] == stream["job_id"]
        owner.close()
    finally:
        service.stop()


def test_stream_request_is_validated(embedded: h.LiveService) -> None:
    size = {"width": 320, "height": 240}
    for body, field in (
        ({"parameters": {"method": "paper"}, **size}, "method"),
        ({"parameters": {"start_frame": 3}, **size}, "start_frame"),
        ({"max_duration_s": 1e9, **size}, "max_duration_s"),
        ({"target_relative_uncertainty": 0, **size}, "target_relative_uncertainty"),
        ({"height": 240}, "width"),
    ):
        response = embedded.client.post("/v1/streams", json=body)
        assert response.status_code == 422, (body, response.text)
        assert response.headers["content-type"].startswith("application/problem+json")
        assert field in response.text
    assert embedded.client.get("/v1/streams/nope").status_code == 404


def test_cli_streams_a_clip(embedded: h.LiveService, tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    clip = tmp_path / "spring.npz"
    truth = h.synth_clip(
        clip, frames=90, width=320, height=240, frequency_hz=4.5, mass_kg=0.8, force_n=6.0, release_frame=10
    )
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "eigenscope",
            "stream",
            str(clip),
            "--server",
            embedded.base_url,
            "--force-n",
            "6",
            "--stop-when-converged",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    f_true = truth["objects"][0]["eigenfrequency_hz"]
    assert abs(result["eigenfrequency_hz"] - f_true) / f_true < 0.01
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "eigenscope",
            "stream",
            str(tmp_path / "missing.npz"),
            "--server",
            embedded.base_url,
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


def test_openapi_client_reaches_streams(embedded: h.LiveService) -> None:
    doc = httpx.get(f"{embedded.base_url}/asyncapi.json").json()
    assert doc["asyncapi"] == "3.0.0"
    assert doc["channels"]["stream"]["address"] == "/v1/streams/{stream_id}"


def test_realsense_playback_of_a_recorded_bag(embedded: h.LiveService, tmp_path: Path) -> None:
    """`eigenscope stream --realsense --bag`: pyrealsense2's playback device, a .bag written here."""
    import json
    import subprocess
    import sys

    import numpy as np
    from realsense_bag import write_realsense_bag

    from workers.pipeline.synth import Scene, SceneObject, render

    pytest.importorskip(
        "pyrealsense2", reason="pip install pyrealsense2 (and libusb-1.0) for RealSense cameras"
    )
    obj = SceneObject(
        center_px=(160, 120), size_px=(80, 60), frequency_hz=4.5, mass_kg=0.8, force_n=6.0, release_frame=10
    )
    scene = Scene(width=320, height=240, frames=90, fps=30.0, seed=4, objects=(obj,))
    clip = render(scene)
    bag = write_realsense_bag(
        tmp_path / "recording.bag",
        clip.rgb,
        clip.depth.astype(np.uint16),
        fps=30.0,
        intrinsics=clip.intrinsics,
    )
    out = subprocess.run(
        [sys.executable, "-m", "eigenscope", "stream", "--realsense", "--bag", str(bag), "--server",
         embedded.base_url, "--force-n", "6", "--json"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    truth = clip.truth["objects"][0]
    assert abs(result["eigenfrequency_hz"] - truth["eigenfrequency_hz"]) / truth["eigenfrequency_hz"] < 0.01
    obj = result["objects"][0]
    # Intrinsics and depth scale came from the recording through the SDK: metric stiffness follows.
    assert abs(obj["stiffness_n_per_m"] - truth["stiffness_n_per_m"]) / truth["stiffness_n_per_m"] < 0.1
    assert result["frames_used"][1] >= 80
