"""The one atomic writer (images, result.json): whole files, readable by all, nothing left on failure."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from workers.pipeline._files import write_atomically
from workers.pipeline.model import finite_or_none


def test_writes_bytes_and_text_whole_and_readable(tmp_path: Path):
    target = tmp_path / "result.json"
    assert write_atomically(target, '{"f": "5 Hz ± 0.1"}') == target
    assert target.read_text(encoding="utf-8") == '{"f": "5 Hz ± 0.1"}'
    write_atomically(str(target), b"\x89PNG")  # replaces the old file
    assert target.read_bytes() == b"\x89PNG"
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_a_failed_write_leaves_no_temporary_file(tmp_path: Path):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "taken").mkdir()  # a folder where the file should go: os.replace fails
    with pytest.raises(IsADirectoryError):
        write_atomically(folder / "taken", b"data")
    assert [p.name for p in folder.iterdir()] == ["taken"]
    with pytest.raises(FileNotFoundError):
        write_atomically(tmp_path / "missing" / "x.png", b"data")


@pytest.mark.parametrize(
    ("value", "expected"), [(None, None), (float("nan"), None), (float("inf"), None), (2, 2.0), (-0.5, -0.5)]
)
def test_finite_or_none(value, expected):
    got = finite_or_none(value)
    assert got == expected
    assert got is None or type(got) is float
