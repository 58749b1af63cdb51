"""A bounded run of the clip readers' fuzzer (``tests/fuzz/fuzz_clips.py``, atheris): about a minute of
coverage-guided mutations of a valid clip of every format, in which only domain errors may escape, in
bounded memory and time. ``EIGENSCOPE_FUZZ_SECONDS`` changes the length; the README says how to run it
for hours."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.fuzz.seeds import write_seeds
from workers.pipeline.clipio import open_clip
from workers.pipeline.clipio.detect import FORMATS

HARNESS = Path(__file__).with_name("fuzz_clips.py")
SECONDS = int(os.environ.get("EIGENSCOPE_FUZZ_SECONDS", "60"))
RSS_LIMIT_MB = 1536


def test_seed_corpus_holds_a_valid_clip_of_every_format(tmp_path: Path) -> None:
    formats = set()
    for path in write_seeds(tmp_path):
        with open_clip(path) as reader:
            frames = sum(1 for _ in reader.frames())
            assert frames == reader.info.frames >= 8, path.name
            formats.add(reader.info.format)
    assert formats == set(FORMATS)


@pytest.mark.slow
@pytest.mark.timeout(SECONDS + 240)
def test_fuzzing_the_readers_finds_nothing(tmp_path: Path) -> None:
    pytest.importorskip("atheris", reason="atheris (a dev dependency) is not installed")
    seeds, corpus = tmp_path / "seeds", tmp_path / "corpus"
    write_seeds(seeds)
    corpus.mkdir()
    cmd = [
        sys.executable,
        str(HARNESS),
        str(corpus),
        str(seeds),
        f"-max_total_time={SECONDS}",
        f"-rss_limit_mb={RSS_LIMIT_MB}",
        "-timeout=30",
        "-seed=20261202",
        f"-artifact_prefix={tmp_path}/",
    ]
    run = subprocess.run(
        cmd, capture_output=True, text=True, timeout=SECONDS + 200, check=False, cwd=tmp_path
    )
    log = run.stdout + run.stderr
    findings = sorted(
        p.name for p in tmp_path.iterdir() if p.name.startswith(("crash-", "oom-", "timeout-", "leak-"))
    )
    assert not findings, f"fuzzing found {findings}:\n{log[-8000:]}"
    assert run.returncode == 0, log[-8000:]
    done = re.search(r"Done (\d+) runs in (\d+) second", log)
    assert done is not None, log[-3000:]
    runs = int(done.group(1))
    assert runs > 100, log[-3000:]  # it did fuzz
    coverage = re.findall(r"cov: (\d+)", log)
    print(
        f"\nFUZZ clip readers: {runs} executions in {done.group(2)} s, coverage {coverage[-1]} edges, "
        "no finding"
    )
