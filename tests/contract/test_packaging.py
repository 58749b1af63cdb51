"""Both distributions ship their licence and a ``py.typed`` marker for every package of typed code, and one
version is reported everywhere: the package metadata, ``--version``, the OpenAPI and AsyncAPI documents,
the ``eigenscope_build_info`` metric and the client.

The root distribution requires the client (``eigenscope submit`` and ``stream`` use it): a release build
by its version, a build from a checkout by the checkout's ``client/`` (``tools/build_backend.py``), so
that a plain ``pip install .`` in a fresh environment gives commands that work.
"""

from __future__ import annotations

import importlib.metadata
import json
import socket
import subprocess
import sys
import tarfile
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest

from backend.version import __version__
from tests.contract.wheels import build_wheel, copy_sources

ROOT = Path(__file__).resolve().parents[2]
#: The typed packages of each distribution.
PACKAGES = {
    ROOT: ("api_schemas", "backend", "eigenscope", "service", "workers"),
    ROOT / "client": ("eigenscope_client",),
}


#: What each distribution's wheel is built from (None: its whole folder); the root's, as in a checkout,
#: with the client's sources beside it.
PARTS = {
    ROOT: (
        "pyproject.toml",
        "README.md",
        "LICENSE",
        "MANIFEST.in",
        "tools/build_backend.py",
        "client",
        *PACKAGES[ROOT],
    ),
    ROOT / "client": None,
}
#: The client requirement in the root's metadata, as a release has it.
RELEASED_CLIENT = f"eigenscope-client[streams]=={__version__}"


def _wheel(source: Path, out: Path) -> Path:
    return build_wheel(source, out, parts=PARTS[source])


def _requirements(metadata: str) -> list[str]:
    return [
        line.split(":", 1)[1].strip() for line in metadata.splitlines() if line.startswith("Requires-Dist:")
    ]


def _run(cmd: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=540, check=False, **kwargs)  # type: ignore[call-overload]
    assert done.returncode == 0, f"{' '.join(cmd)}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


def test_the_sources_have_a_licence_and_markers() -> None:
    for source, packages in PACKAGES.items():
        assert (source / "LICENSE").read_text().startswith("MIT License"), source
        base = source / "src" if (source / "src").is_dir() else source
        for package in packages:
            assert (base / package / "py.typed").is_file(), package


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("source", list(PACKAGES), ids=["eigenscope", "eigenscope-client"])
def test_each_wheel_ships_its_licence_and_py_typed(source: Path, tmp_path: Path) -> None:
    with zipfile.ZipFile(_wheel(source, tmp_path)) as zf:
        names = zf.namelist()
        licence = [n for n in names if n.endswith("LICENSE") and ".dist-info/" in n]
        assert licence, names
        assert zf.read(licence[0]).decode().startswith("MIT License")
        metadata = zf.read(next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
        assert "License-Expression: MIT" in metadata
        for package in PACKAGES[source]:
            assert f"{package}/py.typed" in names, package
    if source == ROOT:  # built from a checkout: the client comes from the client/ beside it
        client = (tmp_path / "source" / "client").as_uri()
        assert f"eigenscope-client[streams] @ {client}" in _requirements(metadata)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_release_build_requires_the_client_by_its_version(tmp_path: Path) -> None:
    """``python -m build`` builds the sdist, then the wheel from it, as for an index: the sdist holds the
    build backend and not the client, and the wheel requires the client's release of the same version."""
    checkout = copy_sources(ROOT, tmp_path, parts=PARTS[ROOT])
    dist = tmp_path / "dist"
    _run([sys.executable, "-m", "build", "--outdir", str(dist), str(checkout)])
    (sdist,) = dist.glob("eigenscope-*.tar.gz")
    with tarfile.open(sdist) as tf:
        names = {name.split("/", 1)[1] for name in tf.getnames() if "/" in name}
    assert "tools/build_backend.py" in names
    assert not [n for n in names if n.startswith("client/")], names
    (wheel,) = dist.glob("eigenscope-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        metadata = zf.read(next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    assert RELEASED_CLIENT in _requirements(metadata)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_plain_install_of_a_checkout_gives_client_commands_that_work(tmp_path: Path) -> None:
    """``pip install .`` (no ``./run``, no ``-e ./client``) in a fresh environment: ``submit`` and ``stream``
    reach for the server and, with nothing listening, say so on one line with status 2."""
    checkout = copy_sources(ROOT, tmp_path, parts=PARTS[ROOT])
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", str(venv)])
    _run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-compile", str(checkout)],
        cwd=tmp_path,
    )
    clip = tmp_path / "clip.npz"
    rng = np.random.default_rng(0)
    np.savez(clip, rgb=rng.integers(0, 255, (16, 48, 64, 3), dtype=np.uint8), fps=np.float64(30.0))
    server = f"http://127.0.0.1:{_closed_port()}"
    for command in ("submit", "stream"):
        done = subprocess.run(
            [str(venv / "bin" / "eigenscope"), command, str(clip), "--server", server],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
            cwd=tmp_path,
        )
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2, (command, done.returncode, done.stderr)
        assert len(lines) == 1, (command, done.stderr)
        assert lines[0].startswith(f"eigenscope {command}: error: "), lines
        assert server in lines[0], lines


def test_one_version_everywhere() -> None:
    import eigenscope_client

    import eigenscope
    from backend.metrics import BuildInfoCollector
    from backend.settings import Settings
    from service.app import create_app

    version = eigenscope.__version__
    assert importlib.metadata.version("eigenscope") == version
    assert importlib.metadata.version("eigenscope-client") == version
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert f"eigenscope-client[streams]=={version}" in pyproject["project"]["dependencies"]
    assert eigenscope_client.__version__ == version
    spec = json.loads((ROOT / "openapi" / "openapi.json").read_text())
    assert spec["info"]["version"] == version
    asyncapi = json.loads((ROOT / "openapi" / "asyncapi.json").read_text())
    assert asyncapi["info"]["version"] == version
    app = create_app(Settings(data_dir=Path("/nonexistent/eigenscope-version-check")))
    assert app.version == version
    (family,) = BuildInfoCollector("api").collect()
    assert family.samples[0].labels["version"] == version
    cli = subprocess.run(
        [sys.executable, "-m", "eigenscope", "--version"], capture_output=True, text=True, check=True
    )
    assert cli.stdout.strip() == f"eigenscope {version}"
