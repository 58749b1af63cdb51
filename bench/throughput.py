"""Service throughput: jobs per minute that `eigenscope serve` finishes with N analysis workers.

Starts the embedded service (API + workers, no external server) in a temporary folder, uploads one
clip, queues ``--jobs`` analyses of it at once (step release, 10 N) and waits until every job has
finished; reports jobs per minute, the per-job analysis time the workers recorded and the queue's
end-to-end latency. Runs once per worker count given, in one invocation, so the figures compare.

    python bench/throughput.py                               # 640x480x256, 1 and 2 workers, 12 jobs
    python bench/throughput.py --workers 2 --jobs 24 --size 320x240x128

Prints figures measured in this run; never fails on timing.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from load import start_server


def make_clip(workdir: Path, size: str) -> Path:
    width, height, frames = (int(v) for v in size.lower().split("x"))
    path = workdir / f"clip-{size}.npz"
    cmd = [sys.executable, "-m", "eigenscope", "synth", "--out", str(path), "--frames", str(frames)]
    cmd += ["--width", str(width), "--height", str(height), "--frequency-hz", "5"]
    subprocess.run(cmd, check=True, capture_output=True)
    return path


def run(clip: Path, workers: int, jobs: int) -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="eigenscope-throughput-") as tmp:
        proc, base = start_server(Path(tmp), workers)
        try:
            with httpx.Client(base_url=base, timeout=120.0) as client:
                up = client.post("/v1/clips", files={"file": (clip.name, clip.read_bytes())})
                up.raise_for_status()
                clip_id = up.json()["id"]
                body = {"clip_id": clip_id, "excitation": {"type": "step_release", "force_n": 10.0}}
                started = time.perf_counter()
                ids = []
                for _ in range(jobs):
                    created = client.post("/v1/jobs", json=body)
                    created.raise_for_status()
                    ids.append(created.json()["id"])
                done: dict[str, dict[str, object]] = {}
                while len(done) < len(ids):
                    for job_id in ids:
                        if job_id in done:
                            continue
                        job = client.get(f"/v1/jobs/{job_id}").json()
                        if job["status"] in ("succeeded", "failed", "cancelled"):
                            done[job_id] = job
                    time.sleep(0.05)
                elapsed = time.perf_counter() - started
                failed = [j for j in done.values() if j["status"] != "succeeded"]
                if failed:
                    raise SystemExit(f"throughput: {len(failed)} jobs did not succeed: {failed[0]}")
                analysis = [sum(j["result"]["timings_s"].values()) for j in done.values()]  # type: ignore[index]
        finally:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=30)
    return {
        "workers": workers,
        "jobs": jobs,
        "wall_s": elapsed,
        "jobs_per_min": jobs / elapsed * 60,
        "analysis_s_mean": sum(analysis) / len(analysis),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--size", default="640x480x256", help="WxHxFRAMES of the synthetic clip")
    parser.add_argument("--workers", default="1,2", help="worker counts to compare, e.g. 1,2")
    parser.add_argument("--jobs", type=int, default=12)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="eigenscope-throughput-clip-") as tmp:
        clip = make_clip(Path(tmp), args.size)
        rows = [run(clip, int(w), args.jobs) for w in args.workers.split(",")]
    print(f"clip {args.size}, {args.jobs} jobs queued at once")
    print("| workers | jobs | wall s | jobs/min | analysis s per job (mean) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['workers']:.0f} | {r['jobs']:.0f} | {r['wall_s']:.1f} | {r['jobs_per_min']:.1f} "
            f"| {r['analysis_s_mean']:.2f} |"
        )


if __name__ == "__main__":
    main()
