"""The analysis process asks glibc to reuse freed buffers (fewer page faults); settings in the environment
win, and elsewhere than glibc nothing is changed."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CHECK = """
import ctypes, sys
from workers.allocator import tune_malloc
ok = tune_malloc()
print(ok, tune_malloc() is ok)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc settings exist on Linux only")
@pytest.mark.parametrize("env", [{}, {"MALLOC_MMAP_THRESHOLD_": "65536"}])
def test_glibc_accepts_the_settings_once_per_process(env: dict[str, str]):
    result = subprocess.run(
        [sys.executable, "-c", CHECK], env={**os.environ, **env}, capture_output=True, text=True, check=True
    )
    assert result.stdout.split() == ["True", "True"]


def test_the_settings_are_not_applied_off_linux(monkeypatch: pytest.MonkeyPatch):
    from workers import allocator

    allocator.tune_malloc.cache_clear()
    monkeypatch.setattr(allocator.sys, "platform", "darwin")
    try:
        assert allocator.tune_malloc() is False
    finally:
        allocator.tune_malloc.cache_clear()
