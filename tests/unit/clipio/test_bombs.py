"""Decompression bombs are refused before they cost memory: by the upload's validation (``workers.probe``)
and by a reader that streams every frame (what a job does), each in a child process whose peak resident
memory is read from ``wait4`` (never a timing).

The bombs are those of the hardening review: a zip whose fourth PNG declares 16000x16000 16-bit RGB (the
worker peaked at 3.9 GB) and an ``.npz`` whose ``rgb`` deflates to 96 frames of 4096x4096 (2.8 GB and
124 s, three times).
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.unit.clipio.bombs import npz_bomb, png_bomb_zip

ROOT = Path(__file__).resolve().parents[3]
#: A refused bomb may cost the interpreter, numpy and the readers, and no more.
PEAK_MB = 300
#: Cap of the children, so that a bomb that gets through costs an error, not this machine's memory.
CHILD_AS_MB = 2048

CONSUME = """
import json, sys
import eigenscope
from workers.pipeline.clipio import open_clip
from workers.pipeline.errors import EigenscopeError
try:
    with open_clip(sys.argv[1]) as reader:
        for frame in reader.frames():
            pass
    print(json.dumps({"code": "read"}))
except EigenscopeError as exc:
    print(json.dumps({"code": exc.code, "detail": str(exc)}))
"""


#: Runs the command given after it and reports the command's peak resident memory. The command is forked
#: from this small launcher, not from pytest: a process forked from a large one would report that one's
#: resident set as its own peak (Linux records the memory it replaces at exec).
LAUNCHER = """
import os, resource, sys
limit = int(sys.argv[1]) * 1024 * 1024
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
pid = os.fork()
if pid == 0:
    os.execv(sys.executable, [sys.executable, *sys.argv[2:]])
_, status, usage = os.wait4(pid, 0)
sys.stderr.write(f"MAXRSS_KB {usage.ru_maxrss}\\n")
sys.exit(os.waitstatus_to_exitcode(status))
"""


def run_measured(argv: list[str], *, timeout_s: float = 300) -> tuple[int, dict[str, str], float]:
    """Run ``python argv`` under an address-space cap; returns exit status, its last JSON line and its
    peak resident memory in MiB (``ru_maxrss`` from ``wait4``)."""
    run = subprocess.run(
        [sys.executable, "-c", LAUNCHER, str(CHILD_AS_MB), *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=timeout_s,
        check=False,
    )
    lines = [line for line in run.stdout.splitlines() if line.startswith("{")]
    verdict = (
        json.loads(lines[-1]) if lines else {"code": "none", "detail": (run.stdout + run.stderr)[-2000:]}
    )
    peak = [line.split()[1] for line in run.stderr.splitlines() if line.startswith("MAXRSS_KB ")]
    assert peak, run.stderr[-2000:]
    return run.returncode, verdict, int(peak[-1]) / 1024


BOMBS: list[tuple[str, Callable[[Path], Path], str]] = [
    ("png-frame-bomb", lambda d: png_bomb_zip(d / "frames.zip"), "declares 16000x16000 pixels"),
    ("npz-deflate-bomb", lambda d: npz_bomb(d / "bomb.npz"), "decompression bomb"),
]


@pytest.fixture(scope="module", params=BOMBS, ids=[b[0] for b in BOMBS])
def bomb(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    name, build, message = request.param
    return build(tmp_path_factory.mktemp(name)), message


@pytest.mark.slow
def test_upload_validation_refuses_the_bomb_in_bounded_memory(bomb: tuple[Path, str]) -> None:
    path, message = bomb
    status, verdict, peak_mb = run_measured(["-m", "workers.probe", str(path), "--memory-mb", "4096"])
    assert verdict.get("code") == "clip-too-large", (status, verdict)
    assert message in verdict["detail"]
    assert status == 3
    assert peak_mb < PEAK_MB, f"the probe peaked at {peak_mb:.0f} MB"
    print(f"\nBOMB {path.name}: probe refused it, peak {peak_mb:.0f} MB")


@pytest.mark.slow
def test_streaming_every_frame_refuses_the_bomb_in_bounded_memory(bomb: tuple[Path, str]) -> None:
    path, message = bomb
    status, verdict, peak_mb = run_measured(["-c", CONSUME, str(path)])
    assert verdict.get("code") == "clip-too-large", (status, verdict)
    assert message in verdict["detail"]
    assert peak_mb < PEAK_MB, f"reading peaked at {peak_mb:.0f} MB"
    print(f"\nBOMB {path.name}: reader refused it, peak {peak_mb:.0f} MB")
