"""A short, bounded form of ``bench/load.py``: 3 concurrent uploaders (each upload queues a job) and 50
robots polling job status twice a second for 8 s, against ``eigenscope serve`` on loopback while its
worker is busy. No request may fail or be throttled. How fast the status stays is a figure of
``bench/load.py`` (printed here too, never asserted: the suite shares its cores with other work)."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import service_harness as h

pytestmark = [pytest.mark.integration, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]


def load_bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("eigenscope_bench_load", ROOT / "bench" / "load.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


KEY = "load-test-key-0123456789"


@pytest.fixture(scope="module")
def keyed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """``eigenscope serve`` that requires an API key."""
    service = h.start_embedded(
        tmp_path_factory.mktemp("keyed"), api_keys=KEY, max_active_jobs_per_key="100000"
    )
    yield service
    service.stop()


def test_submit_with_and_without_a_key(keyed: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    cmd = [sys.executable, "-m", "eigenscope", "submit", str(truth_clip[0]), "--server", keyed.base_url]
    refused = subprocess.run(cmd, capture_output=True, text=True, timeout=60, check=False)
    assert refused.returncode != 0
    assert "401" in refused.stderr
    assert "--api-key" in refused.stderr
    assert "Traceback" not in refused.stderr
    done = subprocess.run(
        [*cmd, "--wait", "--json", "--force-n", "5"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "EIGENSCOPE_API_KEY": KEY},
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["status"] == "succeeded"


def test_load_zero_errors(keyed: h.LiveService, truth_clip: tuple[Path, Any]) -> None:
    bench = load_bench()
    service = keyed
    report = asyncio.run(
        bench.run_load(
            service.base_url,
            truth_clip[0],
            duration_s=8.0,
            uploaders=3,
            pollers=50,
            poll_interval_s=0.5,
            api_key=KEY,
        )
    )
    busy = service.client.get(
        "/v1/jobs", params={"status": ["running", "queued"]}, headers={"Authorization": f"Bearer {KEY}"}
    ).json()["items"]
    print("\nLOAD " + report.text().replace("\n", "\nLOAD "))
    summary = report.summary()
    assert summary["errors"] == 0, summary["first_errors"]
    assert summary["throttled"] == 0
    status = summary["by_kind"]["status"]
    # 50 robots polling every 0.5 s for 8 s: ~800 on an idle machine, but each waits for its answer
    # before its next poll, so a loaded machine makes fewer (92 in a run beside three other suites):
    # every robot polled.
    assert status["requests"] >= 50, summary
    assert summary["by_kind"]["upload"]["requests"] >= 3
    assert busy, "the worker should still have had jobs to do while the status was polled"
