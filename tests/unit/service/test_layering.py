"""Dependencies point one way:

    api_schemas  <-  backend  <-  service (HTTP)  and  workers  <-  eigenscope (the command line)

``backend`` (job state, storage, broker, stream transport, settings, errors, logs, metrics, the version)
is what the API and the workers share: it imports neither of them, nor the command line, nor an HTTP
framework. ``service`` never imports ``workers`` (it enqueues by task name) and ``workers`` never imports
``service``; no package imports the command line (``eigenscope``), which sits on top of them all. So the
API process stays free of the task code, the pipeline, OpenCV and FFTW, and a worker process loads no
FastAPI, Starlette or Uvicorn.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import tomllib
from fnmatch import fnmatch
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
SERVICE = ROOT / "service"
FORBIDDEN_IN_API = ("workers", "cv2", "pyfftw")
#: The HTTP stack: the API's alone.
HTTP_FRAMEWORKS = ("fastapi", "starlette", "uvicorn")
#: What each package must not import, anywhere in it (top-level names).
FORBIDDEN_IMPORTS = {
    "backend": ("service", "workers", "eigenscope", *HTTP_FRAMEWORKS),
    "workers": ("service", *HTTP_FRAMEWORKS),
    "service": ("workers",),
}
#: The modules a worker process starts from (Celery tasks, one delivery of a job, live stream sessions).
WORKER_ENTRY_MODULES = ("workers.tasks", "workers.execution", "workers.streams")
#: The command line's package: it imports the others, none imports it.
CLI = "eigenscope"


def _imported_modules(tree: ast.AST) -> list[tuple[int, str]]:
    """Every module ``tree`` imports, anywhere (top level, functions, ``TYPE_CHECKING`` blocks), and every
    string handed to ``importlib.import_module`` / ``__import__``."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("import_module", "__import__") and node.args:
                arg = node.args[0]
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                    found.append((node.lineno, arg.value))
    return found


def test_the_scan_sees_every_kind_of_import() -> None:
    tree = ast.parse(
        "import workers.tasks\n"
        "def f():\n    from workers.celery_app import create_celery\n"
        "import importlib\nimportlib.import_module('workers.runner')\n"
    )
    assert {m for _, m in _imported_modules(tree)} == {
        "workers.tasks",
        "workers.celery_app",
        "importlib",
        "workers.runner",
    }


def _offenders(package: str, forbidden: tuple[str, ...]) -> tuple[list[Path], list[str]]:
    files = sorted((ROOT / package).rglob("*.py"))
    offenders = []
    for path in files:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for line, module in _imported_modules(tree):
            if module.split(".", 1)[0] in forbidden:
                offenders.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    return files, offenders


@pytest.mark.parametrize("package", sorted(FORBIDDEN_IMPORTS))
def test_each_layer_imports_only_what_is_below_it(package: str) -> None:
    files, offenders = _offenders(package, FORBIDDEN_IMPORTS[package])
    assert len(files) > 10, files
    assert not offenders, (
        f"{package} must not import {', '.join(FORBIDDEN_IMPORTS[package])} (what the API and the workers "
        "share lives in backend; the API publishes jobs by task name, see backend/broker.py): "
        + "; ".join(offenders)
    )


def test_the_scan_finds_a_forbidden_import(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "backend").mkdir()
    (tmp_path / "backend" / "leak.py").write_text(
        "def f():\n    from starlette.requests import Request\n    import service.app\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    _, offenders = _offenders("backend", FORBIDDEN_IMPORTS["backend"])
    assert offenders == [
        "backend/leak.py:2 imports starlette.requests",
        "backend/leak.py:3 imports service.app",
    ]


def _loaded_after_importing(modules: tuple[str, ...]) -> list[str]:
    """In a fresh interpreter: import ``modules``, list every module then loaded."""
    script = f"""
import importlib, json, sys
for name in {list(modules)!r}:
    importlib.import_module(name)
print(json.dumps(sorted(sys.modules)))
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    loaded: list[str] = json.loads(out.stdout.strip().splitlines()[-1])
    return loaded


def test_the_workers_load_no_http_framework() -> None:
    loaded = _loaded_after_importing(WORKER_ENTRY_MODULES)
    assert set(WORKER_ENTRY_MODULES) <= set(loaded)
    assert "backend.store" in loaded, "the workers should have loaded the job store"
    bad = [m for m in loaded if m.split(".", 1)[0] in (*HTTP_FRAMEWORKS, "service")]
    assert not bad, f"a worker process loaded {bad}"


def test_the_back_end_loads_no_http_framework() -> None:
    modules = tuple(
        ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        for path in sorted((ROOT / "backend").rglob("*.py"))
    )
    assert "backend.store.jobs" in modules, modules
    loaded = _loaded_after_importing(modules)
    bad = [m for m in loaded if m.split(".", 1)[0] in (*HTTP_FRAMEWORKS, "service", "workers", CLI)]
    assert not bad, f"importing backend loaded {bad}"


def test_building_the_app_and_publishing_a_job_loads_no_worker_code(tmp_path: Path) -> None:
    """In a fresh interpreter: build the app, publish a job on the embedded broker, list what was loaded."""
    script = f"""
import json, sys
from service.app import create_app
from backend.settings import Settings
app = create_app(Settings(data_dir={str(tmp_path / "data")!r}))
app.openapi()
app.state.ctx.queue.publish("job-layering")
app.state.ctx.queue.close()
print(json.dumps(sorted(sys.modules)))
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "service.app" in loaded
    assert "celery" in loaded, "the producer app should have been built"
    bad = [m for m in loaded if m.split(".", 1)[0] in FORBIDDEN_IN_API]
    assert not bad, f"the API process loaded {bad}"
    messages = list((tmp_path / "data" / "broker" / "queue").iterdir())
    assert len(messages) == 1, messages
    body = messages[0].read_text()
    assert "eigenscope.run_job" in body


def _shipped_packages() -> list[Path]:
    """The folders of every top-level package the distributions ship (as pyproject.toml finds them), the
    client's included, but the command line's."""
    found = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    names = {
        path.name
        for path in ROOT.iterdir()
        if (path / "__init__.py").is_file() and any(fnmatch(path.name, p) for p in found["include"])
    }
    folders = [ROOT / name for name in sorted(names - {CLI})]
    return [*folders, ROOT / "client" / "src" / "eigenscope_client"]


def test_no_package_but_the_command_line_imports_it() -> None:
    folders = _shipped_packages()
    assert {f.name for f in folders} >= {
        "api_schemas",
        "backend",
        "service",
        "workers",
        "eigenscope_client",
    }, folders
    offenders = []
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for line, module in _imported_modules(tree):
                if module == CLI or module.startswith(f"{CLI}."):
                    offenders.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert not offenders, (
        "only the command line imports eigenscope (the version is backend.version): " + "; ".join(offenders)
    )
