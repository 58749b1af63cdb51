"""Both distributions ship their licence and a ``py.typed`` marker for every package of typed code, and one
version is reported everywhere: the package metadata, ``--version``, the OpenAPI and AsyncAPI documents,
the ``eigenscope_build_info`` metric and the client."""

from __future__ import annotations

import importlib.metadata
import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from tests.contract.wheels import build_wheel

ROOT = Path(__file__).resolve().parents[2]
#: The typed packages of each distribution.
PACKAGES = {
    ROOT: ("api_schemas", "eigenscope", "service", "workers"),
    ROOT / "client": ("eigenscope_client",),
}


#: What each distribution's wheel is built from (None: its whole folder).
PARTS = {
    ROOT: ("pyproject.toml", "README.md", "LICENSE", *PACKAGES[ROOT]),
    ROOT / "client": None,
}


def _wheel(source: Path, out: Path) -> Path:
    return build_wheel(source, out, parts=PARTS[source])


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


def test_one_version_everywhere() -> None:
    import eigenscope_client

    import eigenscope
    from service.app import create_app
    from service.metrics import BuildInfoCollector
    from service.settings import Settings

    version = eigenscope.__version__
    assert importlib.metadata.version("eigenscope") == version
    assert importlib.metadata.version("eigenscope-client") == version
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
