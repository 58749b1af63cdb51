"""The pure pipeline (``workers/pipeline/**``) imports no process, signal or framework machinery.

How a process runs the pipeline (helper processes, forks, priorities, exit paths, Celery, the API) lives in
``workers/`` and ``eigenscope/``; the pipeline is ndarrays and dataclasses in and out. Threads used for
computing (flow pairs, FFT blocks, a live window) are allowed. This scans every module's source, so a new
import of a forbidden module fails here with the file and line to change.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PIPELINE = Path(__file__).resolve().parents[3] / "workers" / "pipeline"

#: Top-level modules the pipeline never imports (processes, signals, scheduling, frameworks, the service).
FORBIDDEN_MODULES = frozenset(
    {
        "multiprocessing",
        "subprocess",
        "signal",
        "sched",
        "concurrent.futures.process",
        "celery",
        "fastapi",
        "starlette",
        "redis",
        "kombu",
        "service",
        "backend",
        "api_schemas",
    }
)
#: Attributes of ``os`` that start, end, signal or schedule processes.
FORBIDDEN_OS = frozenset(
    {
        "_exit",
        "fork",
        "forkpty",
        "kill",
        "killpg",
        "setpgid",
        "setsid",
        "nice",
        "sched_setscheduler",
        "sched_setaffinity",
        "spawnv",
        "spawnl",
        "execv",
        "execve",
        "system",
        "popen",
        "posix_spawn",
        "waitpid",
    }
)


def _modules() -> list[Path]:
    files = sorted(PIPELINE.rglob("*.py"))
    assert len(files) > 20, f"found only {len(files)} modules under {PIPELINE}"
    return files


def _violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
            if node.module == "os":
                names += [f"os.{alias.name}" for alias in node.names]
        for name in names:
            parts = name.split(".")
            prefixes = {".".join(parts[: i + 1]) for i in range(len(parts))}
            if prefixes & FORBIDDEN_MODULES:
                found.append(f"line {node.lineno}: imports {name}")
            if parts[0] == "workers" and len(parts) > 1 and parts[1] != "pipeline":
                found.append(f"line {node.lineno}: imports {name} (the pipeline imports nothing of workers/)")
            if parts[0] == "os" and len(parts) == 2 and parts[1] in FORBIDDEN_OS:
                found.append(f"line {node.lineno}: imports {name}")
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == "os"
            and node.attr in FORBIDDEN_OS
        ):
            found.append(f"line {node.lineno}: uses os.{node.attr}")
    return found


@pytest.mark.parametrize("path", _modules(), ids=lambda p: str(p.relative_to(PIPELINE)))
def test_pipeline_module_imports_no_process_machinery(path: Path):
    violations = _violations(path)
    assert not violations, (
        f"{path.relative_to(PIPELINE.parents[1])} must stay pure: "
        + "; ".join(violations)
        + " -- move process handling to workers/ (e.g. workers/drawing.py)"
    )


def test_the_scan_finds_what_it_forbids(tmp_path: Path):
    """The scanner itself: each kind of violation is reported (so the test above can fail)."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "import os\nimport subprocess\nfrom multiprocessing import Pool\n"
        "from workers.drawing import draw_all\n"
        "from os import fork\nimport celery.app\ndef f():\n    os._exit(0)\n"
    )
    found = " ".join(_violations(bad))
    for expected in ("subprocess", "multiprocessing", "workers.drawing", "os.fork", "celery.app", "os._exit"):
        assert expected in found, (expected, found)
    good = tmp_path / "good.py"
    good.write_text(
        "import os\nimport threading\nfrom workers.pipeline.model import Analysis\nos.path.join('a')\n"
    )
    assert _violations(good) == []
