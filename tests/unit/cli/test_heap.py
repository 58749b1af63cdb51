"""The ``eigenscope`` executable settles its heap (:mod:`eigenscope._heap`): after ``analyze`` has imported
what it needs and before the process exits, every object alive is moved out of the cyclic collector's
reach; garbage made later is still collected. A process that calls :func:`eigenscope.cli.main` itself
keeps its collector as it was (``bench/devices.py``, device ``gc_freeze``)."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from pathlib import Path

import pytest

#: As the executable runs ``eigenscope analyze``, with the analysis itself replaced by a stub that notes
#: how many objects were frozen when it was called.
CONSOLE = """
import gc, json, sys, weakref
import eigenscope
from eigenscope import cli
import workers.runner

class Node:
    pass

def cycle():
    a, b = Node(), Node()
    a.other, b.other = b, a
    return [a, b]

report = {}

def analysis(*args, **kwargs):
    report["frozen_at_analysis"] = gc.get_freeze_count()
    raise RuntimeError("stub analysis")

workers.runner.run_analysis = analysis
held = cycle()  # alive while the executable runs: frozen with the rest
held_ref = weakref.ref(held[0])
clip, out = sys.argv[1:3]
sys.argv = ["eigenscope", "analyze", clip, "--out", out]
try:
    cli.console_main()
except SystemExit as exc:
    report["status"] = exc.code
report["frozen_at_exit"] = gc.get_freeze_count()
del held
later = cycle()
later_ref = weakref.ref(later[0])
del later
gc.collect()
report["frozen_cycle_kept"] = held_ref() is not None
report["later_cycle_collected"] = later_ref() is None
print(json.dumps(report))
"""


def test_the_executable_settles_its_heap_after_the_imports_and_before_exit(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-c", CONSOLE, str(tmp_path / "clip.npz"), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=True,
    )
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["status"] == 70, done.stderr  # the stub's error, reported as an internal one
    assert "stub analysis" in done.stderr
    # the imports' objects (numpy, OpenCV, pydantic, the pipeline: tens of thousands) before the analysis
    assert report["frozen_at_analysis"] > 10_000, report
    assert report["frozen_at_exit"] >= report["frozen_at_analysis"], report
    # frozen objects are out of the collector's reach; what is made later is collected as before
    assert report["frozen_cycle_kept"], report
    assert report["later_cycle_collected"], report


def test_a_process_that_calls_main_itself_keeps_its_collector(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import workers.runner
    from eigenscope import cli

    calls: list[int] = []

    def analysis(*args: object, **kwargs: object) -> None:
        calls.append(gc.get_freeze_count())
        raise RuntimeError("stub analysis")

    monkeypatch.setattr(workers.runner, "run_analysis", analysis)
    frozen = gc.get_freeze_count()
    code = cli.main(["analyze", str(tmp_path / "clip.npz"), "--out", str(tmp_path / "out")])
    assert code == 70
    assert calls == [frozen]
    assert gc.get_freeze_count() == frozen
