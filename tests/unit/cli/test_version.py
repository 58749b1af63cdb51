"""The version is written once, in ``backend/version.py``; the installed metadata and
``eigenscope.__version__`` read it from there."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys

import eigenscope


def test_the_installed_metadata_has_the_package_version():
    assert eigenscope.__version__ == importlib.metadata.version("eigenscope")


def test_the_command_line_prints_it():
    out = subprocess.run(
        [sys.executable, "-m", "eigenscope", "--version"], capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == f"eigenscope {eigenscope.__version__}"
