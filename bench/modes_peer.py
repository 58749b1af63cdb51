"""Modes against the field peer (issue 30): a struck cantilever rendered with its first three bending modes
(Euler-Bernoulli, :mod:`workers.pipeline.synth_beam`), measured by ``eigenscope analyze`` (the whole frame,
no points, no frequencies given) and by pyidi 1.4's Lucas-Kanade on points placed by hand along the beam
with sdypy-EMA's LSCF and LSFD (the poles picked nearest the true frequencies, as a user reads them off a
stabilisation chart), in alternating rounds, each in a fresh process. Prints per mode the frequency and
damping errors and the MAC of each tool's shape against the analytic one along the beam, and the wall time
of each.

pyidi and sdypy-EMA are bench-only (``--peer-python``: a Python that has them); never runtime dependencies.

    python bench/modes_peer.py [--rounds 3 --points 24 --peer-python /tmp/peer/bin/python]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.peer import _run  # noqa: E402
from workers.pipeline.clipio import write_npz  # noqa: E402
from workers.pipeline.modes import mac  # noqa: E402
from workers.pipeline.synth_beam import BeamScene, render_beams  # noqa: E402


def _ours(out: Path, beam, columns_of) -> list[dict]:  # type: ignore[no-untyped-def]
    result = json.loads((out / "result.json").read_text())
    with np.load(out / "modes.npz") as arrays:
        obj = result["objects"][0]
        shapes = arrays[f"object_{obj['id']}_shapes"][..., 1]
    rows = []
    for m, mode in enumerate(obj["modes"]):
        columns = columns_of(shapes[m])
        with np.errstate(all="ignore"):
            profile = np.nanmean(shapes[m][:, columns], axis=0)
        rows.append(_row("eigenscope", mode["frequency_hz"], mode["damping_ratio"], profile, columns, beam))
    return rows


def _row(tool, f, zeta, profile, columns, beam) -> dict:  # type: ignore[no-untyped-def]
    r = int(np.argmin([abs(f - beam.damped_hz(i)) for i in range(len(beam.damping_ratios))]))
    truth_f = beam.damped_hz(r) if tool == "eigenscope" else beam.natural_hz(r)
    return {
        "tool": tool,
        "mode": r + 1,
        "f_hz": f,
        "f_err_%": 100 * abs(f - truth_f) / truth_f,
        "zeta_err_%": None
        if zeta is None
        else 100 * abs(zeta - beam.damping_ratios[r]) / beam.damping_ratios[r],
        "mac": mac(np.asarray(profile), beam.shape(r, np.asarray(columns, float))),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--points", type=int, default=24)
    parser.add_argument("--peer-python", default=sys.executable, help="a Python with pyidi and sdypy-EMA")
    args = parser.parse_args()
    scene = BeamScene()
    beam = scene.beams[0]
    clip = render_beams(scene)
    work = Path(tempfile.mkdtemp(prefix="modes-peer-"))
    clip_path = work / "beam.npz"
    write_npz(clip_path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
    grey = (clip.rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float64)
    np.save(work / "grey.npy", grey)
    x0, y0 = beam.root_px
    peer = [
        args.peer_python,
        str(ROOT / "bench" / "_pyidi_modes.py"),
        str(work / "grey.npy"),
        str(scene.fps),
        str(x0 + 0.1 * beam.length_px),
        str(x0 + beam.length_px - 6),
        str(y0),
        str(args.points),
        ",".join(f"{beam.natural_hz(r):.3f}" for r in range(len(beam.damping_ratios))),
        str(beam.strike_frame),
    ]
    ours = [sys.executable, "-m", "eigenscope", "analyze", str(clip_path), "--out", str(work / "out")]
    times: dict[str, list[float]] = {"eigenscope": [], "pyidi+EMA": []}
    rows: list[dict] = []
    for _ in range(args.rounds):
        seconds, _, _ = _run(ours)
        times["eigenscope"].append(seconds)
        seconds, _, stdout = _run(peer)
        times["pyidi+EMA"].append(seconds)
    peer_out = json.loads(stdout.strip().splitlines()[-1])
    rows += _ours(work / "out", beam, lambda shape: np.flatnonzero(np.isfinite(shape).any(axis=0)))
    for mode in peer_out["modes"]:
        rows.append(
            _row(
                "pyidi+EMA",
                mode["frequency_hz"],
                mode["damping_ratio"],
                mode["shape"],
                peer_out["points"],
                beam,
            )
        )
    print(f"{'tool':<11} {'mode':>4} {'f (Hz)':>9} {'f err %':>8} {'zeta err %':>10} {'MAC':>6}")
    for row in rows:
        zeta = "-" if row["zeta_err_%"] is None else f"{row['zeta_err_%']:.1f}"
        print(
            f"{row['tool']:<11} {row['mode']:>4} {row['f_hz']:>9.3f} {row['f_err_%']:>8.3f} {zeta:>10} "
            f"{row['mac']:>6.3f}"
        )
    for tool, values in times.items():
        print(f"{tool:<11} wall {statistics.median(values):.2f} s (median of {len(values)})")
    ratio = statistics.median(times["eigenscope"]) / statistics.median(times["pyidi+EMA"])
    print(f"ratio eigenscope / pyidi+EMA: {ratio:.2f}")
    print(f"(pyidi's tracking alone: {peer_out['tracking_seconds']:.2f} s of {peer_out['seconds']:.2f} s)")


if __name__ == "__main__":
    main()
