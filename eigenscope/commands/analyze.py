"""``eigenscope analyze CLIP --out DIR``: measure a clip and write result.json and mask.png."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "analyze",
        help="measure eigenfrequency, damping, stiffness, mass and a mask from a clip",
        description="Measure the vibrating objects of CLIP and write DIR/result.json and DIR/mask.png.",
    )
    p.add_argument("clip", help="the clip (.npz bundle or another supported format)")
    exc = p.add_mutually_exclusive_group()
    exc.add_argument("--force-n", type=float, help="held force before release, newtons (step release)")
    exc.add_argument("--impulse-ns", type=float, help="impulse that struck the object, newton-seconds")
    p.add_argument("--force-uncertainty", type=float, default=0.0, help="standard uncertainty of F or J")
    p.add_argument("--object-id", type=int, help="object the excitation applies to (default: the main one)")
    p.add_argument(
        "--point", type=float, nargs=2, metavar=("X", "Y"), help="... or a point on that object, pixels"
    )
    p.add_argument(
        "--box", type=float, nargs=4, metavar=("X", "Y", "W", "H"), help="... or a box around it, pixels"
    )
    p.add_argument("--fps", type=float, help="true recording frame rate (wins over the file's)")
    for name in ("fx", "fy", "cx", "cy"):
        p.add_argument(f"--{name}", type=float, help=f"camera intrinsic {name}, pixels")
    p.add_argument("--depth-scale", type=float, help="metres per depth unit")
    p.add_argument(
        "--depth", metavar="PATH", help="depth companion of a video: .npz with 'depth' or zip of PNGs"
    )
    p.add_argument("--color-topic", help="bag topic of the colour images (default: automatic)")
    p.add_argument("--depth-topic", help="bag topic of the depth images ('none' ignores depth)")
    p.add_argument("--depth-m", type=float, help="object distance for clips without depth, metres")
    p.add_argument("--frames", type=int, help="analysis window length in frames (default: up to 256)")
    p.add_argument("--start-frame", type=int, help="first frame of the window (default 0)")
    p.add_argument("--min-frequency-hz", type=float)
    p.add_argument("--max-frequency-hz", type=float)
    p.add_argument("--method", choices=["default", "paper"], default="default")
    p.add_argument("--flow", choices=["farneback", "dis"], help="optical flow (default: the method's)")
    p.add_argument(
        "--flow-threads",
        type=int,
        help="frame pairs whose optical flow is computed at once (default 2; 1 runs it as the paper did)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--json", action="store_true", help="print result.json instead of a summary")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from api_schemas import AnalysisParameters, ImpulseExcitation, StepReleaseExcitation
    from eigenscope.cli import UsageError
    from workers.runner import run_analysis

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
            min_frequency_hz=args.min_frequency_hz,
            max_frequency_hz=args.max_frequency_hz,
        )
        excitation: StepReleaseExcitation | ImpulseExcitation | None = None
        if args.force_n is not None:
            excitation = StepReleaseExcitation(
                type="step_release",
                force_n=args.force_n,
                force_uncertainty_n=args.force_uncertainty,
                object_id=args.object_id,
                point_px=args.point,
                box_px=args.box,
            )
        elif args.impulse_ns is not None:
            excitation = ImpulseExcitation(
                type="impulse",
                impulse_ns=args.impulse_ns,
                impulse_uncertainty_ns=args.force_uncertainty,
                object_id=args.object_id,
                point_px=args.point,
                box_px=args.box,
            )
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(x) for x in err["loc"]) or "input"
        raise UsageError(f"--{where.replace('_', '-')}: {err['msg']}") from None

    result = run_analysis(
        args.clip,
        args.out,
        excitation=excitation,
        parameters=params,
        depth_path=args.depth,
        flow_threads=args.flow_threads,
    )
    if args.json:
        json.dump(result.model_dump(mode="json"), sys.stdout, indent=2)
        print()
        return 0
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
        line += f", {o.pixel_count} px"
        print(line)
        for reason in o.null_reasons:
            print(f"  note: {reason}")
    for q in result.quality:
        print(f"{q.severity}: {q.message}")
    print(f"wrote {args.out}/result.json and {args.out}/{result.artifacts.mask}")
    return 0
