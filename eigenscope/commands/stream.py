"""``eigenscope stream``: stream frames live to a server and get the answer as the ring-down ends.

``eigenscope stream CLIP --server URL`` replays any clip Eigenscope reads (as fast as the server takes
it, or at its frame rate with ``--realtime``); ``eigenscope stream --realsense`` streams an Intel
RealSense camera (``--bag FILE``: a recording, through the RealSense SDK's playback device). Estimates
are shown as they arrive; ``--stop-when-converged`` stops sending once the server says the estimate has
reached its target uncertainty. The final result is the same as a job's (``--json`` prints it); the
stream is kept as a job and a clip on the server.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from eigenscope.cli import UsageError


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "stream",
        help="stream a clip or a RealSense camera live to a server",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("clip", type=Path, nargs="?", help="clip to replay (any format `analyze` reads)")
    parser.add_argument("--server", required=True, help="base URL, e.g. http://127.0.0.1:8000")
    parser.add_argument("--api-key", default=None, help="API key (default: EIGENSCOPE_API_KEY)")
    parser.add_argument("--realsense", action="store_true", help="stream an Intel RealSense camera")
    parser.add_argument("--bag", type=Path, default=None, help="with --realsense: a recorded .bag (or .db3)")
    parser.add_argument("--realtime", action="store_true", help="send frames at their capture rate")
    parser.add_argument(
        "--stop-when-converged", action="store_true", help="stop sending once the estimate has converged"
    )
    exc = parser.add_mutually_exclusive_group()
    exc.add_argument("--force-n", type=float, default=None, help="holding force before release, N")
    exc.add_argument("--impulse-ns", type=float, default=None, help="impulse of the strike, N·s")
    parser.add_argument("--fps", type=float, default=None, help="true frame rate (default: the clip's)")
    parser.add_argument("--target", type=float, default=0.01, help="target relative uncertainty (0.01)")
    parser.add_argument("--max-duration", type=float, default=60.0, help="longest capture, seconds")
    parser.add_argument("--frames", type=int, default=None, help="most frames to send")
    parser.add_argument("--png", action="store_true", help="send colour as PNG (lossless) instead of JPEG")
    parser.add_argument("--json", action="store_true", help="print the final result as JSON on stdout")
    parser.set_defaults(handler=run)


@dataclass(frozen=True)
class Camera:
    width: int
    height: int
    fps: float | None
    intrinsics: tuple[float, float, float, float] | None
    depth_scale: float


@dataclass(frozen=True)
class RawFrame:
    rgb: Any  # (H, W, 3) uint8
    depth_units: Any  # (H, W) uint16 or None
    timestamp_s: float


def _clip_frames(path: Path, fps: float | None) -> tuple[Camera, Iterator[RawFrame]]:
    import numpy as np

    from workers.pipeline.clipio import ClipOverrides, open_clip

    reader = open_clip(path, overrides=ClipOverrides(fps=fps))
    info = reader.info
    scale = info.depth_scale or 0.001
    k = info.intrinsics
    camera = Camera(info.width, info.height, info.fps, None if k is None else (k.fx, k.fy, k.cx, k.cy), scale)

    def frames() -> Iterator[RawFrame]:
        with reader:
            for f in reader.frames():
                units = None
                if f.depth_m is not None:
                    d = np.nan_to_num(f.depth_m / np.float32(scale), nan=0.0, posinf=0.0, neginf=0.0)
                    units = np.clip(np.rint(d), 0, 65535).astype("<u2")
                yield RawFrame(f.rgb, units, f.timestamp_s)

    return camera, frames()


def _realsense_frames(bag: Path | None, realtime: bool) -> tuple[Camera, Iterator[RawFrame]]:
    """Frames of a RealSense camera (or of a recording played through the SDK), depth aligned to colour."""
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise UsageError(
            f"--realsense needs the RealSense SDK: pip install pyrealsense2 (and libusb-1.0) ({exc})"
        ) from None
    import numpy as np

    pipeline = rs.pipeline()
    config = rs.config()
    if bag is not None:
        if not bag.is_file():
            raise UsageError(f"{bag}: no such file")
        config.enable_device_from_file(str(bag), repeat_playback=False)
    else:
        config.enable_stream(rs.stream.depth, 640, 480, rs.format.z16, 30)
        config.enable_stream(rs.stream.color, 640, 480, rs.format.rgb8, 30)
    try:
        profile = pipeline.start(config)
    except RuntimeError as exc:
        where = f"the recording {bag}" if bag else "a RealSense camera"
        raise UsageError(f"cannot stream from {where}: {exc}") from None
    device = profile.get_device()
    if bag is not None:
        device.as_playback().set_real_time(realtime)
    color = profile.get_stream(rs.stream.color).as_video_stream_profile()
    k = color.get_intrinsics()
    try:
        scale = float(device.first_depth_sensor().get_depth_scale())
    except RuntimeError:
        scale = 0.001
    camera = Camera(k.width, k.height, float(color.fps()), (k.fx, k.fy, k.ppx, k.ppy), scale)
    align = rs.align(rs.stream.color)
    bgr = color.format() == rs.format.bgr8

    def frames() -> Iterator[RawFrame]:
        first: float | None = None
        try:
            while True:
                ok, frameset = pipeline.try_wait_for_frames(2000)
                if not ok:
                    return  # end of the recording (or a camera that stopped)
                aligned = align.process(frameset)
                c, d = aligned.get_color_frame(), aligned.get_depth_frame()
                if not c:
                    continue
                rgb = np.asanyarray(c.get_data()).copy()
                if bgr:
                    rgb = rgb[..., ::-1].copy()
                t = c.get_timestamp() / 1000.0
                first = t if first is None else first
                depth = np.asanyarray(d.get_data()).astype("<u2") if d else None
                yield RawFrame(rgb, depth, t - first)
        finally:
            pipeline.stop()

    return camera, frames()


def _encode(rgb: Any, png: bool) -> bytes:
    import cv2

    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    if png:
        ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    else:
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise UsageError("a frame could not be encoded")
    return bytes(buf)


def _excitation(args: argparse.Namespace) -> dict[str, Any] | None:
    if args.force_n is not None:
        return {"type": "step_release", "force_n": args.force_n}
    if args.impulse_ns is not None:
        return {"type": "impulse", "impulse_ns": args.impulse_ns}
    return None


def _show(message: dict[str, Any], quiet: bool) -> None:
    kind = message.get("type")
    if quiet:
        return
    if kind == "estimate":
        e = message["estimate"]
        extra = _mechanics_text(e)
        print(
            f"estimate after {e['frames_received']} frames: f = {e['eigenfrequency_hz']:.4f} ± "
            f"{e['eigenfrequency_uncertainty_hz']:.4f} Hz ({e['relative_uncertainty'] * 100:.2f} %), "
            f"ζ = {e.get('damping_ratio') or 0:.3f}{extra}",
            file=sys.stderr,
            flush=True,
        )
    elif kind == "converged":
        print(
            f"converged after {message['frames_received']} frames: relative uncertainty "
            f"{message['relative_uncertainty'] * 100:.2f} % <= "
            f"{message['target_relative_uncertainty'] * 100:g} %",
            file=sys.stderr,
            flush=True,
        )
    elif kind == "error":
        p = message.get("problem") or {}
        print(f"server: {p.get('title')}: {p.get('detail')}", file=sys.stderr, flush=True)
    elif kind == "backpressure":
        print(
            f"server: backpressure ({message['action']}, frame {message.get('frame')}, "
            f"{message['in_flight']}/{message['window']} in flight)",
            file=sys.stderr,
            flush=True,
        )


def run(args: argparse.Namespace) -> int:
    from eigenscope_client import EigenscopeError

    _check(args)
    if args.clip is not None:
        camera, frames = _clip_frames(args.clip, args.fps)
    else:
        camera, frames = _realsense_frames(args.bag, args.realtime)
    session = _open(args, camera)
    if not args.json:
        print(f"stream {session.stream_id} open (job {session.job_id})", file=sys.stderr, flush=True)
    try:
        with session:
            sent, started, last = _send(session, frames, args, camera)
            result = session.finish(timeout_s=120)
            latency = time.monotonic() - last
    except EigenscopeError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        f"sent {sent} frames in {last - started:.2f} s; result {latency * 1000:.0f} ms after the last frame"
        + (f"; converged: {session.converged}" if session.estimate else ""),
        file=sys.stderr,
    )
    for obj in result.get("objects", []):
        print(
            f"object {obj['id']}: f = {obj['eigenfrequency_hz']:.4f} Hz, "
            f"ζ = {obj.get('damping_ratio') or 0:.3f}{_mechanics_text(obj)}"
        )
    print(f"job {session.job_id}: {args.server.rstrip('/')}/v1/jobs/{session.job_id}")
    return 0


def _mechanics_text(values: dict[str, Any]) -> str:
    """``, k = … N/m, m = … kg`` of an estimate or a result's object, or nothing when they are null."""
    k, m = values.get("stiffness_n_per_m"), values.get("mass_kg")
    return "" if k is None or m is None else f", k = {k:.4g} N/m, m = {m:.4g} kg"


def _check(args: argparse.Namespace) -> None:
    """The options' combinations: a clip or a camera, --bag with --realsense, enough frames."""
    if args.realsense == (args.clip is not None):
        raise UsageError("give either a CLIP to replay or --realsense (with --bag FILE for a recording)")
    if args.bag is not None and not args.realsense:
        raise UsageError("--bag needs --realsense")
    if args.frames is not None and args.frames < 8:
        raise UsageError(f"--frames={args.frames}: send at least 8 frames")
    if args.clip is not None and not args.clip.exists():
        raise UsageError(f"{args.clip}: no such file")


def _open(args: argparse.Namespace, camera: Any) -> Any:
    """The live stream's session, opened on the server with the camera's rate, intrinsics and size."""
    from eigenscope_client import EigenscopeError, StreamSession

    k = camera.intrinsics
    quiet = args.json
    try:
        return StreamSession(
            args.server,
            api_key=args.api_key or os.environ.get("EIGENSCOPE_API_KEY") or None,
            excitation=_excitation(args),
            fps=args.fps or camera.fps,
            fx=k[0] if k else None,
            fy=k[1] if k else None,
            cx=k[2] if k else None,
            cy=k[3] if k else None,
            depth_scale=camera.depth_scale,
            target_relative_uncertainty=args.target,
            max_duration_s=args.max_duration,
            width=camera.width,
            height=camera.height,
            realtime=args.realtime,
            on_message=lambda m: _show(m, quiet),
        )
    except EigenscopeError as exc:
        raise UsageError(str(exc)) from None


def _send(session: Any, frames: Any, args: argparse.Namespace, camera: Any) -> tuple[int, float, float]:
    """Send the frames (at their capture rate with --realtime) until --frames, the end, or convergence
    with --stop-when-converged; the frames sent, and the clock when sending started and ended."""
    sent = 0
    started = time.monotonic()
    first_t: float | None = None
    for frame in frames:
        if args.frames is not None and sent >= args.frames:
            break
        if args.realtime:
            first_t = frame.timestamp_s if first_t is None else first_t
            delay = started + (frame.timestamp_s - first_t) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        session.send_frame(
            _encode(frame.rgb, args.png),
            timestamp_s=frame.timestamp_s,
            depth=None if frame.depth_units is None else frame.depth_units.tobytes(),
            color_encoding="png" if args.png else "jpeg",
            width=camera.width,
            height=camera.height,
        )
        sent += 1
        if args.stop_when_converged and session.converged:
            break
    return sent, started, time.monotonic()
