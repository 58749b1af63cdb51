"""Benchmark: ``eigenscope analyze`` end to end, this checkout against earlier revisions.

Each revision is checked out in a temporary git worktree and run with this checkout's interpreter, in a
fresh process per run, round after round with the order reversed every other round (this VM is noisy:
compare the median of the per-round ratios of one run, never figures of different runs). Per revision
it prints the median wall seconds, the median per-round ratio to the first revision, and the median
seconds of each stage the result reports (``timings_s``; "outside" is the rest: start-up, reading, exit).

    python bench/versions.py 3fdd940                 # the revision before issue 18 against this checkout
    python bench/versions.py 3fdd940 HEAD --rounds 9 --size 320x240x128

Timing never fails anything: this prints figures, it does not assert them.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from devices import make_clip  # noqa: E402 - the same clip as the devices' figures


def _run(tree: Path, clip: Path, out: Path) -> tuple[float, dict[str, float]]:
    shutil.rmtree(out, ignore_errors=True)
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); sys.argv = ['eigenscope', 'analyze', sys.argv[2], "
        "'--out', sys.argv[3], '--force-n', '10']\n"
        "from eigenscope.cli import console_main; console_main()\n"
    )
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", code, str(tree), str(clip), str(out)],
        cwd=tree,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - started
    timings = json.loads((out / "result.json").read_text()).get("timings_s") or {}
    return wall, timings


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("revisions", nargs="+", help="git revisions; 'here' is this checkout as it is")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--size", default="640x480x256", help="clip WxHxFRAMES")
    args = parser.parse_args()
    names = list(dict.fromkeys([*args.revisions, "here"]))
    with tempfile.TemporaryDirectory(prefix="eigenscope-versions-") as tmp_name:
        tmp = Path(tmp_name)
        trees: dict[str, Path] = {"here": ROOT}
        try:
            for rev in names:
                if rev == "here":
                    continue
                tree = tmp / f"tree-{len(trees)}"
                subprocess.run(
                    ["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), rev],
                    check=True,
                    capture_output=True,
                )
                trees[rev] = tree
            clip = tmp / "clip.npz"
            make_clip(args.size, clip)
            for name in names:  # one warm-up run each (page cache, bytecode)
                _run(trees[name], clip, tmp / "out")
            walls: dict[str, list[float]] = {n: [] for n in names}
            stages: dict[str, list[dict[str, float]]] = {n: [] for n in names}
            for r in range(args.rounds):
                for name in names if r % 2 == 0 else names[::-1]:
                    wall, timings = _run(trees[name], clip, tmp / "out")
                    walls[name].append(wall)
                    stages[name].append(timings)
                print(
                    f"round {r + 1}: " + ", ".join(f"{n} {walls[n][-1]:.3f} s" for n in names),
                    file=sys.stderr,
                    flush=True,
                )
            base = names[0]
            print(
                f"eigenscope analyze, {args.size}, {args.rounds} rounds (ratio: median per-round to {base})"
            )
            for name in names:
                ratio = statistics.median(a / b for a, b in zip(walls[name], walls[base], strict=True))
                keys = list(stages[name][0])
                per_stage = {
                    k: round(statistics.median(t.get(k, 0.0) for t in stages[name]), 3) for k in keys
                }
                outside = statistics.median(
                    w - sum(t.values()) for w, t in zip(walls[name], stages[name], strict=True)
                )
                print(
                    f"{name:>12}: {statistics.median(walls[name]):.3f} s, ratio {ratio:.3f}; stages "
                    f"{per_stage}, outside {outside:.3f}"
                )
        finally:
            for name, tree in trees.items():
                if name != "here":
                    subprocess.run(
                        ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)],
                        check=False,
                        capture_output=True,
                    )


if __name__ == "__main__":
    main()
