"""Schemathesis against ``openapi/openapi.json`` on a live uvicorn process: no 5xx, and every response
matches the spec (status declared, body schema, content type, headers).

The app runs with an API key (so the authorised paths are exercised) and the embedded broker; each
operation gets a bounded number of generated cases, in every phase (examples, coverage, fuzzing,
stateful).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import service_harness as h

pytestmark = [pytest.mark.integration, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
SPEC = ROOT / "openapi" / "openapi.json"
KEY = "schemathesis-key-0123456789"
CHECKS = "not_a_server_error,status_code_conformance,content_type_conformance,response_schema_conformance"


@pytest.mark.timeout(300)
def test_schemathesis_finds_no_server_error_and_no_spec_mismatch(tmp_path: Path) -> None:
    port = h.free_port()
    # Long-polls end within the requests' timeout (a generated `wait` may ask for the server's cap).
    env = h.base_env(
        tmp_path / "data", api_keys=KEY, max_upload_mb="4", probe_timeout_s="20", long_poll_max_s="10"
    )
    service = h.LiveService(f"http://127.0.0.1:{port}", tmp_path / "data", env)
    try:
        h.start_api(service, port=port)
        cli = Path(sys.executable).with_name("st")
        cmd = [
            str(cli),
            "run",
            str(SPEC),
            "--url",
            service.base_url,
            "--checks",
            CHECKS,
            "--max-examples",
            "20",
            "--seed",
            "20260101",
            "--header",
            f"Authorization: Bearer {KEY}",
            "--request-timeout",
            "30",
            "--no-color",
        ]
        run = subprocess.run(
            cmd, capture_output=True, text=True, timeout=280, check=False, cwd=tmp_path, env=env
        )
        api_log = service.logs()
    finally:
        service.stop()
    output = run.stdout + run.stderr
    assert run.returncode == 0, f"{output[-6000:]}\n{api_log[-4000:]}"
    generated = re.search(r"(\d+) generated", output)
    assert generated is not None, output[-3000:]
    cases = int(generated.group(1))
    assert cases >= 200, output[-3000:]
    assert "Traceback" not in api_log
    print(f"\nSCHEMATHESIS {cases} cases, checks {CHECKS}: no failure")
