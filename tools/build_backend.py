"""The root distribution's build backend: setuptools, with the Python client taken from a checkout.

``eigenscope submit`` and ``eigenscope stream`` use the Python client, which is a distribution of its own
(``client/``, ``eigenscope-client``, so that a robot installs it with httpx alone). ``pyproject.toml``
therefore requires it, by its version, as a release on an index must (``eigenscope-client==0.1.0``).

No index holds the client of a checkout, though: built from one (``client/`` beside ``pyproject.toml``,
holding that version), the wheel requires those sources instead (``eigenscope-client @ file:///…/client``),
so that a plain ``pip install .`` installs both. Everything else is setuptools' own:

- an sdist holds no ``client/``, so the wheel built from it (``python -m build``, as for an index) keeps
  the version;
- an editable install keeps it too: it goes beside the client's own editable install
  (``pip install -e ./client -e ".[dev]"``, as ``./run`` does), which a file reference would replace.
"""

from __future__ import annotations

import base64
import hashlib
import re
import zipfile
from pathlib import Path

from setuptools import build_meta as _setuptools
from setuptools.build_meta import (
    build_editable,
    build_sdist,
    get_requires_for_build_editable,
    get_requires_for_build_sdist,
    get_requires_for_build_wheel,
    prepare_metadata_for_build_editable,
)

__all__ = [
    "build_editable",
    "build_sdist",
    "build_wheel",
    "get_requires_for_build_editable",
    "get_requires_for_build_sdist",
    "get_requires_for_build_wheel",
    "prepare_metadata_for_build_editable",
    "prepare_metadata_for_build_wheel",
]

CLIENT = "eigenscope-client"
#: ``Requires-Dist: eigenscope-client[extras]==VERSION`` (extras optional), as setuptools writes it.
_REQUIREMENT = re.compile(rb"^Requires-Dist: eigenscope-client(\[[^\]]*\])?==([^\s;]+)\r?$", re.M)
_CLIENT_VERSION = re.compile(r'^__version__ = "([^"]+)"$', re.M)


def _checkout_client() -> tuple[Path, str] | None:
    """The client's folder beside the sources being built (hooks run in the source tree) and its version,
    or None when there is none (an sdist)."""
    folder = Path("client").resolve()
    version_file = folder / "src" / "eigenscope_client" / "_version.py"
    if not (folder / "pyproject.toml").is_file() or not version_file.is_file():
        return None
    found = _CLIENT_VERSION.search(version_file.read_text(encoding="utf-8"))
    return (folder, found.group(1)) if found else None


def point_at_checkout(metadata: bytes) -> bytes:
    """``metadata`` (a METADATA file) with the client requirement pointing at the checkout's client, when
    there is one of the version required; unchanged otherwise."""
    client = _checkout_client()
    found = _REQUIREMENT.search(metadata)
    if client is None or found is None or found.group(2).decode() != client[1]:
        return metadata
    extras = (found.group(1) or b"").decode()
    line = f"Requires-Dist: {CLIENT}{extras} @ {client[0].as_uri()}".encode()
    return metadata[: found.start()] + line + metadata[found.end() :]


def prepare_metadata_for_build_wheel(
    metadata_directory: str, config_settings: dict[str, object] | None = None
) -> str:
    name: str = _setuptools.prepare_metadata_for_build_wheel(metadata_directory, config_settings)
    path = Path(metadata_directory, name, "METADATA")
    path.write_bytes(point_at_checkout(path.read_bytes()))
    return name


def build_wheel(
    wheel_directory: str,
    config_settings: dict[str, object] | None = None,
    metadata_directory: str | None = None,
) -> str:
    name: str = _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)
    _rewrite_metadata(Path(wheel_directory, name))
    return name


def _rewrite_metadata(wheel: Path) -> None:
    """Apply :func:`point_at_checkout` to the wheel's METADATA, and its RECORD line to match."""
    with zipfile.ZipFile(wheel) as zf:
        members = [(info, zf.read(info)) for info in zf.infolist()]
    metadata = next(i for i, (info, _) in enumerate(members) if info.filename.endswith(".dist-info/METADATA"))
    info, old = members[metadata]
    new = point_at_checkout(old)
    if new == old:
        return
    members[metadata] = (info, new)
    record = next(i for i, (info, _) in enumerate(members) if info.filename.endswith(".dist-info/RECORD"))
    digest = base64.urlsafe_b64encode(hashlib.sha256(new).digest()).rstrip(b"=").decode()
    lines = [
        f"{info.filename},sha256={digest},{len(new)}" if line.split(",", 1)[0] == info.filename else line
        for line in members[record][1].decode().splitlines()
    ]
    members[record] = (members[record][0], ("\n".join(lines) + "\n").encode())
    partial = wheel.with_suffix(".partial")
    with zipfile.ZipFile(partial, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for member, data in members:
            zf.writestr(member, data)
    partial.replace(wheel)
