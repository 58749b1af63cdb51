"""The client distribution installs on its own: its wheel needs httpx only, and in a fresh virtual
environment it installs and works without the pipeline's dependencies (numpy, OpenCV, FFTW, Celery,
matplotlib, PyAV ...)."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.contract.wheels import build_wheel

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

CLIENT = Path(__file__).resolve().parents[2] / "client"
#: What the analysis pipeline and the server need, and a robot's client must not.
HEAVY = {
    "numpy",
    "opencv-python-headless",
    "pyfftw",
    "celery",
    "matplotlib",
    "av",
    "scipy",
    "fastapi",
    "sqlalchemy",
}


def _run(cmd: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=540, check=False, **kwargs)  # type: ignore[call-overload]
    assert done.returncode == 0, f"{' '.join(cmd)}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    built = build_wheel(CLIENT, tmp_path_factory.mktemp("wheel"))
    assert built.name.startswith("eigenscope_client-")
    return built


def test_wheel_requires_httpx_only(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as zf:
        metadata = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        lines = zf.read(metadata).decode().splitlines()
        assert any(n.endswith("eigenscope_client/py.typed") for n in zf.namelist())
    requires = [line.split(":", 1)[1].strip() for line in lines if line.startswith("Requires-Dist:")]
    # What every install needs is httpx alone; live streams (`eigenscope-client[streams]`) add websockets.
    assert [r for r in requires if "extra ==" not in r] == ["httpx>=0.27"]
    assert [r for r in requires if "extra ==" in r] == ['websockets>=13.0; extra == "streams"']
    assert "Requires-Python: >=3.10" in lines


def test_installs_and_runs_in_a_fresh_environment(wheel: Path, tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)])
    python = str(venv / "bin" / "python")
    _run([python, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", str(wheel)])
    listed = _run([python, "-m", "pip", "list", "--format", "json", "--disable-pip-version-check"])
    installed = {p["name"].lower() for p in json.loads(listed.stdout)}
    assert "eigenscope-client" in installed
    assert "httpx" in installed
    assert not (installed & HEAVY), installed & HEAVY
    probe = (
        "import sys, eigenscope_client as ec\n"
        "c = ec.Client('http://127.0.0.1:9', max_retries=0, timeout=2)\n"
        "try:\n"
        "    c.health()\n"
        "except ec.TransportError as e:\n"
        "    print('unreachable:', type(e).__name__)\n"
        "assert not {'numpy', 'cv2', 'celery'} & set(sys.modules)\n"
        "print(ec.__version__)\n"
    )
    out = _run([python, "-c", probe], cwd=tmp_path)
    assert "unreachable: TransportError" in out.stdout
    assert out.stdout.strip().endswith("0.1.0")
