"""``eigenscope submit CLIP --server URL``: upload a clip, queue an analysis, optionally wait for it.

Talks to a running ``eigenscope serve`` over HTTP only. With ``--wait`` it shows a progress bar and
prints the result summary and the artifact URLs; exit status 1 if the job failed or was cancelled.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import uuid
from pathlib import Path
from typing import Any

from eigenscope.cli import UsageError

_PARAMS = ("fps", "fx", "fy", "cx", "cy", "depth_scale", "depth_m", "min_frequency_hz", "max_frequency_hz")


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "submit",
        help="upload a clip to a server and analyse it",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("clip", type=Path, help="clip file (.npz or any format the server reads)")
    parser.add_argument("--server", required=True, help="base URL, e.g. http://127.0.0.1:8000")
    parser.add_argument(
        "--api-key",
        default=None,
        help="API key of a server that requires one (default: the EIGENSCOPE_API_KEY environment variable)",
    )
    exc = parser.add_mutually_exclusive_group()
    exc.add_argument("--force-n", type=float, default=None, help="holding force before release, N")
    exc.add_argument("--impulse-ns", type=float, default=None, help="impulse of the strike, N·s")
    parser.add_argument("--method", choices=("default", "paper"), default=None)
    parser.add_argument("--flow", choices=("farneback", "dis"), default=None)
    parser.add_argument("--frames", type=int, default=None, help="analysis window length N")
    parser.add_argument("--start-frame", type=int, default=None)
    for name in _PARAMS:
        parser.add_argument(f"--{name.replace('_', '-')}", type=float, default=None)
    parser.add_argument("--wait", action="store_true", help="wait for the result and print it")
    parser.add_argument("--timeout", type=float, default=3600.0, help="seconds to wait with --wait")
    parser.add_argument("--json", action="store_true", help="print the job as JSON on stdout")
    parser.set_defaults(handler=run)


def build_job_request(args: argparse.Namespace, clip_id: str) -> dict[str, Any]:
    """The ``POST /v1/jobs`` body for these options."""
    excitation: dict[str, Any] | None = None
    if args.force_n is not None:
        excitation = {"type": "step_release", "force_n": args.force_n}
    elif args.impulse_ns is not None:
        excitation = {"type": "impulse", "impulse_ns": args.impulse_ns}
    parameters: dict[str, Any] = {}
    for name in ("method", "flow", "frames", "start_frame", *_PARAMS):
        value = getattr(args, name, None)
        if value is not None:
            parameters[name] = value
    return {"clip_id": clip_id, "excitation": excitation, "parameters": parameters}


class ApiClient:
    """The few calls ``submit`` (and the demo) make, with problem+json errors turned into messages."""

    def __init__(self, server: str, *, timeout_s: float = 600.0, api_key: str | None = None) -> None:
        import httpx

        self.base = server.rstrip("/")
        if not self.base.startswith(("http://", "https://")):
            raise UsageError(f"--server {server!r} must be an http:// or https:// URL")
        timeout = httpx.Timeout(timeout_s, connect=10.0)
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self.http = httpx.Client(base_url=self.base, timeout=timeout, headers=headers)

    def close(self) -> None:
        self.http.close()

    def _request(self, method: str, url: str, **kwargs: Any) -> Any:
        import httpx

        for attempt in range(4):
            try:
                response = self.http.request(method, url, **kwargs)
                break
            except (httpx.ConnectError, httpx.RemoteProtocolError) as exc:
                if attempt == 3 or "files" in kwargs:
                    raise UsageError(f"cannot reach {self.base}: {exc}") from exc
                time.sleep(0.5 * (attempt + 1))
            except httpx.HTTPError as exc:
                raise UsageError(f"request to {self.base}{url} failed: {exc}") from exc
        if response.status_code >= 400:
            raise UsageError(_problem_message(response))
        return response.json() if response.content else None

    def upload(self, path: Path) -> dict[str, Any]:
        if not path.is_file():
            raise UsageError(f"{path}: no such file")
        with path.open("rb") as fh:
            result: dict[str, Any] = self._request(
                "POST", "/v1/clips", files={"file": (path.name, fh, "application/octet-stream")}
            )
        return result

    def create_job(self, body: dict[str, Any]) -> dict[str, Any]:
        key = uuid.uuid4().hex  # makes the retries in _request safe
        result: dict[str, Any] = self._request(
            "POST", "/v1/jobs", json=body, headers={"Idempotency-Key": key}
        )
        return result

    def get_job(self, job_id: str) -> dict[str, Any]:
        result: dict[str, Any] = self._request("GET", f"/v1/jobs/{job_id}")
        return result

    def wait(self, job_id: str, *, timeout_s: float, show: bool) -> dict[str, Any]:
        """Poll until the job finishes; draws a progress bar on stderr when ``show``."""
        deadline = time.monotonic() + timeout_s
        delay = 0.05
        last_line = ""
        while True:
            job = self.get_job(job_id)
            if show:
                last_line = _draw_progress(job, last_line)
            if job["status"] in ("succeeded", "failed", "cancelled"):
                if show and sys.stderr.isatty():
                    sys.stderr.write("\n")
                return job
            if time.monotonic() > deadline:
                raise UsageError(f"job {job_id} still {job['status']} after {timeout_s:g} s; poll it later")
            time.sleep(delay)
            delay = min(delay * 1.5, 1.0)


def _problem_message(response: Any) -> str:
    try:
        doc = response.json()
    except ValueError:
        doc = {}
    detail = doc.get("detail") if isinstance(doc, dict) else None
    title = doc.get("title") if isinstance(doc, dict) else None
    title = title or response.reason_phrase
    message = f"server answered {response.status_code} {title}: {detail or response.text[:200]}"
    if response.status_code == 401:
        message += " (pass --api-key KEY or set EIGENSCOPE_API_KEY)"
    return message


def _draw_progress(job: dict[str, Any], last_line: str) -> str:
    """Redraw the bar on a terminal; elsewhere print a line when the stage changes. Returns the line."""
    fraction = float(job.get("progress") or 0.0)
    width = 30
    filled = round(fraction * width)
    state = f"{job['status']}: {job.get('stage') or ''}"
    line = f"[{'#' * filled}{'.' * (width - filled)}] {fraction * 100:5.1f}% {state}"
    if sys.stderr.isatty():
        sys.stderr.write("\r" + line.ljust(len(last_line)))
        sys.stderr.flush()
    elif not last_line.endswith(state):
        print(line, file=sys.stderr, flush=True)
    return line


def _fmt(value: Any, unit: str, digits: int = 4) -> str:
    if value is None:
        return "n/a"
    return f"{value:.{digits}g} {unit}".strip()


def summarize(job: dict[str, Any], base: str) -> list[str]:
    """Human-readable lines for a finished job."""
    lines = [f"job {job['id']}: {job['status']} (attempts: {job.get('attempts')})"]
    if job["status"] != "succeeded":
        error = job.get("error") or {}
        if error:
            lines.append(f"error: {error.get('title')}: {error.get('detail')}")
        return lines
    result = job.get("result") or {}
    source = result.get("fps_source") or "unknown"
    lines.append(f"frame rate: {_fmt(result.get('fps'), 'fps')} (from {source})")
    lines.append(f"eigenfrequency: {_fmt(result.get('eigenfrequency_hz'), 'Hz')}")
    for obj in result.get("objects", []):
        lines.append(
            f"object {obj.get('id')}: f = {_fmt(obj.get('eigenfrequency_hz'), 'Hz')} "
            f"({str(obj.get('regime') or 'ring_down').replace('_', '-')}), "
            f"damping ratio = {_fmt(obj.get('damping_ratio'), '')}, "
            f"amplitude = {_fmt(obj.get('amplitude_m'), 'm')}, "
            f"stiffness = {_fmt(obj.get('stiffness_n_per_m'), 'N/m')}, "
            f"mass = {_fmt(obj.get('mass_kg'), 'kg')}"
        )
        for reason in obj.get("null_reasons") or []:
            lines.append(f"  note: {reason}")
    for flag in result.get("quality", []):
        lines.append(f"quality [{flag.get('severity')}] {flag.get('code')}: {flag.get('message')}")
    artifacts = result.get("artifacts") or {}
    if artifacts:
        lines.append("artifacts:")
        for name, url in artifacts.items():
            full = f"{base}{url}" if isinstance(url, str) and url.startswith("/") else url
            lines.append(f"  {name}: {full}")
    return lines


def run(args: argparse.Namespace) -> int:
    client = ApiClient(args.server, api_key=args.api_key or os.environ.get("EIGENSCOPE_API_KEY") or None)
    try:
        clip = client.upload(args.clip)
        print(
            f"uploaded {args.clip.name}: clip {clip['id']} ({clip['format']}, {clip['frames']} frames "
            f"{clip['width']}x{clip['height']} @ {clip.get('fps')} fps, depth: {clip['has_depth']})",
            file=sys.stderr,
        )
        job = client.create_job(build_job_request(args, clip["id"]))
        print(f"job {job['id']} queued: {client.base}/v1/jobs/{job['id']}", file=sys.stderr)
        if args.wait:
            job = client.wait(job["id"], timeout_s=args.timeout, show=not args.json)
        if args.json:
            print(json.dumps(job, indent=2))
        elif args.wait:
            print("\n".join(summarize(job, client.base)))
        else:
            print(job["id"])
    finally:
        client.close()
    if args.wait and job["status"] != "succeeded":
        return 1
    return 0
