"""The field peer's modal analysis, as a user of pyidi 1.4 and sdypy-EMA would make it (run by
``bench/modes_peer.py`` with a Python that has both: the ``bench`` extra, never a runtime dependency).

The grey frames (a ``.npy`` array, T x H x W) are tracked by Lucas-Kanade on points placed by hand along the
beam's centre line; the displacements' spectra from the strike on (a free decay: its spectrum is the
receptance times the strike's flat spectrum) go to sdypy-EMA's LSCF for the poles, the poles nearest the
frequencies a user reads off the stabilisation chart are picked (given here, as a user would type them),
and LSFD gives the mode shapes. Prints one JSON line: seconds, and per mode the natural frequency, damping
and shape at the points.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time

import numpy as np


def main() -> None:
    frames_path, fps, x0, x1, y, count = (
        sys.argv[1],
        float(sys.argv[2]),
        float(sys.argv[3]),
        float(sys.argv[4]),
        float(sys.argv[5]),
        int(sys.argv[6]),
    )
    picks = [float(v) for v in sys.argv[7].split(",")]
    strike = int(sys.argv[8])
    started = time.perf_counter()
    video_array = np.load(frames_path)
    from pyidi import LucasKanade, VideoReader

    columns = np.linspace(x0, x1, count)
    points = np.array([(y, c) for c in columns])
    video = VideoReader(video_array, root=tempfile.mkdtemp(prefix="pyidi-"), fps=fps)
    idi = LucasKanade(video)
    idi.set_points(points)
    idi.configure(roi_size=(11, 11), verbose=0, show_pbar=False)
    displacements = idi.get_displacements()  # (points, frames, 2): (y, x)
    tracked_s = time.perf_counter() - started
    motion = displacements[:, :, 0]
    motion = motion - motion[:, :strike].mean(axis=1, keepdims=True)  # from the rest position
    motion = motion[:, strike:]  # the free decay, from the strike (a user sees it in the video)
    spectrum = np.fft.rfft(motion, axis=1)
    freq = np.fft.rfftfreq(motion.shape[1], 1 / fps)

    from sdypy import EMA

    model = EMA.Model(
        frf=spectrum, freq=freq, lower=2.0, upper=0.42 * fps, pol_order_high=60, frf_form="receptance"
    )
    model.get_poles(show_progress=False)
    # A narrow search window: sdypy's default (50 Hz) lets a low pick slide to the masked 0 Hz entries.
    model.select_closest_poles(picks, f_window=7)
    _, shapes = model.get_constants(whose_poles="own")
    elapsed = time.perf_counter() - started
    modes = []
    for k in range(len(model.nat_freq)):
        shape = np.asarray(shapes[:, k])
        shape = shape * np.exp(-0.5j * np.angle(np.sum(shape**2)))
        modes.append(
            {
                "frequency_hz": float(model.nat_freq[k]),
                "damping_ratio": float(model.nat_xi[k]),
                "shape": [float(v) for v in shape.real],
            }
        )
    print(
        json.dumps(
            {
                "seconds": elapsed,
                "tracking_seconds": tracked_s,
                "points": [float(c) for c in columns],
                "modes": modes,
            }
        )
    )


if __name__ == "__main__":
    main()
