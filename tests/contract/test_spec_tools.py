"""``openapi/openapi.json`` through the tools client authors use, from npm (``tools/spec``): Redocly's lint
finds no error, and the TypeScript types openapi-typescript generates compile under ``tsc --strict`` with a
minimal job request (and refuse an incomplete one). A TypeScript program on openapi-fetch
(``ts/client.ts``: upload, job, long-poll from the 202's ETag, result, list, artifact) compiles under
``--strict`` with the types of ``tools/spec/generate-types.mjs`` (binary parts as ``Blob``), and node runs
it against a live server.

The tools are installed by ``npm ci`` from ``tools/spec/package-lock.json`` (``./run`` does it; this module
does it when they are missing). Without node and npm the tests skip here and fail in CI.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import service_harness as h
from conftest import LIVE

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parents[2]
TOOLS = ROOT / "tools" / "spec"
SPEC = ROOT / "openapi" / "openapi.json"
CLIENT_PROGRAM = Path(__file__).with_name("ts") / "client.ts"
#: tsc's options: strict, ES modules as a bundler resolves them.
TSC_STRICT = ["--strict", "--target", "es2022", "--module", "esnext", "--moduleResolution", "bundler"]
#: ... and for the openapi-fetch program, the DOM's and node's globals.
TSC_PROGRAM = [*TSC_STRICT, "--lib", "es2022,dom", "--types", "node", "--skipLibCheck"]

#: A TypeScript module a client author might write against the generated types.
CLIENT_TS = """\
import type { components, paths } from "./schema";

type JobCreate = components["schemas"]["JobCreate"];
type Job = paths["/v1/jobs/{job_id}"]["get"]["responses"][200]["content"]["application/json"];
type Problem = components["schemas"]["Problem"];

// The smallest useful requests: every defaulted field left out.
export const held: JobCreate = { clip_id: "abc", excitation: { type: "step_release", force_n: 10 } };
export const struck: JobCreate = {
  clip_id: "abc",
  excitation: { type: "impulse", impulse_ns: 0.5 },
  parameters: { fps: 240 },
  callback_url: "https://robot.lab/done",
};
export const bare: JobCreate = { clip_id: "abc" };

// @ts-expect-error force_n is required: the types are strict where the API is
export const incomplete: JobCreate = { clip_id: "abc", excitation: { type: "step_release" } };

export function frequency(job: Job): number | null | undefined {
  return job.result?.eigenfrequency_hz;
}
export const notFound: Problem = { type: "about:blank", title: "Not found", status: 404 };
"""


def _tool_env() -> dict[str, str]:
    return {
        **os.environ,
        "NO_COLOR": "1",
        "REDOCLY_TELEMETRY": "off",
        "REDOCLY_SUPPRESS_UPDATE_NOTICE": "true",
    }


@pytest.fixture(scope="module")
def bin_dir() -> Path:
    """``tools/spec/node_modules/.bin``, installed with ``npm ci`` when missing or older than the lock."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        message = (
            "node and npm are needed for the spec lint and the TypeScript check (apt-get install nodejs npm)"
        )
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(f"CI requires {message}", pytrace=False)
        pytest.skip(message)
    stamp = TOOLS / "node_modules" / ".package-lock.json"
    if not stamp.is_file() or stamp.stat().st_mtime < (TOOLS / "package-lock.json").stat().st_mtime:
        done = subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund", "--loglevel=error"],
            cwd=TOOLS,
            capture_output=True,
            text=True,
            timeout=540,
            check=False,
            env=_tool_env(),
        )
        assert done.returncode == 0, f"npm ci failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return TOOLS / "node_modules" / ".bin"


def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        cmd, cwd=cwd, capture_output=True, text=True, timeout=300, check=False, env=_tool_env()
    )


def test_redocly_lint_finds_no_error(bin_dir: Path) -> None:
    done = _run([str(bin_dir / "redocly"), "lint", str(SPEC), "--config", str(TOOLS / "redocly.yaml")], TOOLS)
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-6000:]
    assert "Your API description is valid" in output, output[-3000:]
    print(f"\nREDOCLY {output.strip().splitlines()[-1]}")


def test_typescript_client_compiles_strict(bin_dir: Path, tmp_path: Path) -> None:
    generated = _run(
        [str(bin_dir / "openapi-typescript"), str(SPEC), "-o", str(tmp_path / "schema.d.ts")], TOOLS
    )
    assert generated.returncode == 0, generated.stdout + generated.stderr
    assert "StepReleaseExcitation" in (tmp_path / "schema.d.ts").read_text()
    (tmp_path / "client.ts").write_text(CLIENT_TS)
    compiled = _run([str(bin_dir / "tsc"), *TSC_STRICT, "--noEmit", "client.ts"], tmp_path)
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr


def _program(bin_dir: Path, folder: Path) -> Path:
    """``ts/client.ts`` beside its generated types (``schema.d.ts``, binary parts as Blob), in ``folder``,
    with the spec tools' node_modules; returns the folder."""
    (folder / "node_modules").symlink_to(TOOLS / "node_modules", target_is_directory=True)
    (folder / "package.json").write_text(json.dumps({"type": "module", "private": True}))
    generated = _run(
        ["node", str(TOOLS / "generate-types.mjs"), str(SPEC), str(folder / "schema.d.ts")], TOOLS
    )
    assert generated.returncode == 0, generated.stdout + generated.stderr
    shutil.copy(CLIENT_PROGRAM, folder / "client.ts")
    return folder


def test_typescript_upload_client_compiles_strict(bin_dir: Path, tmp_path: Path) -> None:
    """The upload takes a Blob (a File), and every other call of the program type-checks; the
    ``@ts-expect-error`` lines (a misspelt quality code, an unknown artifact, a null header) fail to."""
    folder = _program(bin_dir, tmp_path)
    schema = (folder / "schema.d.ts").read_text()
    assert "file: Blob" in schema
    compiled = _run([str(bin_dir / "tsc"), *TSC_PROGRAM, "--noEmit", "client.ts"], folder)
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr


@LIVE
def test_typescript_client_runs_against_a_live_server(
    bin_dir: Path, tmp_path: Path, live_service: h.LiveService, truth_clip: tuple[Path, dict[str, Any]]
) -> None:
    folder = _program(bin_dir, tmp_path)
    compiled = _run([str(bin_dir / "tsc"), *TSC_PROGRAM, "--outDir", "out", "client.ts"], folder)
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr
    clip, truth = truth_clip
    ran = _run(["node", str(folder / "out" / "client.js"), live_service.base_url, str(clip)], folder)
    assert ran.returncode == 0, ran.stdout + ran.stderr + live_service.logs()[-3000:]
    report = json.loads(ran.stdout.strip().splitlines()[-1])
    assert report["status"] == "succeeded"
    assert report["format"] == "npz"
    assert report["eigenfrequency_hz"] == pytest.approx(truth["objects"][0]["eigenfrequency_hz"], rel=0.02)
    assert report["summary_hz"] == report["eigenfrequency_hz"]
    assert report["result_url"] == f"/v1/jobs/{report['job']}/result"
    assert report["mask_magic"] == [0x89, 0x50, 0x4E, 0x47]
