"""Eigenscope against the field peer (issue 26): pyidi 1.4's Lucas-Kanade on a grid of points over the clip's
hand-placed region of interest, frames decoded once into an array, against ``eigenscope analyze`` on the
whole frame of the same frames, in alternating rounds (each in a fresh process), with the wall time and the
peak memory (largest resident set) of each and their ratios.

pyidi is a bench-only extra (``pip install -e ".[bench]"``, or a separate environment given with
``--peer-python``); it is never a runtime dependency.

    python bench/peer.py [--clip PATH --roi PATH --fps 1000 --frames 1000 --points 108 --rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORKS = ROOT.parent / "shared" / "data" / "real" / "tuning-forks"


def _run(command: list[str]) -> tuple[float, float, str]:
    """Wall seconds, peak resident MiB and standard output of ``command`` in a child process (its output
    goes to files: a pipe nobody reads while the child runs fills up and stops it)."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        started = time.perf_counter()
        process = subprocess.Popen(command, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(process.pid, 0)
        seconds = time.perf_counter() - started
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"peer.py: {command[0]} failed: {stderr.strip().splitlines()[-1:]}")
    return seconds, usage.ru_maxrss / 1024, stdout


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clip", type=Path, default=FORKS / "tuning_hz32_fps1000_50-1_640x420.mp4")
    parser.add_argument("--roi", type=Path, default=FORKS / "tuning_hz32_fps1000.roi")
    parser.add_argument("--fps", type=float, default=1000.0)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--points", type=int, default=108)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--peer-python", default=sys.executable, help="a Python with pyidi installed")
    args = parser.parse_args()
    if not args.clip.is_file():
        raise SystemExit(f"peer.py: {args.clip} is missing (the shared footage beside the checkout)")
    peer = [
        args.peer_python,
        str(ROOT / "bench" / "_pyidi_peer.py"),
        str(args.clip),
        str(args.roi),
        str(args.fps),
        str(args.frames),
        str(args.points),
    ]
    ours_bin = str(Path(sys.executable).with_name("eigenscope"))
    figures: dict[str, list[tuple[float, float]]] = {"pyidi": [], "eigenscope": []}
    found: dict[str, float] = {}
    for r in range(args.rounds):
        order = ["pyidi", "eigenscope"] if r % 2 == 0 else ["eigenscope", "pyidi"]
        for who in order:
            if who == "pyidi":
                seconds, mib, out = _run(peer)
                found["pyidi"] = json.loads(out.strip().splitlines()[-1])["frequency_hz"]
            else:
                with tempfile.TemporaryDirectory() as out_dir:
                    command = [ours_bin, "analyze", str(args.clip), "--fps", str(args.fps), "--frames"]
                    command += [str(args.frames), "--start-frame", "0", "--out", out_dir, "--json"]
                    seconds, mib, out = _run(command)
                found["eigenscope"] = float(json.loads(out)["eigenfrequency_hz"])
            figures[who].append((seconds, mib))
            print(f"round {r + 1}: {who:10s} {seconds:6.2f} s  {mib:7.0f} MiB peak", flush=True)
    print(f"\n{'':12s} {'median s':>9s} {'peak MiB':>9s} {'frequency':>10s}")
    for who, rows in figures.items():
        print(
            f"{who:12s} {statistics.median(s for s, _ in rows):9.2f} {max(m for _, m in rows):9.0f} "
            f"{found[who]:10.3f}"
        )
    ratios = [e[0] / p[0] for e, p in zip(figures["eigenscope"], figures["pyidi"], strict=True)]
    print(f"\ntime ratio eigenscope / pyidi, median of the rounds: {statistics.median(ratios):.2f}")
    memory = max(m for _, m in figures["eigenscope"]) / max(m for _, m in figures["pyidi"])
    print(f"peak memory ratio eigenscope / pyidi: {memory:.2f}")


if __name__ == "__main__":
    main()
