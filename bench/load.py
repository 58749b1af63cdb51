"""Load test on loopback: concurrent uploads (each queues a job) and many robot clients polling job status.

    python bench/load.py                          # starts `eigenscope serve` in a temp dir, 60 s
    python bench/load.py --duration 300 --pollers 200 --uploaders 8
    python bench/load.py --server http://127.0.0.1:8000 --api-key KEY --clip my.npz

Reports throughput, p50/p99 latency per kind of request, and errors (any 5xx, transport error or
unexpected status; there must be none). 429s from the per-key limits are counted apart as "throttled".
The status endpoint must stay fast while the workers are busy with the queued jobs. Prints figures
measured in this run; never fails on timing. The test suite runs a short form
(``tests/integration/test_load.py``) that checks no request fails; the latencies are this script's.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx


@dataclass
class LoadReport:
    duration_s: float
    latencies_s: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    errors: list[str] = field(default_factory=list)
    throttled: int = 0
    jobs_created: int = 0

    @property
    def requests(self) -> int:
        return sum(len(v) for v in self.latencies_s.values()) + len(self.errors)

    def percentile(self, kind: str, q: float) -> float:
        values = sorted(self.latencies_s.get(kind, []))
        if not values:
            return float("nan")
        return values[min(len(values) - 1, round(q / 100 * (len(values) - 1)))]

    def summary(self) -> dict[str, Any]:
        kinds = {
            kind: {
                "requests": len(values),
                "p50_ms": round(self.percentile(kind, 50) * 1000, 2),
                "p99_ms": round(self.percentile(kind, 99) * 1000, 2),
                "max_ms": round(max(values) * 1000, 2),
            }
            for kind, values in sorted(self.latencies_s.items())
            if values
        }
        return {
            "duration_s": round(self.duration_s, 2),
            "requests": self.requests,
            "throughput_rps": round(self.requests / self.duration_s, 1) if self.duration_s else 0.0,
            "jobs_created": self.jobs_created,
            "errors": len(self.errors),
            "throttled": self.throttled,
            "by_kind": kinds,
            "first_errors": self.errors[:5],
        }

    def text(self) -> str:
        s = self.summary()
        lines = [
            f"{s['requests']} requests in {s['duration_s']} s ({s['throughput_rps']} req/s), "
            f"{s['jobs_created']} jobs queued, {s['errors']} errors, {s['throttled']} throttled (429)"
        ]
        for kind, k in s["by_kind"].items():
            lines.append(
                f"  {kind:<8} {k['requests']:>7} requests  p50 {k['p50_ms']:>8.2f} ms  "
                f"p99 {k['p99_ms']:>8.2f} ms  max {k['max_ms']:>8.2f} ms"
            )
        lines += [f"  error: {e}" for e in s["first_errors"]]
        return "\n".join(lines)


async def _timed(
    report: LoadReport, kind: str, request: Coroutine[Any, Any, httpx.Response], expected: tuple[int, ...]
) -> httpx.Response | None:
    """Await ``request`` (not started until awaited), timing it and filing the outcome."""
    start = time.perf_counter()
    try:
        response = await request
    except httpx.HTTPError as exc:
        report.errors.append(f"{kind}: {type(exc).__name__}: {exc}")
        return None
    elapsed = time.perf_counter() - start
    if response.status_code == 429:
        report.throttled += 1
        report.latencies_s[kind].append(elapsed)
        return None
    if response.status_code not in expected:
        report.errors.append(f"{kind}: HTTP {response.status_code}: {response.text[:200]}")
        return None
    report.latencies_s[kind].append(elapsed)
    return response


async def run_load(
    base_url: str,
    clip: Path,
    *,
    duration_s: float = 10.0,
    uploaders: int = 3,
    pollers: int = 50,
    poll_interval_s: float = 0.5,
    api_key: str | None = None,
    seed: int = 0,
) -> LoadReport:
    """Drive the server at ``base_url`` for ``duration_s``; see the module docstring."""
    headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
    data = clip.read_bytes()
    limits = httpx.Limits(
        max_connections=uploaders + pollers + 4, max_keepalive_connections=uploaders + pollers
    )
    report = LoadReport(duration_s=duration_s)
    rng = random.Random(seed)
    async with httpx.AsyncClient(base_url=base_url, headers=headers, timeout=60.0, limits=limits) as client:
        # A few jobs exist before the pollers start; the uploaders add more as they go.
        first = await client.post("/v1/clips", files={"file": (clip.name, data)})
        first.raise_for_status()
        clip_id = first.json()["id"]
        job_ids: list[str] = []
        for _ in range(3):
            created = await client.post("/v1/jobs", json={"clip_id": clip_id})
            created.raise_for_status()
            job_ids.append(created.json()["id"])
        started = time.perf_counter()
        deadline = started + duration_s

        async def uploader() -> None:
            while time.perf_counter() < deadline:
                up = await _timed(
                    report,
                    "upload",
                    client.post("/v1/clips", files={"file": (clip.name, data)}),
                    (201,),
                )
                if up is None:
                    await asyncio.sleep(0.2)
                    continue
                job = await _timed(
                    report,
                    "create",
                    client.post("/v1/jobs", json={"clip_id": up.json()["id"]}),
                    (202,),
                )
                if job is not None:
                    job_ids.append(job.json()["id"])
                    report.jobs_created += 1

        async def poller(i: int) -> None:
            await asyncio.sleep(rng.random() * poll_interval_s)  # spread the robots out
            while time.perf_counter() < deadline:
                job_id = job_ids[(i + rng.randrange(len(job_ids))) % len(job_ids)]
                await _timed(report, "status", client.get(f"/v1/jobs/{job_id}"), (200,))
                await asyncio.sleep(poll_interval_s)

        async def lister() -> None:
            while time.perf_counter() < deadline:
                await _timed(report, "list", client.get("/v1/jobs", params={"limit": 20}), (200,))
                await asyncio.sleep(0.5)

        tasks = [uploader() for _ in range(uploaders)] + [poller(i) for i in range(pollers)] + [lister()]
        await asyncio.gather(*tasks)
        report.duration_s = time.perf_counter() - started
    return report


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_server(workdir: Path, workers: int) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("EIGENSCOPE_")}
    env.update(EIGENSCOPE_DATA_DIR=str(workdir / "data"), EIGENSCOPE_MAX_ACTIVE_JOBS_PER_KEY="100000")
    log = (workdir / "serve.log").open("ab")
    cmd = [sys.executable, "-m", "eigenscope", "serve", "--port", str(port), "--workers", str(workers)]
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{base}/readyz", timeout=1).status_code == 200:
                return proc, base
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)
    raise SystemExit(f"eigenscope serve did not start; see {workdir / 'serve.log'}")


def _make_clip(workdir: Path) -> Path:
    path = workdir / "load.npz"
    subprocess.run(
        [sys.executable, "-m", "eigenscope", "synth", "--out", str(path), "--frames", "48", "--width", "96",
         "--height", "72", "--frequency-hz", "4"],
        check=True,
        capture_output=True,
    )  # fmt: skip
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--server", default=None, help="base URL; default: start `eigenscope serve` here")
    parser.add_argument("--api-key", default=None)
    parser.add_argument("--clip", type=Path, default=None, help="clip to upload (default: a small synth)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds (default 60)")
    parser.add_argument("--uploaders", type=int, default=4)
    parser.add_argument("--pollers", type=int, default=100)
    parser.add_argument("--poll-interval", type=float, default=0.5, help="seconds between one robot's polls")
    parser.add_argument("--workers", type=int, default=1, help="analysis workers of a started server")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="eigenscope-load-") as tmp:
        workdir = Path(tmp)
        clip = args.clip or _make_clip(workdir)
        proc = None
        base = args.server
        if base is None:
            proc, base = start_server(workdir, args.workers)
        try:
            report = asyncio.run(
                run_load(
                    base,
                    clip,
                    duration_s=args.duration,
                    uploaders=args.uploaders,
                    pollers=args.pollers,
                    poll_interval_s=args.poll_interval,
                    api_key=args.api_key,
                )
            )
        finally:
            if proc is not None:
                os.killpg(proc.pid, signal.SIGTERM)
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
    print(json.dumps(report.summary(), indent=2) if args.json else report.text())
    return 1 if report.errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
