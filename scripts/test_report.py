"""The end of ``scripts/test.sh``: the slowest tests of every tier run and each tier's wall time.

    python scripts/test_report.py REPORTS_FOLDER [--slowest 15]

``REPORTS_FOLDER`` holds JUnit XML reports (``<tier>.xml`` per tier run alone, or ``all.xml`` for every
tier in one run) and ``walls``: one line per run, ``tier-or-all started ended exit-status`` (seconds since
the epoch). A test's tier is its ``tier`` property (``tests/conftest.py`` records it), else its report's
name. A test's time is its setup, call and teardown (a module's services are started in its first test's
setup). "Serial" is the sum of the tier's test times: what it would take one worker; the wall time is
what the run took on the workers it had (one figure for all tiers when they ran together). The total wall
time is from the first run's start to the last one's end: runs that overlapped (the fuzz tier beside the
others) count once.
"""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ET
from pathlib import Path

#: The tiers in the order the README lists them.
_ORDER = ("unit", "accuracy", "contract", "integration", "e2e", "fuzz")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("reports", type=Path)
    parser.add_argument("--slowest", type=int, default=15)
    args = parser.parse_args(argv)

    tests: list[tuple[float, str, str]] = []
    serial: dict[str, float] = {}
    counts: dict[str, int] = {}
    for xml in sorted(args.reports.glob("*.xml")):
        default = xml.name.split(".")[0]  # <tier>.xml
        for case in ET.parse(xml).iter("testcase"):
            tier = next(
                (p.get("value", default) for p in case.iter("property") if p.get("name") == "tier"), default
            )
            seconds = float(case.get("time", "0") or 0)
            name = f"{case.get('classname', '')}::{case.get('name', '')}"
            tests.append((seconds, tier, name))
            serial[tier] = serial.get(tier, 0.0) + seconds
            counts[tier] = counts.get(tier, 0) + 1

    print(f"\n== the {args.slowest} slowest tests (setup + call + teardown)")
    for seconds, tier, name in sorted(tests, reverse=True)[: args.slowest]:
        print(f"{seconds:9.2f} s  {tier:<12} {name}")

    print("\n== wall time per tier")
    print(f"{'tier':<12} {'tests':>6} {'wall s':>9} {'serial s':>9}  result")
    walls = args.reports / "walls"
    runs = [line.split() for line in walls.read_text().splitlines()] if walls.is_file() else []
    together = [r for r in runs if r[0] == "all"]
    for tier, started, ended, status in [r for r in runs if r[0] != "all"]:
        wall = float(ended) - float(started)
        result = "passed" if status == "0" else f"exit {status}"
        print(f"{tier:<12} {counts.get(tier, 0):>6} {wall:>9.1f} {serial.get(tier, 0.0):>9.1f}  {result}")
    for _, started, ended, status in together:
        result = "passed" if status == "0" else f"exit {status}"
        own = {r[0] for r in runs if r[0] != "all"}  # tiers that ran on their own, listed above
        shared = [t for t in counts if t not in own]
        for tier in sorted(shared, key=lambda t: (_ORDER.index(t) if t in _ORDER else len(_ORDER), t)):
            print(f"{tier:<12} {counts[tier]:>6} {'-':>9} {serial[tier]:>9.1f}  (in one run)")
        wall = float(ended) - float(started)
        print(f"{'(one run)':<12} {sum(counts[t] for t in shared):>6} {wall:>9.1f} {'':>9}  {result}")
    total = max(float(r[2]) for r in runs) - min(float(r[1]) for r in runs) if runs else 0.0
    print(f"{'all':<12} {sum(counts.values()):>6} {total:>9.1f} {sum(serial.values()):>9.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
