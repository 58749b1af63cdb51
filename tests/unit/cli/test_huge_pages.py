"""``import eigenscope`` tells numpy not to ask for transparent huge pages (unless the environment says
otherwise): on this VM's kernel the compaction that huge pages cost made an analysis slower
(``bench/devices.py``, device ``hugepage_off``)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CHECK = """
import eigenscope
import numpy
try:
    from numpy._core.multiarray import _get_madvise_hugepage
except ImportError:  # numpy 1
    from numpy.core.multiarray import _get_madvise_hugepage
print(_get_madvise_hugepage())
"""


@pytest.mark.parametrize(("given", "advised"), [(None, "False"), ("1", "True")])
def test_numpy_asks_for_huge_pages_only_when_told_to(given: str | None, advised: str):
    env = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if given is not None:
        env["NUMPY_MADVISE_HUGEPAGE"] = given
    done = subprocess.run([sys.executable, "-c", CHECK], env=env, capture_output=True, text=True, check=True)
    assert done.stdout.split() == [advised]
