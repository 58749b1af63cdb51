"""Live streams: keeping up, latency, early stop, coverage of the intervals, concurrency.

    python bench/stream.py                 # everything (about 10 minutes on 2 cores)
    python bench/stream.py --only coverage # one part: keepup, latency, early, coverage, concurrency

- keepup: 640x480 RGB-D (JPEG colour, raw depth) through ``eigenscope serve`` (embedded): at 30 fps
  (paced like a camera) the frames the server had to drop and its lag behind capture; then as fast as
  flow control lets, the rate the stream sustains (where it stops keeping up).
- rule: 640x480 RGB-D paced at 30 fps by a client that follows the flow-control rule (waits for room in
  the window): fps sustained, frames dropped, ``slow_down`` messages, stalls (sends blocked longer than a
  frame interval), how far it fell behind real time, and the client's and the server's in-flight counts.
- latency: seconds from the last frame sent to the ``result`` message (median of several streams).
- early: release to ``converged`` (1 % target) for a 4.5 Hz object at 640x480, in seconds of capture.
- coverage: on randomised synthetic scenes (2-10 Hz, damping 0.01-0.08, step release or impulse), the
  fraction of live estimates whose 95 % frequency interval holds the truth, and at convergence; also
  their errors. In-process (:class:`workers.pipeline.live.LiveAnalysis`), no server.
- concurrency: 4 streams at once on 2 stream workers with Redis (EIGENSCOPE_BENCH_REDIS_URL or
  redis://127.0.0.1:6379/12), realtime 30 fps: none lost, their latencies.

Prints figures measured in this run; never fails on timing.
"""

from __future__ import annotations

# isort: off
import eigenscope  # noqa: F401 - one BLAS thread, as every entry point

# isort: on
import argparse
import math
import os
import statistics
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "integration"))
sys.path.insert(0, str(ROOT))

import service_harness as h  # noqa: E402
from eigenscope_client import StreamSession  # noqa: E402

from workers.pipeline.synth import Scene, SceneObject, SceneReader  # noqa: E402


@dataclass
class Frames:
    color: list[bytes]
    depth: list[bytes]
    times: list[float]
    width: int
    height: int
    intrinsics: tuple[float, float, float, float]
    truth: dict[str, Any]


def scene_frames(*, width: int, height: int, frames: int, frequency_hz: float = 4.5, seed: int = 1) -> Frames:
    obj = SceneObject(
        center_px=(width / 2, height / 2),
        size_px=(width * 0.22, height * 0.22),
        frequency_hz=frequency_hz,
        mass_kg=0.8,
        force_n=6.0,
        release_frame=15,
    )
    scene = Scene(width=width, height=height, frames=frames, fps=30.0, objects=(obj,), seed=seed)
    reader = SceneReader(scene)
    color, depth, times = [], [], []
    for f in reader.frames():
        color.append(
            bytes(
                cv2.imencode(".jpg", cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])[
                    1
                ]
            )
        )
        assert f.depth_m is not None
        depth.append(np.rint(np.nan_to_num(f.depth_m) * 1000).astype("<u2").tobytes())
        times.append(f.timestamp_s)
    return Frames(color, depth, times, width, height, scene.intrinsics, reader.truth["objects"][0])


def open_session(base: str, fr: Frames, **kwargs: Any) -> StreamSession:
    fx, fy, cx, cy = fr.intrinsics
    return StreamSession(
        base,
        fps=30.0,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        depth_scale=0.001,
        width=fr.width,
        height=fr.height,
        excitation={"type": "step_release", "force_n": 6.0},
        **kwargs,
    )


def stream(
    base: str, fr: Frames, *, pace_fps: float | None, realtime: bool, stop_when_converged: bool = False
) -> dict[str, Any]:
    """Send the frames (paced at ``pace_fps`` or as fast as allowed); returns what happened."""
    seen: list[tuple[float, dict[str, Any]]] = []
    session = open_session(
        base, fr, realtime=realtime, on_message=lambda m: seen.append((time.perf_counter(), m))
    )
    sent_at: dict[int, float] = {}
    start = time.perf_counter()
    n = 0
    for i, (c, d, _t) in enumerate(zip(fr.color, fr.depth, fr.times, strict=True)):
        if pace_fps:
            delay = start + i / pace_fps - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        sent_at[i] = time.perf_counter()
        session.send_frame(c, timestamp_s=fr.times[i], depth=d, width=fr.width, height=fr.height)
        n += 1
        if stop_when_converged and session.converged:
            break
    last = time.perf_counter()
    result = session.finish(timeout_s=120)
    done = time.perf_counter()
    session.close()
    accepted = {m["frame"]: t for t, m in seen if m["type"] == "accepted"}
    dropped = [m for _, m in seen if m["type"] == "backpressure" and m["action"] == "dropped"]
    lags = [accepted[i] - sent_at[i] for i in accepted if i in sent_at]
    converged = next((m for _, m in seen if m["type"] == "converged"), None)
    return {
        "frames": n,
        "send_s": last - start,
        "latency_s": done - last,
        "dropped": len(dropped),
        "lag_median_s": statistics.median(lags) if lags else math.nan,
        "lag_max_s": max(lags) if lags else math.nan,
        "converged": converged,
        "result": result,
        "job_id": session.job_id,
    }


def bench_keepup(base: str) -> None:
    fr = scene_frames(width=640, height=480, frames=150)
    paced = stream(base, fr, pace_fps=30.0, realtime=True)
    print(
        f"keepup 640x480 RGB-D at 30 fps: {paced['frames']} frames, dropped {paced['dropped']}, "
        f"accept lag median "
        f"{paced['lag_median_s'] * 1000:.0f} ms, max {paced['lag_max_s'] * 1000:.0f} ms"
    )
    rates = []
    for _ in range(2):
        fast = stream(base, fr, pace_fps=None, realtime=False)
        rates.append(fast["frames"] / fast["send_s"])
    print(
        f"keepup: as fast as flow control allows: {statistics.median(rates):.1f} fps sustained (runs: "
        + ", ".join(f"{r:.1f}" for r in rates)
        + ") = where a stream stops keeping up"
    )


def paced_by_the_rule(base: str, fr: Frames) -> dict[str, Any]:
    """Frames paced at 30 fps by a client that follows the documented flow-control rule (it waits for room
    in the window rather than send past it): fps sustained, drops, stalls and how far it fell behind."""
    seen: list[dict[str, Any]] = []
    counts: list[tuple[int, int]] = []  # (the client's in-flight count, the server's) at each `accepted`
    holder: dict[str, StreamSession] = {}

    def on_message(m: dict[str, Any]) -> None:
        seen.append(m)
        if m["type"] == "accepted" and "session" in holder:
            counts.append((holder["session"].in_flight, int(m["in_flight"])))

    session = open_session(base, fr, realtime=False, on_message=on_message)
    holder["session"] = session
    interval = 1 / 30.0
    start = time.perf_counter()
    stalls, behind = 0, 0.0
    for i, (c, d) in enumerate(zip(fr.color, fr.depth, strict=True)):
        delay = start + i * interval - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        before = time.perf_counter()
        session.send_frame(c, timestamp_s=fr.times[i], depth=d, width=fr.width, height=fr.height)
        after = time.perf_counter()
        stalls += after - before > interval
        behind = max(behind, after - (start + (i + 1) * interval))
    send_s = time.perf_counter() - start
    session.finish(timeout_s=120)
    session.close()
    waits = getattr(session, "stalls", None)  # the client's own count of waits for room (newer clients)
    return {
        "waits": waits,
        "fps": len(fr.color) / send_s,
        "dropped": sum(m["type"] == "backpressure" and m["action"] == "dropped" for m in seen),
        "slow_down": sum(m["type"] == "backpressure" and m["action"] == "slow_down" for m in seen),
        "stalls": stalls,
        "behind_s": behind,
        "max_client_in_flight": max((c for c, _ in counts), default=0),
        "max_server_in_flight": max((s for _, s in counts), default=0),
        "max_disagreement": max((abs(c - s) for c, s in counts), default=0),
    }


def bench_rule(base: str, runs: int) -> None:
    fr = scene_frames(width=640, height=480, frames=150)
    for _ in range(runs):
        r = paced_by_the_rule(base, fr)
        print(
            f"rule: 640x480 RGB-D paced at 30 fps, flow-controlled by the client: {r['fps']:.1f} fps "
            f"sustained, dropped {r['dropped']}, slow_down {r['slow_down']}, stalls {r['stalls']} "
            f"(sends blocked over a frame interval; waits for room {r['waits']}), at most "
            f"{r['behind_s'] * 1000:.0f} ms behind real time; "
            f"in flight max {r['max_client_in_flight']} by the client's count, {r['max_server_in_flight']} "
            f"by the server's (largest disagreement {r['max_disagreement']})"
        )
        sys.stdout.flush()


def bench_latency(base: str, runs: int) -> None:
    fr = scene_frames(width=640, height=480, frames=120)
    full, early = [], []
    for _ in range(runs):
        full.append(stream(base, fr, pace_fps=30.0, realtime=True)["latency_s"])
        early.append(stream(base, fr, pace_fps=30.0, realtime=True, stop_when_converged=True)["latency_s"])
    print(
        "latency last frame -> result, 640x480: whole 120-frame clip median "
        f"{statistics.median(full) * 1000:.0f} ms "
        f"(runs {', '.join(f'{x * 1000:.0f}' for x in full)}); stopped when converged median "
        f"{statistics.median(early) * 1000:.0f} ms (runs {', '.join(f'{x * 1000:.0f}' for x in early)})"
    )


def _live_run(
    fr_scene: Scene, *, every: int = 3
) -> tuple[list[tuple[float, float, float]], dict[str, Any] | None]:
    """Estimates (frame, f, sd) of one scene fed to LiveAnalysis, and the converged one."""
    from workers.pipeline.analysis import Excitation
    from workers.pipeline.clipio.types import Intrinsics
    from workers.pipeline.live import LiveAnalysis, LiveConfig

    reader = SceneReader(fr_scene)
    fx, fy, cx, cy = fr_scene.intrinsics
    obj = fr_scene.objects[0]
    exc = Excitation(
        kind=obj.excitation, value=obj.force_n if obj.excitation == "step_release" else obj.impulse_ns
    )
    live = LiveAnalysis(
        width=fr_scene.width,
        height=fr_scene.height,
        intrinsics=Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy),
        config=LiveConfig(fps=fr_scene.fps),
        excitation=exc,
    )
    out: list[tuple[float, float, float]] = []
    converged = None
    for f in reader.frames():
        live.push(rgb=f.rgb, depth_m=f.depth_m, timestamp_s=f.timestamp_s)
        if f.index % every == 0:
            live.wait(5.0)
            est = live.estimate()
            if est is not None:
                out.append((f.index, est.eigenfrequency_hz, est.eigenfrequency_uncertainty_hz))
                if est.converged and converged is None:
                    converged = {
                        "frame": f.index,
                        "f": est.eigenfrequency_hz,
                        "sd": est.eigenfrequency_uncertainty_hz,
                        "k": est.stiffness_n_per_m,
                        "k_sd": est.stiffness_uncertainty_n_per_m,
                    }
    live.close()
    return out, converged


def bench_early(seeds: int) -> None:
    times = []
    errors = []
    for seed in range(seeds):
        scene = Scene(
            width=640,
            height=480,
            frames=90,
            fps=30.0,
            seed=100 + seed,
            objects=(
                SceneObject(frequency_hz=4.5, damping_ratio=0.03, mass_kg=0.8, force_n=6.0, release_frame=15),
            ),
        )
        _, conv = _live_run(scene, every=1)
        truth = scene.truth()["objects"][0]["eigenfrequency_hz"]
        if conv is None:
            times.append(math.inf)
            continue
        times.append((conv["frame"] - 15) / 30.0)
        errors.append(abs(conv["f"] - truth) / truth)
    print(
        "early stop, 4.5 Hz at 640x480, target 1 %: release -> converged median "
        f"{statistics.median(times):.2f} s of "
        f"capture (runs {', '.join(f'{t:.2f}' for t in times)}); error at convergence max "
        f"{max(errors) * 100:.3f} %"
    )


def bench_coverage(scenes: int) -> None:
    rng = np.random.default_rng(7)
    inside = total = conv_inside = conv_total = 0
    k_inside = k_total = 0
    errs, conv_errs = [], []
    for i in range(scenes):
        f = float(rng.uniform(2.0, 10.0))
        zeta = float(rng.uniform(0.01, 0.08))
        kind = "step_release" if i % 2 == 0 else "impulse"
        mass = float(rng.uniform(0.2, 2.0))
        k = mass * (2 * math.pi * f) ** 2
        obj = SceneObject(
            center_px=(float(rng.uniform(120, 200)), float(rng.uniform(90, 150))),
            size_px=(70.0, 55.0),
            depth_m=float(rng.uniform(0.6, 1.4)),
            frequency_hz=f,
            damping_ratio=zeta,
            mass_kg=mass,
            excitation=kind,
            force_n=0.006 * k,
            impulse_ns=0.006 * mass * 2 * math.pi * f,
            direction=(float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)), 0.0),
            release_frame=int(rng.integers(5, 20)),
        )
        scene = Scene(
            width=320,
            height=240,
            frames=120,
            fps=30.0,
            objects=(obj,),
            seed=1000 + i,
            rgb_noise=float(rng.uniform(1.0, 4.0)),
        )
        truth = scene.truth()["objects"][0]
        est, conv = _live_run(scene)
        for _frame, fe, sd in est[1:]:
            total += 1
            inside += abs(fe - truth["eigenfrequency_hz"]) <= 1.96 * sd
            errs.append(abs(fe - truth["eigenfrequency_hz"]) / truth["eigenfrequency_hz"])
        if conv is not None:
            conv_total += 1
            conv_inside += abs(conv["f"] - truth["eigenfrequency_hz"]) <= 1.96 * conv["sd"]
            conv_errs.append(abs(conv["f"] - truth["eigenfrequency_hz"]) / truth["eigenfrequency_hz"])
            if conv["k"] is not None and conv["k_sd"] is not None:
                k_total += 1
                k_inside += abs(conv["k"] - truth["stiffness_n_per_m"]) <= 1.96 * conv["k_sd"]
    print(
        f"coverage of 95 % frequency intervals, {scenes} random scenes (320x240): all live estimates "
        f"{inside}/{total} = {inside / max(total, 1) * 100:.1f} % "
        f"(median error {statistics.median(errs) * 100:.3f} %); "
        f"at convergence {conv_inside}/{conv_total} = {conv_inside / max(conv_total, 1) * 100:.1f} % "
        "(median error "
        f"{statistics.median(conv_errs) * 100 if conv_errs else math.nan:.3f} %, max "
        f"{max(conv_errs) * 100 if conv_errs else math.nan:.3f} %); "
        f"stiffness at convergence {k_inside}/{k_total}"
    )


def _final_status(client: Any, job_id: str, timeout_s: float = 120.0) -> str:
    """The job's status once it has ended (long-polling), or its status when ``timeout_s`` runs out."""
    deadline = time.monotonic() + timeout_s
    status = "unknown"
    while time.monotonic() < deadline:
        status = client.get(f"/v1/jobs/{job_id}", params={"wait": 30}, timeout=40).json()["status"]
        if status in ("succeeded", "failed", "cancelled"):
            break
    return str(status)


def bench_concurrency(tmp: Path) -> None:
    url = os.environ.get("EIGENSCOPE_BENCH_REDIS_URL", "redis://127.0.0.1:6379/12")
    service = h.start_split(tmp / "concurrency", workers=0, redis_url=url, queue="bench-streams")
    try:
        for i in range(2):
            h.start_stream_worker(service, f"sw{i}")
        fr = scene_frames(width=640, height=480, frames=120)
        results: list[dict[str, Any]] = []
        errors: list[BaseException] = []

        def one() -> None:
            try:
                results.append(stream(service.base_url, fr, pace_fps=30.0, realtime=True))
            except BaseException as exc:
                errors.append(exc)

        threads = [threading.Thread(target=one) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        # The result goes out before the images are drawn: each job completes a moment later.
        jobs = [_final_status(service.client, r["job_id"]) for r in results]
        print(
            "concurrency: 4 streams of 640x480 at 30 fps on 2 stream workers (Redis): "
            f"{len(results)} results, "
            f"{len(errors)} errors, jobs {jobs}; latencies "
            + ", ".join(f"{r['latency_s'] * 1000:.0f} ms" for r in results)
            + "; dropped frames "
            + ", ".join(str(r["dropped"]) for r in results)
        )
        for e in errors:
            print(f"  error: {e}")
    finally:
        service.stop()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--only", default=None)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--scenes", type=int, default=30)
    args = parser.parse_args()
    parts = [args.only] if args.only else ["coverage", "early", "keepup", "rule", "latency", "concurrency"]
    with tempfile.TemporaryDirectory(prefix="eigenscope-bench-stream-") as tmp_name:
        tmp = Path(tmp_name)
        service = None
        if {"keepup", "rule", "latency"} & set(parts):
            service = h.start_embedded(tmp / "embedded")
        try:
            for part in parts:
                if part == "coverage":
                    bench_coverage(args.scenes)
                elif part == "early":
                    bench_early(args.runs)
                elif part == "keepup":
                    assert service is not None
                    bench_keepup(service.base_url)
                elif part == "rule":
                    assert service is not None
                    bench_rule(service.base_url, args.runs)
                elif part == "latency":
                    assert service is not None
                    bench_latency(service.base_url, args.runs)
                elif part == "concurrency":
                    bench_concurrency(tmp)
                sys.stdout.flush()
        finally:
            if service is not None:
                service.stop()


if __name__ == "__main__":
    main()
