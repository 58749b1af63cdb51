"""How fast each malformed or hostile clip of the test corpus is refused.

    python bench/refusal.py

Builds every clip of ``tests/unit/clipio/test_clipio_malformed.py``'s corpus (truncated files, lying
headers, decompression and frame bombs, path traversal, ...), opens and reads it as the test does, and
prints the time until the reader refused it (median of three) with the start of its message. The test
checks the refusals and their messages (a hang fails on its timeout); the times are this script's.
Prints figures measured in this run; never fails on timing.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import eigenscope  # noqa: E402, F401 - one BLAS thread, as in every entry point
from tests.unit.clipio.test_clipio_malformed import CORPUS, _consume  # noqa: E402


def main() -> int:
    rows = []
    with tempfile.TemporaryDirectory(prefix="eigenscope-refusal-") as tmp:
        for i, (build, error, _) in enumerate(CORPUS):
            times = []
            message = ""
            for run in range(3):
                folder = Path(tmp) / f"{i}-{run}"
                folder.mkdir()
                path, kwargs = build(folder)
                started = time.perf_counter()
                try:
                    _consume(path, kwargs)
                except error as exc:
                    message = str(exc)
                else:
                    message = "NOT REFUSED"
                times.append(time.perf_counter() - started)
            rows.append((build.__name__, statistics.median(times), message))
    width = max(len(name) for name, _, _ in rows)
    print(f"{'clip':<{width}}  {'refused in ms':>13}  message")
    for name, seconds, message in sorted(rows, key=lambda r: -r[1]):
        print(f"{name:<{width}}  {seconds * 1000:>13.1f}  {message[:70]}")
    print(f"slowest: {max(r[1] for r in rows):.3f} s; all {len(rows)}: {sum(r[1] for r in rows):.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
