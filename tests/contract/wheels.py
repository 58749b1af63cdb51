"""Building a distribution's wheel for a test, from a private copy of its sources.

setuptools builds in the source tree (``build/``, ``*.egg-info``): two tests building the same
distribution at once (pytest-xdist workers) would empty each other's build folder, and a wheel would
come out without some of its files. Each build therefore works on a copy of what the distribution is
made of.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

#: Never part of a distribution: build products, caches, environments, data.
_SKIP = shutil.ignore_patterns("build", "*.egg-info", "__pycache__", ".venv", "node_modules", "var", ".git")


def copy_sources(source: Path, out: Path, *, parts: tuple[str, ...] | None = None) -> Path:
    """A private copy of the distribution at ``source`` in ``out / "source"``; returns its path.

    ``parts`` names the files and folders of ``source`` the build needs (default: all of it).
    """
    tree = out / "source"
    if parts is None:
        shutil.copytree(source, tree, ignore=_SKIP)
    else:
        tree.mkdir(parents=True)
        for name in parts:
            item = source / name
            if item.is_dir():
                shutil.copytree(item, tree / name, ignore=_SKIP)
            else:
                (tree / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(item, tree / name)
    return tree


def build_wheel(source: Path, out: Path, *, parts: tuple[str, ...] | None = None) -> Path:
    """Build the wheel of the distribution at ``source`` into ``out`` from a private copy of ``parts`` (see
    :func:`copy_sources`); returns the wheel's path."""
    tree = copy_sources(source, out, parts=parts)
    wheels = out / "wheels"
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir", str(wheels), str(tree)],
        capture_output=True,
        text=True,
        timeout=540,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (built,) = wheels.glob("*.whl")
    return built
