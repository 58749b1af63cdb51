"""The field peer's run, as a user of pyidi 1.4 would make it (run by ``bench/peer.py`` with a Python that
has pyidi: the ``bench`` extra, never a runtime dependency): the clip's frames decoded once into an array
(grey), Lucas-Kanade on a grid of points over the clip's hand-placed region of interest, and the frequency
read from the spectrum of the points it tracked (those on flat background have no solution). Prints one
JSON line: seconds, the frequency, the points and how many were tracked."""

from __future__ import annotations

import json
import sys
import tempfile
import time

import av
import numpy as np


def main() -> None:
    path, roi_file, fps, frames, count = (
        sys.argv[1],
        sys.argv[2],
        float(sys.argv[3]),
        int(sys.argv[4]),
        int(sys.argv[5]),
    )
    started = time.perf_counter()
    with av.open(path) as container:
        stream = container.streams.video[0]
        gray = []
        for frame in container.decode(stream):
            gray.append(frame.to_ndarray(format="gray"))
            if len(gray) >= frames:
                break
    video_array = np.stack(gray)
    decoded = time.perf_counter() - started

    from pyidi import LucasKanade, VideoReader

    with open(roi_file) as roi:
        x, y, w, h = (int(v) for v in roi.read().split()[:4])
    across = max(1, round((count * w / h) ** 0.5))
    rows = np.linspace(y + 4, y + h - 4, -(-count // across))
    cols = np.linspace(x + 4, x + w - 4, across)
    points = np.array([(r, c) for r in rows for c in cols])
    video = VideoReader(video_array, root=tempfile.mkdtemp(prefix="pyidi-"), fps=fps)
    idi = LucasKanade(video)
    idi.set_points(points)
    idi.configure(roi_size=(9, 9), verbose=0, show_pbar=False)
    displacements = idi.get_displacements()
    # points on flat background have no solution (NaN): a user keeps the points that were tracked
    tracked = np.isfinite(displacements).all(axis=(1, 2))
    motion = np.diff(displacements[tracked, :, 1], axis=1)  # x velocity per point (the slow drift left out)
    motion -= motion.mean(axis=1, keepdims=True)
    spectra = np.abs(np.fft.rfft(motion * np.hanning(motion.shape[1]), n=8 * motion.shape[1], axis=1)) ** 2
    freqs = np.fft.rfftfreq(8 * motion.shape[1], 1 / fps)
    band = freqs >= 2.0 * fps / motion.shape[1]
    f = float(freqs[band][np.argmax(spectra.sum(axis=0)[band])])
    print(
        json.dumps(
            {
                "seconds": time.perf_counter() - started,
                "decode_s": decoded,
                "frequency_hz": f,
                "points": len(points),
                "tracked": int(tracked.sum()),
            }
        )
    )


if __name__ == "__main__":
    main()
