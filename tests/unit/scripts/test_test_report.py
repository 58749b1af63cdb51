"""The end of ``scripts/test.sh`` (``scripts/test_report.py``): each tier's tests and serial time, and the
whole run's wall time, also when the fuzz tier ran beside the others."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_SPEC = importlib.util.spec_from_file_location(
    "test_report", Path(__file__).resolve().parents[3] / "scripts" / "test_report.py"
)
assert _SPEC is not None
assert _SPEC.loader is not None
test_report = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(test_report)


def _junit(path: Path, cases: list[tuple[str, str, float]]) -> None:
    rows = "".join(
        f'<testcase classname="{name}" name="t" time="{seconds}"><properties>'
        f'<property name="tier" value="{tier}"/></properties></testcase>'
        for name, tier, seconds in cases
    )
    path.write_text(f'<?xml version="1.0"?><testsuites><testsuite name="p">{rows}</testsuite></testsuites>')


def _all_line(out: str) -> list[str]:
    return next(line.split() for line in out.splitlines() if line.startswith("all "))


def test_a_fuzz_run_beside_the_others_counts_once_in_the_wall_time(tmp_path, capsys) -> None:
    _junit(tmp_path / "all.xml", [("a", "unit", 2.0), ("b", "accuracy", 30.0), ("c", "integration", 8.0)])
    _junit(tmp_path / "fuzz.xml", [("f", "fuzz", 70.0)])
    # every other tier from t=1000 to t=1500; the fuzz tier from t=1000 to t=1080, beside them
    (tmp_path / "walls").write_text("all 1000.0 1500.0 0\nfuzz 1000.0 1080.0 0\n")
    assert test_report.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    _, tests, wall, serial = _all_line(out)
    assert (tests, float(wall), float(serial)) == ("4", pytest.approx(500.0), pytest.approx(110.0))
    fuzz = next(line.split() for line in out.splitlines() if line.startswith("fuzz "))
    assert fuzz[1:4] == ["1", "80.0", "70.0"]


def test_tiers_run_one_after_another_add_up(tmp_path, capsys) -> None:
    _junit(tmp_path / "unit.xml", [("a", "unit", 2.0)])
    _junit(tmp_path / "e2e.xml", [("b", "e2e", 5.0)])
    (tmp_path / "walls").write_text("unit 100.0 110.0 0\ne2e 110.0 130.0 1\n")
    assert test_report.main([str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert float(_all_line(out)[2]) == pytest.approx(30.0)
    assert "exit 1" in next(line for line in out.splitlines() if line.startswith("e2e "))
