"""The service's overhead on a small job: upload to result over HTTP, minus the analysis's own time.

    python bench/overhead.py                       # embedded (`eigenscope serve`, SQLite), 5 jobs
    python bench/overhead.py --redis-url redis://127.0.0.1:6379/12 --jobs 10

Starts the service in a temporary folder (embedded broker; with ``--redis-url``, uvicorn and a separate
``eigenscope worker`` on Redis, whose database is flushed), queues the 64-frame 160x120 clip of the
integration tests job after job, and prints each job's end-to-end time, its analysis time (the sum of its
``timings_s``) and the difference: queueing, the job record, storage, the images and HTTP. The first job
pays the worker's start-up (its drawing process); the median of the others is the figure. The
integration tests (``tests/integration/test_modes.py``) check that jobs succeed in every mode and print
their latency; they never assert it. Prints figures measured in this run; never fails on timing.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "integration"))

import service_harness as h  # noqa: E402


def one_job(service: h.LiveService, clip: Path) -> tuple[float, float]:
    """(end to end, analysis) seconds of one job on an uploaded clip."""
    started = time.monotonic()
    up = service.upload(clip)
    up.raise_for_status()
    created = service.client.post(
        "/v1/jobs", json={"clip_id": up.json()["id"], "excitation": {"type": "step_release", "force_n": 5.0}}
    )
    created.raise_for_status()
    job = service.wait_job(created.json()["id"])
    wall = time.monotonic() - started
    if job["status"] != "succeeded":
        raise SystemExit(f"job failed: {job}")
    return wall, sum(job["result"].get("timings_s", {}).values())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--jobs", type=int, default=5)
    parser.add_argument(
        "--redis-url", help="run uvicorn and a worker on this Redis (its database is flushed)"
    )
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="eigenscope-overhead-") as tmp:
        folder = Path(tmp)
        clip = folder / "spring.npz"
        h.synth_clip(clip, **h.SMALL_CLIP)
        if args.redis_url:
            import redis

            redis.Redis.from_url(args.redis_url).flushdb()
            service = h.start_split(folder / "service", redis_url=args.redis_url)
            mode = "redis (uvicorn + worker)"
        else:
            service = h.start_embedded(folder / "service")
            mode = "embedded (eigenscope serve)"
        try:
            runs = [one_job(service, clip) for _ in range(args.jobs)]
        finally:
            service.stop()
    print(f"{mode}, {args.jobs} jobs of the 160x120x64 clip:")
    print(f"{'job':>4} {'end to end s':>13} {'analysis s':>11} {'overhead s':>11}")
    for i, (wall, analysis) in enumerate(runs, 1):
        print(f"{i:>4} {wall:>13.3f} {analysis:>11.3f} {wall - analysis:>11.3f}")
    later = [wall - analysis for wall, analysis in runs[1:]] or [runs[0][0] - runs[0][1]]
    print(
        f"overhead: median {statistics.median(later):.3f} s, best {min(later):.3f} s (jobs after the first)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
