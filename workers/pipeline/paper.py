"""The paper's recipe, step by step, kept for comparison (never the default).

1. Farnebäck flow at full resolution, its per-pixel magnitude |v| (px/frame).
2. numpy FFT of |v| along time for every pixel; spectra summed over pixels.
3. Eigenfrequency = the argmax bin of the summed spectrum (one bin = fps / N).
4. Mask = pixels whose own spectrum peaks in that bin, well above the median pixel.
5. Amplitude x ≈ Vmax / (4 f) with Vmax the object's peak speed (px/s), converted to metres with depth and
   focal length; k = F / x (held force) or m = J / (x ω) (impulse); ω = 2πf; m = k / ω².

Known faults, which the default method fixes: |v| rings at 2f, the decaying envelope piles power into the
lowest bins, one bin is 10 % wide at N = 64, and Vmax / 4f is not the amplitude of a sampled sine.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from workers.pipeline.segmentation import upsample_labels

if TYPE_CHECKING:
    from workers.pipeline.clipio.types import ClipReader
    from workers.pipeline.model import Analysis, AnalysisConfig, Excitation, Progress


def analyze_paper(
    reader: ClipReader,
    *,
    config: AnalysisConfig,
    excitation: Excitation | None,
    progress: Progress | None,
) -> Analysis:
    """Run the paper's recipe on ``reader``; see the module docstring. Returns an :class:`Analysis`."""
    import cv2

    from workers.pipeline.measure import bounding_box
    from workers.pipeline.metric import object_depth
    from workers.pipeline.model import Analysis, ObjectMeasurement, QualityNote, Stopwatch
    from workers.pipeline.stream import stream_frames
    from workers.pipeline.window import analysis_band, plan_analysis

    watch = Stopwatch()
    info = reader.info
    plan = plan_analysis(info, config)  # the paper's recipe: the given (or first) window, every frame
    buffers = stream_frames(reader, plan.start, plan.stop, plan.grid, plan.flow, progress, magnitude=True)
    watch.stream_lap(buffers.decode_s)
    n = buffers.count
    band = analysis_band(config, plan.fps, n)
    mags = buffers.flow[..., 0].reshape(n, -1)
    spectra = np.abs(np.fft.rfft(mags, axis=0)) ** 2
    freqs = np.fft.rfftfreq(n, d=1.0 / plan.fps).astype(np.float64)
    summed = spectra.sum(axis=1)
    usable = np.flatnonzero(freqs > 0)
    k = int(usable[np.argmax(summed[usable])])
    f = float(freqs[k])
    watch.lap("spectrum")

    pixel_peak = np.argmax(spectra[1:], axis=0) + 1
    level = spectra[k]
    mask = (pixel_peak == k) & (level > 8.0 * np.median(level))
    mask_img = mask.reshape(plan.grid).astype(np.uint8)
    mask_img = cv2.morphologyEx(mask_img, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    mask = mask_img.astype(bool)
    labels = upsample_labels(mask.astype(np.int32), (info.height, info.width))
    watch.lap("segmentation")

    quality = [
        QualityNote(
            "paper_method",
            "the paper's recipe: flow magnitude rings at twice the frequency and the argmax bin is one FFT "
            "bin wide; compare with the default method",
            "info",
        )
    ]
    objects = []
    if mask.any():
        speed = mags[:, mask.ravel()].mean(axis=1) * plan.pixel_scale  # px/frame, input pixels
        v_max = float(speed.max()) * plan.fps  # px/s
        x_px = v_max / (4 * f) if f > 0 else 0.0
        depth = object_depth(buffers.depth, mask) or config.depth_m
        omega = 2 * math.pi * f
        x_m = stiff = mass = None
        reasons: list[str] = []
        if depth is not None and info.intrinsics is not None:
            x_m = x_px * depth / info.intrinsics.fx
            if excitation is not None and x_m > 0:
                if excitation.kind == "step_release":
                    stiff = excitation.value / x_m
                    mass = stiff / omega**2
                else:
                    mass = excitation.value / (x_m * omega)
                    stiff = mass * omega**2
            elif excitation is None:
                reasons.append("no excitation given: stiffness and mass need a held force or an impulse")
        else:
            reasons.append("no depth or intrinsics: amplitude in metres is not measurable")
        objects.append(
            ObjectMeasurement(
                id=1,
                eigenfrequency_hz=f,
                eigenfrequency_sd_hz=plan.fps / n / math.sqrt(12),
                natural_frequency_hz=f,
                damping_ratio=None,
                damping_ratio_sd=None,
                amplitude_px=x_px,
                amplitude_m=x_m,
                amplitude_sd_m=None,
                depth_m=depth,
                motion_direction=None,
                stiffness_n_per_m=stiff,
                stiffness_sd=None,
                mass_kg=mass,
                mass_sd=None,
                pixel_count=int((labels == 1).sum()),
                bbox_px=bounding_box(labels == 1),
                harmonics_hz=[],
                release_time_s=None,
                snr_db=None,
                null_reasons=reasons,
            )
        )
    watch.lap("mechanics")
    valid = np.zeros(plan.grid, bool)
    fmap = freqs[pixel_peak].astype(np.float32).reshape(plan.grid)
    return Analysis(
        objects=objects,
        labels=labels,
        frequencies_hz=freqs,
        power=summed.astype(np.float64),
        frequency_map_hz=fmap,
        frequency_map_valid=valid | mask,
        frame_rgb=buffers.first_rgb,
        fps=plan.fps,
        fps_source=info.fps_source or "unknown",
        frames_used=(plan.start, plan.stop),
        band_hz=band,
        quality=quality,
        timings_s=watch.times,
        parameters=config.describe() | {"frames": plan.stop - plan.start},
        method="paper",
    )
