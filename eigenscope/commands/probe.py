"""``eigenscope probe CLIP``: say what a clip file holds without analysing it.

Prints the detected format, streams or topics, frame count, frame rate and where it came from, frame
size, depth and its scale, intrinsics, duration and dropped frames; ``--json`` prints the same as the
API's clip resource. Probing never decodes frames (and never loads OpenCV).
"""

from __future__ import annotations

import argparse
import json
from typing import Any


def register(subparsers: Any) -> None:
    """Add the ``probe`` subcommand to the CLI's subparsers."""
    p: argparse.ArgumentParser = subparsers.add_parser(
        "probe",
        help="show what a clip holds (format, frames, fps and its source, depth, intrinsics)",
        description=(
            "Detect a clip's format from its content and print its metadata. Formats: .npz bundle, zip of "
            "rgb/ (+depth/) frames, TUM RGB-D zip, Open3D RGB-D zip or folder (color/, depth/, "
            "camera_intrinsic.json), Azure Kinect / Orbbec .mkv (colour and b16g depth tracks, "
            "calibration.json), video (mp4/avi/mkv/mov), ROS 1 .bag (rosbag record or RealSense Viewer), "
            "ROS 2 .mcap/.db3 or zipped bag folder. Flags override the file's values."
        ),
    )
    p.add_argument("clip", help="clip file (or a bag/TUM/Open3D/frames folder)")
    p.add_argument("--fps", type=float, help="true recording frame rate, Hz (wins over the file)")
    p.add_argument("--fx", type=float, help="focal length x, pixels")
    p.add_argument("--fy", type=float, help="focal length y, pixels")
    p.add_argument("--cx", type=float, help="principal point x, pixels")
    p.add_argument("--cy", type=float, help="principal point y, pixels")
    p.add_argument("--depth-scale", type=float, help="metres per stored depth unit")
    p.add_argument("--depth", metavar="PATH", help="depth companion of a video (.npz or zip of depth PNGs)")
    p.add_argument("--color-topic", help="bag topic with the colour images")
    p.add_argument("--depth-topic", help="bag topic with the depth images ('none' to ignore depth)")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.set_defaults(handler=run)


def _fmt_num(value: float | None, unit: str = "", digits: int = 4) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}g}{unit}"


def format_text(path: str, data: dict[str, Any]) -> str:
    """Human-readable, one fact per line."""
    lines = [f"clip:        {path}"]
    lines.append(f"format:      {data['format']}")
    lines.append(f"size:        {data['size_bytes']} bytes")
    lines.append(f"frames:      {data['frames']} of {data['width']}x{data['height']} px")
    src = data["fps_source"] or "unknown; pass --fps"
    rate = f"{_fmt_num(data['fps'], ' fps', 6)} (from {src})"
    extras = []
    if data["measured_fps"] is not None and data["fps_source"] != "timestamps":
        extras.append(f"timestamps measure {_fmt_num(data['measured_fps'], ' fps', 6)}")
    if data["container_fps"] is not None and data["fps_source"] not in ("container", "bundle"):
        extras.append(f"file declares {_fmt_num(data['container_fps'], ' fps', 6)}")
    if extras:
        rate += "; " + ", ".join(extras)
    lines.append(f"fps:         {rate}")
    lines.append(f"duration:    {_fmt_num(data['duration_s'], ' s')}")
    ts = "per-frame timestamps" if data["has_timestamps"] else "none (uniform at fps)"
    lines.append(f"timestamps:  {ts}; dropped frames: {data['dropped_frames']}")
    if data["has_depth"]:
        lines.append(f"depth:       yes, {data['depth_scale']:.6g} m/unit, from {data['depth_source']}")
    else:
        lines.append("depth:       none")
    k = data["intrinsics"]
    if k is None:
        lines.append("intrinsics:  none (pass --fx/--fy for metric amplitude)")
    else:
        lines.append(f"intrinsics:  fx={k['fx']:.6g} fy={k['fy']:.6g} cx={k['cx']:.6g} cy={k['cy']:.6g} px")
    lines.append("streams:     " + (", ".join(data["streams"]) or "-"))
    for note in data["notes"]:
        lines.append(f"note:        {note}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Probe ``args.clip`` and print its metadata; domain errors propagate to the CLI dispatcher."""
    from workers.pipeline.clipio import ClipOverrides, open_clip

    overrides = ClipOverrides(
        fps=args.fps,
        fx=args.fx,
        fy=args.fy,
        cx=args.cx,
        cy=args.cy,
        depth_scale=args.depth_scale,
        color_topic=args.color_topic,
        depth_topic=args.depth_topic,
    )
    with open_clip(args.clip, overrides=overrides, depth=args.depth) as reader:
        data = reader.info.to_dict()
    if args.json:
        print(json.dumps({"clip": args.clip, **data}, indent=2))
    else:
        print(format_text(args.clip, data))
    return 0
