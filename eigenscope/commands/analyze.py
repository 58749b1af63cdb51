"""``eigenscope analyze CLIP --out DIR``: measure a clip and write result.json and mask.png."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    from eigenscope.commands._options import PARAMETER_HELP as HELP

    p: argparse.ArgumentParser = sub.add_parser(
        "analyze",
        help="measure eigenfrequency, damping, stiffness, mass and a mask from a clip",
        description="Measure the vibrating objects of CLIP and write DIR/result.json and DIR/mask.png.",
    )
    p.add_argument("clip", help="the clip (.npz bundle or another supported format)")
    exc = p.add_mutually_exclusive_group()
    exc.add_argument("--force-n", type=float, help=HELP["force_n"])
    exc.add_argument("--impulse-ns", type=float, help=HELP["impulse_ns"])
    p.add_argument(
        "--force-uncertainty",
        type=float,
        default=0.0,
        help="standard uncertainty of --force-n (N) or --impulse-ns (N·s), in the same unit (default 0)",
    )
    p.add_argument("--object-id", type=int, help="object the excitation applies to (default: the main one)")
    p.add_argument(
        "--point",
        type=float,
        nargs=2,
        metavar=("X", "Y"),
        help="the object the excitation applies to, by a point on it: x y, pixels",
    )
    p.add_argument(
        "--box",
        type=float,
        nargs=4,
        metavar=("X", "Y", "W", "H"),
        help="the object the excitation applies to, by a box around it: x y width height, pixels",
    )
    for name in ("fps", "fx", "fy", "cx", "cy", "depth_scale"):
        p.add_argument(f"--{name.replace('_', '-')}", type=float, help=HELP[name])
    p.add_argument(
        "--depth", metavar="PATH", help="depth companion of a video: .npz with 'depth' or zip of PNGs"
    )
    p.add_argument("--color-topic", help="bag topic of the colour images (default: automatic)")
    p.add_argument("--depth-topic", help="bag topic of the depth images ('none' ignores depth)")
    p.add_argument("--force-topic", help=HELP["force_topic"])
    p.add_argument("--force-log", metavar="FILE", help=HELP["force_log"])
    p.add_argument("--force-log-offset-s", type=float, default=0.0, help=HELP["force_log_offset_s"])
    p.add_argument("--depth-m", type=float, help=HELP["depth_m"])
    p.add_argument("--frames", type=int, help=HELP["frames"])
    p.add_argument("--start-frame", type=int, help=HELP["start_frame"])
    p.add_argument("--min-frequency-hz", type=float, help=HELP["min_frequency_hz"])
    p.add_argument("--max-frequency-hz", type=float, help=HELP["max_frequency_hz"])
    p.add_argument("--method", choices=["default", "paper"], default="default", help=HELP["method"])
    p.add_argument("--flow", choices=["farneback", "dis"], help=HELP["flow"])
    p.add_argument(
        "--flow-threads",
        type=int,
        help="frame pairs whose optical flow is computed at once (default 2; 1 runs it as the paper did)",
    )
    p.add_argument(
        "--out", required=True, help="output folder (created if missing; removed again if the run fails)"
    )
    p.add_argument("--json", action="store_true", help="print result.json instead of a summary")
    p.set_defaults(handler=run)


def first_missing_folder(out: Path) -> Path | None:
    """The outermost folder of ``out`` that does not exist yet (the one a run creates), or None."""
    out = Path(os.path.abspath(out))
    missing = None
    for folder in (out, *out.parents):
        if folder.exists():
            break
        missing = folder
    return missing


def run(args: argparse.Namespace) -> int:
    from eigenscope import _heap
    from eigenscope.commands._options import read_force_log_file
    from workers.runner import RunOptions, run_analysis

    _heap.settle()  # the imports' objects, out of the collector's passes during the analysis

    params, excitation = _request(args)
    force_log = (
        None if args.force_log is None else read_force_log_file(args.force_log, args.force_log_offset_s)
    )
    created = first_missing_folder(Path(args.out))
    try:
        result = run_analysis(
            args.clip,
            args.out,
            excitation=excitation,
            parameters=params,
            depth_path=args.depth,
            force_log=force_log,
            options=RunOptions(flow_threads=args.flow_threads),
        )
    except BaseException:
        if created is not None:  # a failed run leaves no folder it made behind
            shutil.rmtree(created, ignore_errors=True)
        raise
    if args.json:
        json.dump(result.model_dump(mode="json"), sys.stdout, indent=2)
        print()
    else:
        _print_summary(result, args)
    return 0


def _request(args: argparse.Namespace) -> tuple[Any, Any]:
    """The analysis parameters and the typed excitation (or None) the options ask for; a bad value is a
    usage error naming its option."""
    from pydantic import ValidationError

    from api_schemas import AnalysisParameters, ImpulseExcitation, StepReleaseExcitation
    from eigenscope.cli import UsageError

    if args.flow_threads is not None and args.flow_threads < 1:
        raise UsageError(f"--flow-threads={args.flow_threads} must be at least 1")
    try:
        params = AnalysisParameters(
            method=args.method,
            flow=args.flow,
            frames=args.frames,
            start_frame=args.start_frame,
            fps=args.fps,
            fx=args.fx,
            fy=args.fy,
            cx=args.cx,
            cy=args.cy,
            depth_scale=args.depth_scale,
            depth_m=args.depth_m,
            color_topic=args.color_topic,
            depth_topic=args.depth_topic,
            force_topic=args.force_topic,
            min_frequency_hz=args.min_frequency_hz,
            max_frequency_hz=args.max_frequency_hz,
        )
        excitation: StepReleaseExcitation | ImpulseExcitation | None = None
        where = {"object_id": args.object_id, "point_px": args.point, "box_px": args.box}
        if args.force_n is not None:
            excitation = StepReleaseExcitation(
                type="step_release", force_n=args.force_n, force_uncertainty_n=args.force_uncertainty, **where
            )
        elif args.impulse_ns is not None:
            excitation = ImpulseExcitation(
                type="impulse",
                impulse_ns=args.impulse_ns,
                impulse_uncertainty_ns=args.force_uncertainty,
                **where,
            )
    except ValidationError as exc:
        err = exc.errors()[0]
        place = ".".join(str(x) for x in err["loc"]) or "input"
        raise UsageError(f"--{place.replace('_', '-')}: {err['msg']}") from None
    return params, excitation


def _print_summary(result: Any, args: argparse.Namespace) -> None:
    """The result in a few lines: the clip, each object with its notes, the quality flags, the files."""
    frames = f"frames {result.frames_used}" + (
        f", one in {result.frame_step}" if result.frame_step > 1 else ""
    )
    print(f"clip: {args.clip}  ({result.fps:g} fps from {result.fps_source}, {frames})")
    if not result.objects:
        print("no vibrating object found")
    for o in result.objects:
        line = f"object {o.id}: f = {o.eigenfrequency_hz:.4g} Hz ({o.regime.replace('_', '-')})"
        if o.damping_ratio is not None:
            line += f", ζ = {o.damping_ratio:.3g}"
        if o.amplitude_m is not None:
            line += f", A = {o.amplitude_m * 1000:.3g} mm"
        if o.stiffness_n_per_m is not None and o.mass_kg is not None:
            line += f", k = {o.stiffness_n_per_m:.4g} N/m, m = {o.mass_kg:.4g} kg"
        print(line + f", {o.pixel_count} px")
        if len(o.modes) > 1:
            print("  modes: " + "; ".join(_mode_text(m) for m in o.modes))
        if o.excitation is not None and o.excitation.source != "request":
            print("  excitation: " + _excitation_text(o.excitation))
        for reason in o.null_reasons:
            print(f"  note: {reason}")
    for q in result.quality:
        print(f"{q.severity}: {q.message}")
    print(f"wrote {args.out}/result.json and {args.out}/{result.artifacts.mask}")


def _mode_text(mode: Any) -> str:
    """One mode for the summary: its frequency, damping where it decays, and its share of the motion."""
    text = f"{mode.frequency_hz:.4g} Hz"
    if mode.damping_ratio is not None:
        text += f" ζ = {mode.damping_ratio:.3g}"
    return text + f" ({mode.energy_share * 100:.0f} %)"


def _excitation_text(e: Any) -> str:
    """A recorded excitation for the summary: what, how much, when and from where."""
    what = {
        "step_release": f"held force {e.value:.4g} ± {e.uncertainty:.2g} N",
        "impulse": f"impulse {e.value:.4g} ± {e.uncertainty:.2g} N·s",
        "forced": f"a force that kept acting, RMS {e.value:.4g} ± {e.uncertainty:.2g} N",
    }[e.type]
    when = "" if e.release_time_s is None else f", {'released' if e.type == 'step_release' else 'struck'} at "
    when += "" if e.release_time_s is None else f"{e.release_time_s:.4f} s"
    return f"{what}{when}, from {e.source}"
