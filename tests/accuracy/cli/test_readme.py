"""The README's example: its command runs on the example clip it names, and prints what the README shows.

The README's sample output is compared line by line with what the command prints today: the same words
and units in the same order, and each number within a tolerance (the last digits of a measurement may
move with the machine's floating point, not its fields or their meaning).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
README = ROOT / "README.md"
COMMAND = "eigenscope analyze docs/example/spring.zip"
NUMBER = re.compile(r"-?\d+(?:\.\d+)?")


def readme_example() -> tuple[list[str], list[str]]:
    """(the example command's arguments, the sample output's lines), as the README has them."""
    blocks = re.findall(r"```(\w*)\n(.*?)```", README.read_text(), flags=re.DOTALL)
    for i, (_, body) in enumerate(blocks):
        command = next((line for line in body.splitlines() if line.startswith(COMMAND)), None)
        if command is not None:
            return shlex.split(command), blocks[i + 1][1].rstrip("\n").splitlines()
    raise AssertionError(f"the README has no `{COMMAND}` example any more")


def shape(line: str) -> str:
    """The line with its numbers replaced by ``#``."""
    return NUMBER.sub("#", line)


def test_the_example_clip_is_small_and_compressed() -> None:
    clip = ROOT / "docs" / "example" / "spring.zip"
    assert clip.stat().st_size < 3_000_000
    assert (ROOT / "docs" / "example" / "spring.truth.json").is_file()


def test_the_readme_example_prints_what_the_readme_shows(tmp_path: Path) -> None:
    args, sample = readme_example()
    assert args[:2] == ["eigenscope", "analyze"]
    out = args[args.index("--out") + 1]
    args[args.index("--out") + 1] = str(tmp_path / out)
    done = subprocess.run(
        [sys.executable, "-m", "eigenscope", *args[1:]],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
        timeout=600,  # a guard against a hang, not a bound on the time
    )
    assert done.returncode == 0, done.stderr
    printed = done.stdout.replace(str(tmp_path / out), out).rstrip("\n").splitlines()
    assert [shape(line) for line in printed] == [shape(line) for line in sample], (printed, sample)
    for got, shown in zip(printed, sample, strict=True):
        for a, b in zip(NUMBER.findall(got), NUMBER.findall(shown), strict=True):
            assert float(a) == pytest.approx(float(b), rel=0.01, abs=1e-3), (got, shown)
    assert (tmp_path / out / "result.json").is_file()
    from workers.pipeline.figures import ARTIFACT_FILES

    pngs = {name for name in ARTIFACT_FILES.values() if name.endswith(".png")}
    assert {p.name for p in (tmp_path / out).glob("*.png")} == pngs  # the mask, the figures and modes.png
