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
    from numpy.typing import NDArray

    from workers.pipeline.clipio.types import ClipReader, Intrinsics
    from workers.pipeline.model import Analysis, AnalysisConfig, Excitation, ObjectMeasurement, Progress
    from workers.pipeline.window import Plan


def analyze_paper(
    reader: ClipReader,
    *,
    config: AnalysisConfig,
    excitation: Excitation | None,
    progress: Progress | None,
) -> Analysis:
    """Run the paper's recipe on ``reader``; see the module docstring. Returns an :class:`Analysis`."""
    from workers.pipeline.metric import object_depth
    from workers.pipeline.model import Analysis, QualityNote, Stopwatch
    from workers.pipeline.stream import stream_frames
    from workers.pipeline.window import analysis_band, plan_analysis

    watch = Stopwatch()
    info = reader.info
    plan = plan_analysis(info, config)  # the paper's recipe: the given (or first) window, every frame
    buffers = stream_frames(reader, plan.start, plan.stop, plan.grid, plan.flow, progress, magnitude=True)
    watch.stream_lap(buffers.decode_s)
    n = buffers.count
    band = analysis_band(config, plan.sample_rate_hz, n)
    mags = buffers.flow[..., 0].reshape(n, -1)
    spectra, freqs, summed, k = _summed_spectrum(mags, plan.sample_rate_hz)
    f = float(freqs[k])
    watch.lap("spectrum")

    pixel_peak, mask = _peak_bin_mask(spectra, k, plan.grid)
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
        depth = object_depth(buffers.depth, mask) or config.depth_m
        x_px = _amplitude_px(mags, mask, plan, f)
        objects.append(
            _paper_object(f, x_px, depth, labels, plan.sample_rate_hz / n, info.intrinsics, excitation)
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
        fps=plan.sample_rate_hz,
        fps_source=info.fps_source or "unknown",
        frames_used=(plan.start, plan.stop),
        band_hz=band,
        quality=quality,
        timings_s=watch.times,
        parameters=config.describe() | {"frames": plan.stop - plan.start},
        method="paper",
    )


def _summed_spectrum(
    mags: NDArray[np.float32], sample_rate_hz: float
) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float32], int]:
    """Steps 2 and 3: each pixel's power spectrum of ``mags`` (N, pixels), their sum, its argmax bin.

    Returns (spectra (F, pixels), frequencies_hz (F,), summed (F,), the argmax bin above 0 Hz); the
    spectra keep the single precision of the flow.
    """
    n = len(mags)
    spectra = np.abs(np.fft.rfft(mags, axis=0)) ** 2
    freqs = np.fft.rfftfreq(n, d=1.0 / sample_rate_hz).astype(np.float64)
    summed = spectra.sum(axis=1)
    usable = np.flatnonzero(freqs > 0)
    k = int(usable[np.argmax(summed[usable])])
    return spectra, freqs, summed, k


def _peak_bin_mask(
    spectra: NDArray[np.float32], k: int, grid: tuple[int, int]
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Step 4: each pixel's peak bin (above DC), and the (grid-shaped) mask of the pixels peaking in bin
    ``k`` well above the median pixel, morphologically opened."""
    import cv2

    pixel_peak = np.argmax(spectra[1:], axis=0) + 1
    level = spectra[k]
    mask = (pixel_peak == k) & (level > 8.0 * np.median(level))
    mask_img = mask.reshape(grid).astype(np.uint8)
    mask_img = cv2.morphologyEx(mask_img, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    return pixel_peak, mask_img.astype(bool)


def _amplitude_px(mags: NDArray[np.float32], mask: NDArray[np.bool_], plan: Plan, f: float) -> float:
    """Step 5's amplitude Vmax / (4 f), input pixels, with Vmax the mask's peak mean speed (px/s)."""
    speed = mags[:, mask.ravel()].mean(axis=1) * plan.pixel_scale  # px/frame, input pixels
    v_max = float(speed.max()) * plan.sample_rate_hz  # px/s
    return v_max / (4 * f) if f > 0 else 0.0


def _paper_object(
    f: float,
    x_px: float,
    depth: float | None,
    labels: NDArray[np.uint16],
    bin_hz: float,
    intrinsics: Intrinsics | None,
    excitation: Excitation | None,
) -> ObjectMeasurement:
    """The one object of the recipe: frequency ``f`` (an FFT bin ``bin_hz`` wide), amplitude ``x_px`` and
    the mechanics of step 5 (object 1 of ``labels``)."""
    from workers.pipeline.measure import bounding_box
    from workers.pipeline.model import ObjectMeasurement

    x_m, stiff, mass, reasons = _mechanics(f, x_px, depth, intrinsics, excitation)
    return ObjectMeasurement(
        id=1,
        eigenfrequency_hz=f,
        eigenfrequency_uncertainty_hz=bin_hz / math.sqrt(12),
        natural_frequency_hz=f,
        damping_ratio=None,
        damping_ratio_uncertainty=None,
        amplitude_px=x_px,
        amplitude_m=x_m,
        amplitude_uncertainty_m=None,
        depth_m=depth,
        motion_direction=None,
        stiffness_n_per_m=stiff,
        stiffness_uncertainty_n_per_m=None,
        mass_kg=mass,
        mass_uncertainty_kg=None,
        pixel_count=int((labels == 1).sum()),
        bbox_px=bounding_box(labels == 1),
        harmonics_hz=[],
        release_time_s=None,
        snr_db=None,
        null_reasons=reasons,
    )


def _mechanics(
    f: float,
    x_px: float,
    depth: float | None,
    intrinsics: Intrinsics | None,
    excitation: Excitation | None,
) -> tuple[float | None, float | None, float | None, list[str]]:
    """Step 5's amplitude in metres, stiffness and mass, each None when not measurable, and the reasons.

    ω = 2πf; a held force F gives k = F / x and m = k / ω², an impulse J gives m = J / (x ω), k = m ω².
    """
    omega = 2 * math.pi * f
    x_m = stiff = mass = None
    reasons: list[str] = []
    if depth is not None and intrinsics is not None:
        x_m = x_px * depth / intrinsics.fx
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
    return x_m, stiff, mass, reasons
