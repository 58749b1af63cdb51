"""``eigenscope synth --out clip.npz``: render a ground-truth RGB-D clip of a spring-mass object."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    p: argparse.ArgumentParser = sub.add_parser(
        "synth",
        help="render a synthetic RGB-D clip with known eigenfrequency, stiffness and mass",
        description="Render a textured spring-mass object over a textured background with sensor noise and "
        "depth; write the clip, its truth (JSON) and the true mask (PNG) side by side.",
    )
    p.add_argument("--out", required=True, help="clip path (.npz); truth goes to <stem>.truth.json")
    p.add_argument("--frequency-hz", type=float, default=5.0, help="undamped natural frequency")
    p.add_argument("--mass-kg", type=float, default=0.5)
    p.add_argument("--damping-ratio", type=float, default=0.03)
    exc = p.add_mutually_exclusive_group()
    exc.add_argument("--force-n", type=float, help="held force released at --release-frame (default 10)")
    exc.add_argument("--impulse-ns", type=float, help="impulse at --release-frame instead of a held force")
    p.add_argument("--frames", type=int, default=128)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--depth-m", type=float, default=1.0, help="object distance")
    p.add_argument("--background-depth-m", type=float, default=2.0)
    p.add_argument("--release-frame", type=int, default=0, help="still frames before the release")
    p.add_argument("--direction", type=float, nargs=3, default=(1.0, 0.0, 0.0), metavar=("X", "Y", "Z"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--compress", action="store_true", help="deflate the npz (smaller, slower to read)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from workers.pipeline.clipio import write_npz
    from workers.pipeline.figures import write_label_png
    from workers.pipeline.synth import Scene, SceneObject, render

    w, h = args.width, args.height
    scale = w / 640
    obj = SceneObject(
        center_px=(w / 2, h / 2),
        size_px=(140 * scale, 110 * scale),
        depth_m=args.depth_m,
        frequency_hz=args.frequency_hz,
        damping_ratio=args.damping_ratio,
        mass_kg=args.mass_kg,
        excitation="impulse" if args.impulse_ns is not None else "step_release",
        force_n=args.force_n if args.force_n is not None else 10.0,
        impulse_ns=args.impulse_ns if args.impulse_ns is not None else 0.3,
        direction=tuple(args.direction),
        release_frame=args.release_frame,
    )
    scene = Scene(
        width=w,
        height=h,
        frames=args.frames,
        fps=args.fps,
        background_depth_m=args.background_depth_m,
        objects=(obj,),
        seed=args.seed,
    )
    clip = render(scene)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_npz(
        out, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics, compress=args.compress
    )
    truth_path = out.with_name(out.stem + ".truth.json")
    mask_path = out.with_name(out.stem + ".truth-mask.png")
    truth_path.write_text(json.dumps(clip.truth, indent=2))
    write_label_png(mask_path, clip.mask)
    t = clip.truth["objects"][0]
    print(
        f"wrote {out} ({args.frames} frames {w}x{h} @ {args.fps:g} fps): "
        f"f = {t['eigenfrequency_hz']:.4g} Hz, k = {t['stiffness_n_per_m']:.4g} N/m, "
        f"m = {t['mass_kg']:.4g} kg, A = {t['amplitude_m'] * 1000:.3g} mm; "
        f"truth in {truth_path.name}, {mask_path.name}"
    )
    return 0
