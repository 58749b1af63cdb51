"""``./run demo``: start the service, analyse a generated sample clip through its HTTP API, stop.

1. starts ``eigenscope serve`` in embedded mode (no external server) on a free port, data in ./var/demo;
2. renders a synthetic RGB-D clip of a spring-mass object with known frequency, stiffness and mass;
3. uploads it, queues a job, follows its progress and prints the result next to the truth, with the
   artifact URLs, and saves the result and its images in ./var/demo/results/<job id>/;
4. streams the same clip live, as a robot's camera would (``eigenscope stream``): estimates as the frames
   arrive, ``converged`` when the robot may stop recording, the result right after the last frame;
5. stops the server, saying so (or keeps it running with ``--keep-serving``, so that its links work).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_ready(base: str, proc: subprocess.Popen[bytes], timeout_s: float = 90.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"demo: the server exited with status {proc.returncode}")
        try:
            with urllib.request.urlopen(f"{base}/readyz", timeout=2) as resp:
                if resp.status == 200:
                    return
        except OSError:
            pass
        time.sleep(0.2)
    raise SystemExit(f"demo: the server at {base} did not become ready in {timeout_s:g} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-dir", type=Path, default=ROOT / "var" / "demo")
    parser.add_argument("--port", type=int, default=0, help="default: a free port")
    parser.add_argument("--keep-serving", action="store_true", help="leave the server running until Ctrl-C")
    args = parser.parse_args(argv)

    sys.path.insert(0, str(ROOT))
    from eigenscope_client import Client, StepRelease

    from eigenscope.commands.submit import ProgressBar, summarize

    data_dir = args.data_dir.resolve()
    data_dir.mkdir(parents=True, exist_ok=True)
    port = args.port or free_port()
    base = f"http://127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if k != "EIGENSCOPE_REDIS_URL"}
    env.pop("EIGENSCOPE_DATABASE_URL", None)
    env["EIGENSCOPE_DATA_DIR"] = str(data_dir)

    print(
        f"demo: starting eigenscope serve on {base} (embedded broker, SQLite; data in {data_dir})", flush=True
    )
    server = subprocess.Popen(
        [sys.executable, "-m", "eigenscope", "serve", "--port", str(port), "--log-level", "warning"],
        env=env,
        start_new_session=True,
    )
    try:
        wait_ready(base, server)
        clip = data_dir / "sample.npz"
        print("demo: rendering a sample clip (4.5 Hz, 0.8 kg, held by 6 N and released)", flush=True)
        subprocess.run(
            [
                sys.executable, "-m", "eigenscope", "synth", "--out", str(clip), "--frames", "128",
                "--width", "320", "--height", "240", "--frequency-hz", "4.5", "--mass-kg", "0.8",
                "--force-n", "6", "--seed", "7",
            ],
            check=True,
            env=env,
        )  # fmt: skip
        truth = json.loads(clip.with_name("sample.truth.json").read_text())["objects"][0]

        bar = ProgressBar(sys.stdout)
        with Client(base) as client:
            started = time.monotonic()
            uploaded = client.upload_clip(clip)
            print(f"demo: uploaded clip {uploaded.id} ({uploaded.frames} frames)", flush=True)
            job = client.create_job(uploaded.id, excitation=StepRelease(force_n=6.0))
            print(f"demo: job {job.id} queued: {base}/v1/jobs/{job.id}", flush=True)
            job = client.wait(job, timeout=600, on_progress=bar.job)
            bar.done()
            elapsed = time.monotonic() - started
            saved: list[Path] = []
            if job.status == "succeeded" and job.result is not None:
                folder = data_dir / "results" / job.id
                folder.mkdir(parents=True, exist_ok=True)
                for name in ("result.json", *job.result.artifacts):
                    path = client.download_artifact(job, name, folder)
                    assert isinstance(path, Path)
                    saved.append(path)
        print("\n".join(summarize(job, base)))
        print(
            f"truth: f = {truth['eigenfrequency_hz']:.4g} Hz, k = {truth['stiffness_n_per_m']:.4g} N/m, "
            f"m = {truth['mass_kg']:.4g} kg"
        )
        print(f"demo: upload to result in {elapsed:.2f} s")
        if job.status != "succeeded":
            return 1
        results = saved[0].parent
        print(f"demo: the result and its images are saved in {results}/:")
        print("      " + ", ".join(p.name for p in saved))
        print(f"demo: the job's web page (while the server runs): {base}/jobs/{job.id}")
        print(
            "demo: streaming the clip live, as a robot's camera would (eigenscope stream --realtime)",
            flush=True,
        )
        streamed = subprocess.run(
            [
                sys.executable, "-m", "eigenscope", "stream", str(clip), "--server", base, "--force-n", "6",
                "--realtime", "--stop-when-converged",
            ],
            env=env,
            check=False,
        )  # fmt: skip
        if streamed.returncode != 0:
            return 1
        if args.keep_serving:
            print(
                f"demo: still serving on {base}: the job's page {base}/jobs/{job.id}, the web page {base}/, "
                f"API docs {base}/docs; Ctrl-C to stop",
                flush=True,
            )
            with contextlib.suppress(KeyboardInterrupt):
                server.wait()
        else:
            print(
                f"demo: the server stops now, so the URLs above stop answering; the files stay in {results}/ "
                "(`./run demo --keep-serving` keeps the server and its links)",
                flush=True,
            )
        return 0
    finally:
        if server.poll() is None:
            server.send_signal(signal.SIGTERM)
            try:
                server.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(server.pid, signal.SIGKILL)
                server.wait()
        print("demo: server stopped", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
