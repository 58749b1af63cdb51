"""``eigenscope submit CLIP --server URL``: upload a clip, queue an analysis, optionally wait for it.

Talks to a running ``eigenscope serve`` over HTTP through the Python client (``eigenscope_client``, the
same one robot code uses). With ``--wait`` it shows the upload and the analysis as progress bars and prints
the result summary and the artifact URLs (``--out DIR`` downloads them); exit status 1 if the job failed or
was cancelled.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from eigenscope.cli import UsageError
from eigenscope.commands._options import PARAMETER_HELP as HELP

if TYPE_CHECKING:
    from eigenscope_client import Client, Job

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
    exc.add_argument("--force-n", type=float, default=None, help=HELP["force_n"])
    exc.add_argument("--impulse-ns", type=float, default=None, help=HELP["impulse_ns"])
    parser.add_argument("--method", choices=("default", "paper"), default=None, help=HELP["method"])
    parser.add_argument("--flow", choices=("farneback", "dis"), default=None, help=HELP["flow"])
    parser.add_argument("--frames", type=int, default=None, help=HELP["frames"])
    parser.add_argument("--start-frame", type=int, default=None, help=HELP["start_frame"])
    for name in _PARAMS:
        parser.add_argument(f"--{name.replace('_', '-')}", type=float, default=None, help=HELP[name])
    parser.add_argument("--force-log", type=Path, default=None, metavar="FILE", help=HELP["force_log"])
    parser.add_argument(
        "--force-log-offset-s", type=float, default=None, metavar="S", help=HELP["force_log_offset_s"]
    )
    parser.add_argument("--callback-url", default=None, help="URL the server tells when the job ends")
    parser.add_argument("--wait", action="store_true", help="wait for the result and print it")
    parser.add_argument(
        "--timeout", type=float, default=3600.0, help="how long --wait waits, seconds (default 3600)"
    )
    parser.add_argument("--out", type=Path, default=None, help="with --wait: download the artifacts here")
    parser.add_argument("--json", action="store_true", help="print the job as JSON on stdout")
    parser.set_defaults(handler=run)


def job_request(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments of ``Client.create_job`` for these options (excitation, parameters and the
    force log, read here: a file that is not a force log is a one-line error before anything is sent)."""
    from eigenscope_client import Impulse, StepRelease

    excitation: StepRelease | Impulse | None = None
    if args.force_n is not None:
        excitation = StepRelease(force_n=args.force_n)
    elif args.impulse_ns is not None:
        excitation = Impulse(impulse_ns=args.impulse_ns)
    parameters: dict[str, Any] = {}
    for name in ("method", "flow", "frames", "start_frame", *_PARAMS):
        value = getattr(args, name, None)
        if value is not None:
            parameters[name] = value
    return {
        "excitation": excitation,
        "parameters": parameters,
        "callback_url": args.callback_url,
        "force_log": force_log(args),
    }


def force_log(args: argparse.Namespace) -> Any:
    """The ``--force-log`` file as the request's force log (``eigenscope_client.ForceLog``; its times on
    its own clock, ``--force-log-offset-s`` sent as its offset), or None."""
    from eigenscope_client import ForceLog as Log
    from eigenscope_client import ForceLogError

    path: Path | None = getattr(args, "force_log", None)
    offset: float | None = getattr(args, "force_log_offset_s", None)
    if path is None:
        if offset is not None:
            raise UsageError("--force-log-offset-s needs --force-log FILE: it shifts that log's times")
        return None
    if not path.is_file():
        raise UsageError(f"--force-log {path}: no such file")
    try:
        return Log.from_file(path, offset_s=offset or 0.0)
    except ForceLogError as exc:
        raise UsageError(f"--force-log: {exc}") from None
    except OSError as exc:
        raise UsageError(f"--force-log {path}: {exc.strerror or exc}") from None


class ProgressBar:
    """A bar on a terminal (redrawn in place); elsewhere a line each time the label changes."""

    def __init__(self, stream: Any = None, width: int = 30) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.width = width
        self.last = ""
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def show(self, fraction: float, label: str) -> None:
        fraction = min(max(fraction, 0.0), 1.0)
        filled = round(fraction * self.width)
        line = f"[{'#' * filled}{'.' * (self.width - filled)}] {fraction * 100:5.1f}% {label}"
        if self.tty:
            self.stream.write("\r" + line.ljust(len(self.last)))
            self.stream.flush()
        elif not self.last.endswith(label):
            print(line, file=self.stream, flush=True)
        self.last = line

    def upload(self, sent: int, total: int) -> None:
        self.show(sent / total if total else 1.0, f"uploading {total / 1e6:.1f} MB")

    def job(self, job: Job) -> None:
        self.show(job.progress, f"{job.status}: {job.stage or ''}")

    def done(self) -> None:
        if self.tty and self.last:
            self.stream.write("\n")
            self.stream.flush()
        self.last = ""


def _fmt(value: Any, unit: str, digits: int = 4) -> str:
    if value is None:
        return "n/a"
    return f"{value:.{digits}g} {unit}".strip()


def summarize(job: Job, base: str) -> list[str]:
    """Human-readable lines for a finished job."""
    lines = [f"job {job.id}: {job.status} (attempts: {job.attempts})"]
    log = job.force_log
    if log is not None:
        lines.append(
            f"force log: {log.name} ({log.samples} samples, {log.start_s:.3f} s to {log.end_s:.3f} s on the "
            "clip's clock)"
        )
    if job.status != "succeeded" or job.result is None:
        if job.error is not None:
            lines.append(f"error: {job.error.title}: {job.error.detail}")
        return lines
    result = job.result
    lines.append(f"frame rate: {_fmt(result.fps, 'fps')} (from {result.fps_source or 'unknown'})")
    lines.append(f"eigenfrequency: {_fmt(result.eigenfrequency_hz, 'Hz')}")
    for obj in result.objects:
        lines.append(
            f"object {obj.id}: f = {_fmt(obj.eigenfrequency_hz, 'Hz')} ({obj.regime.replace('_', '-')}), "
            f"damping ratio = {_fmt(obj.damping_ratio, '')}, "
            f"amplitude = {_fmt(obj.amplitude_m, 'm')}, "
            f"stiffness = {_fmt(obj.stiffness_n_per_m, 'N/m')}, "
            f"mass = {_fmt(obj.mass_kg, 'kg')}"
        )
        used = obj.excitation
        if used is not None and used.source != "request":
            unit = "N·s" if used.type == "impulse" else "N"  # a held force, or a kept one's RMS
            lines.append(
                f"  excitation: {used.type.replace('_', ' ')} {used.value:.4g} ± {used.uncertainty:.2g} "
                f"{unit} from {used.source}"
            )
        for reason in obj.null_reasons:
            lines.append(f"  note: {reason}")
    for flag in result.quality:
        lines.append(f"quality [{flag.severity}] {flag.code}: {flag.message}")
    if result.artifacts:
        lines.append("artifacts:")
        for name, url in result.artifacts.items():
            lines.append(f"  {name}: {base}{url}" if url.startswith("/") else f"  {name}: {url}")
    return lines


def connect(server: str, api_key: str | None) -> Client:
    """A client of ``server``; a missing client package or a bad URL is a one-line error."""
    try:
        from eigenscope_client import Client
    except ImportError as exc:  # the pipeline installed without the client distribution
        raise UsageError(
            f"the Python client is not installed ({exc}); install it with `pip install -e client/` from the "
            "Eigenscope checkout (./run does)"
        ) from None
    try:
        return Client(server, api_key=api_key or os.environ.get("EIGENSCOPE_API_KEY") or None)
    except ValueError as exc:
        raise UsageError(f"--server: {exc}") from None


def explain(exc: Exception, server: str) -> UsageError:
    """A client error as the one-line message the command prints."""
    from eigenscope_client import APIError, AuthenticationError

    if isinstance(exc, AuthenticationError):
        return UsageError(f"server answered {exc} (pass --api-key KEY or set EIGENSCOPE_API_KEY)")
    if isinstance(exc, APIError):
        return UsageError(f"server answered {exc}")
    return UsageError(f"{server}: {exc}")


def run(args: argparse.Namespace) -> int:
    from eigenscope_client import EigenscopeError

    if args.out is not None and not args.wait:
        raise UsageError("--out needs --wait: the artifacts exist once the job has succeeded")
    if not args.clip.is_file():
        raise UsageError(f"{args.clip}: no such file")
    client = connect(args.server, args.api_key)
    bar = ProgressBar()
    show = not args.json
    try:
        request = job_request(args)  # a bad force log is refused before the clip is sent
        clip = client.upload_clip(args.clip, progress=bar.upload if show else None)
        bar.done()
        print(
            f"uploaded {args.clip.name}: clip {clip.id} ({clip.format}, {clip.frames} frames "
            f"{clip.width}x{clip.height} @ {clip.fps} fps, depth: {clip.has_depth})",
            file=sys.stderr,
        )
        job = client.create_job(clip.id, **request)
        print(f"job {job.id} queued: {client.base_url}/v1/jobs/{job.id}", file=sys.stderr)
        if args.wait:
            job = client.wait(job, timeout=args.timeout, on_progress=bar.job if show else None)
            bar.done()
            if args.out is not None and job.succeeded and job.result is not None:
                args.out.mkdir(parents=True, exist_ok=True)
                for name in ("result", *job.result.artifacts):
                    client.download_artifact(job, name, args.out)
                print(f"downloaded the artifacts to {args.out}", file=sys.stderr)
    except EigenscopeError as exc:
        bar.done()
        raise explain(exc, client.base_url) from None
    finally:
        client.close()
    if args.json:
        print(json.dumps(job.raw, indent=2))
    elif args.wait:
        print("\n".join(summarize(job, client.base_url)))
    else:
        print(job.id)
    if args.wait and job.status != "succeeded":
        return 1
    return 0
