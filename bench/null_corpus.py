"""The null corpus (issue 25): clips where nothing vibrates, and the detection statistic's false-alarm rate
measured on them against the rate it states.

Still scenes, textured and flat, at 30, 60 and 240 fps with sensor noise, each through one of the codecs of
phones and action cameras (``workers.pipeline.synth_corpus.still_corpus``), and still parts of the shared
real footage (the flat background beside the forks, when ``../shared`` is there). For each clip it prints
the objects reported (there should be none) and the smallest false-alarm probability per clip of any line
of the scan statistic (what noise alone reached); then, for several bounds alpha, the fraction of clips
whose smallest probability is at most alpha: for a calibrated (or conservative) statistic it is at most
alpha. Last, the law's tail itself: over every frequency of every clip, how many reach a probability per
frequency of at most q, against the q times their number expected of noise (lines of a codec's keyframe
comb and of a fork seen through a still crop count here too: the artefact tests, not the law, set them
aside).

    python bench/null_corpus.py [--out DIR] [--no-real] [--rounds R]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import eigenscope  # noqa: F401  (thread settings before numpy)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from workers.pipeline.analysis import AnalysisConfig, analyze  # noqa: E402
from workers.pipeline.calibration import ARTEFACT_BINS  # noqa: E402
from workers.pipeline.clipio import ClipOverrides, open_clip  # noqa: E402
from workers.pipeline.detection import significant_bins  # noqa: E402
from workers.pipeline.front import front_of_look  # noqa: E402
from workers.pipeline.look import look_at  # noqa: E402
from workers.pipeline.significance import MAX_FALSE_ALARM  # noqa: E402
from workers.pipeline.synth_corpus import (  # noqa: E402
    REAL_STILL_CROPS,
    ColumnCrop,
    encode,
    still_corpus,
)
from workers.pipeline.window import analysis_band, plan_analysis  # noqa: E402

#: Evidence of the analysis's rejected peaks that names an artefact of the camera, not a motion.
ARTEFACT_EVIDENCE = {"codec_keyframes", "illumination_flicker", "camera_motion"}

SHARED = ROOT.parent / "shared" / "data" / "real" / "tuning-forks"


def scan_probabilities(reader, artefacts_hz: list[float]) -> tuple[float, float, np.ndarray]:
    """The smallest false-alarm probability per clip of any line of the window's scan statistic, the
    smallest of the lines the analysis did not set aside as artefacts (away from ``artefacts_hz``, a
    codec's keyframe comb or mains flicker, and their skirts), and the probability per frequency of every
    frequency of the band (what noise alone reaches at each)."""
    config = AnalysisConfig()
    plan = plan_analysis(reader.info, config, reader=reader)
    source, first, last = plan.source(reader)
    look = look_at(source, first, last)
    band = analysis_band(config, plan.sample_rate_hz, look.count)
    scan = front_of_look(
        look, sample_rate_hz=plan.sample_rate_hz, band_hz=band, max_objects=config.max_objects
    ).scan
    lines = significant_bins(scan, limit=1.0)
    smallest = float(scan.calibration.p_clip(scan.z[lines[0]])) if lines else 1.0
    # A strong artefact line's skirt (the taper's sidelobes) reaches two bins further, as the calibration's
    # fit allows for (``calibration.FIT_OUTLIER_Z``'s neighbours).
    reach = (ARTEFACT_BINS + 2) * scan.bin_hz
    away = [k for k in lines if all(abs(scan.frequencies_hz[k] - f) > reach for f in artefacts_hz)]
    smallest_away = float(scan.calibration.p_clip(scan.z[away[0]])) if away else 1.0
    return smallest, smallest_away, np.asarray(scan.calibration.p_frequency(scan.z), np.float64)


def artefact_lines(analysis) -> list[float]:
    """Frequencies the analysis set aside as artefacts of the camera: each such rejected peak, and every
    tooth of a codec's keyframe comb it named (``comb_hz`` and its multiples up to Nyquist)."""
    nyquist = analysis.sample_rate_hz / 2
    out: list[float] = []
    for r in analysis.rejected_peaks:
        if r.evidence not in ARTEFACT_EVIDENCE:
            continue
        out.append(r.frequency_hz)
        comb = r.figures.get("comb_hz")
        if comb:
            out.extend(comb * k for k in range(1, int(nyquist / comb) + 1))
    return out


def clips(folder: Path, *, real: bool, rounds: int = 1):
    stills = [still for r in range(rounds) for still in still_corpus(round_index=r)]
    for still in stills:
        path = folder / f"{still.name}.mp4"
        if not path.exists():
            encode(
                still.scene,
                path,
                codec=still.codec,
                bit_rate=still.bit_rate,
                keyframe_every=still.keyframe_every,
            )
        yield still.name, (lambda p=path: open_clip(p))
    if real and SHARED.is_dir():
        for f, fps, x0, x1 in REAL_STILL_CROPS:
            path = SHARED / f"tuning_hz{f}_fps{fps}_50-1_640x420.mp4"
            yield (
                f"real {f} Hz fork clip at {fps} fps, columns {x0}-{x1}",
                lambda p=path, r=fps, a=x0, b=x1: ColumnCrop(
                    open_clip(p, overrides=ClipOverrides(fps=r)), a, b
                ),
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--out", type=Path, help="where the encoded clips are kept (default: a temporary folder)"
    )
    parser.add_argument("--no-real", action="store_true", help="leave out the shared real footage")
    parser.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="the still scenes this many times, each round with other seeds (12 clips a round): enough "
        "clips to measure the rate at bounds of 0.05-0.5, where a handful of clips says nothing",
    )
    args = parser.parse_args()
    folder = args.out or Path(tempfile.mkdtemp(prefix="null-corpus-"))
    folder.mkdir(parents=True, exist_ok=True)
    smallest: list[float] = []
    smallest_away: list[float] = []
    per_frequency: list[np.ndarray] = []
    false_objects = 0
    print(f"{'clip':58s} {'objects':>7s} {'min p/clip':>11s} {'not artefact':>12s} {'s':>6s}")
    for name, make in clips(folder, real=not args.no_real, rounds=args.rounds):
        started = time.perf_counter()
        with make() as reader:
            analysis = analyze(reader)
        artefacts_hz = artefact_lines(analysis)
        with make() as reader:
            p, p_away, each = scan_probabilities(reader, artefacts_hz)
        smallest.append(p)
        smallest_away.append(p_away)
        per_frequency.append(each)
        false_objects += len(analysis.objects)
        print(
            f"{name:58s} {len(analysis.objects):7d} {p:11.3g} {p_away:12.3g} "
            f"{time.perf_counter() - started:6.1f}",
            flush=True,
        )
    values, away = np.asarray(smallest), np.asarray(smallest_away)
    print(f"\n{len(values)} clips, {false_objects} false objects (reported at p <= {MAX_FALSE_ALARM:g})")
    print("stated alpha   measured rate: clips whose smallest probability per clip is <= alpha")
    print("               every line    lines not set aside as artefacts")
    for alpha in (MAX_FALSE_ALARM, 0.01, 0.05, 0.1, 0.3, 0.5):
        every_rate, away_rate = float(np.mean(values <= alpha)), float(np.mean(away <= alpha))
        print(f"{alpha:12g}   {every_rate:10.3f}    {away_rate:10.3f}")
    every = np.concatenate(per_frequency)
    print(f"\nper frequency, {every.size} frequencies of {len(values)} clips (the law's tail itself)")
    print("stated q       frequencies at p <= q: measured (expected)")
    for q in (1e-4, 1e-3, 0.01, 0.1, 0.5):
        print(f"{q:12g}   {int(np.sum(every <= q)):5d} ({q * every.size:.1f})")


if __name__ == "__main__":
    main()
