"""Reasons why a result or an object's figures may be unreliable, for the result's quality notes: the
clip (damaged, blank, a frame rate that may be wrong), the window's resolution, and each object.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.model import ObjectMeasurement, QualityNote
from workers.pipeline.verdicts import SECOND_MOTION_SHARE

if TYPE_CHECKING:
    from workers.pipeline.clipio.types import ClipInfo
    from workers.pipeline.stream import FrameBuffers
    from workers.pipeline.window import Plan

#: Objects closer than this many lines of the window's resolution are not resolved from each other.
CLOSE_LINES = 3.0
#: A second motion in an object's region this strong (relative to the first) is not resolved.
SECOND_MOTION = SECOND_MOTION_SHARE
#: Container rates that high-speed cameras write into files whose frames they captured much faster.
PLAYBACK_RATES = (23.976, 24.0, 25.0, 29.97, 30.0, 50.0, 59.94, 60.0)


def clip_notes(plan: Plan, buffers: FrameBuffers, info: ClipInfo) -> list[QualityNote]:
    """What the clip itself did: frames that did not decode, a rate taken from capture metadata."""
    notes: list[QualityNote] = []
    decoded = plan.decodable_frames
    analysed_stop = plan.start + buffers.count * plan.step + 1
    if buffers.count < buffers.announced:
        decoded = min(decoded, analysed_stop)
    if decoded < info.frames:
        notes.append(
            QualityNote(
                "damaged_file",
                f"the clip lists {info.frames} frames but only the first {decoded} could be decoded (a "
                f"truncated or damaged file): frames {decoded}-{info.frames - 1} are missing, and frames "
                f"{plan.start}-{analysed_stop - 1} were analysed",
            )
        )
    if info.fps_source == "metadata":
        notes.append(
            QualityNote(
                "frame_rate",
                f"the frame rate {info.fps:g} fps is the capture rate the file's metadata records (it plays "
                f"at {info.container_fps or 0:g} fps); give --fps if that is wrong",
                "info",
            )
        )
    return notes


#: Frames are uniform when their grey level varies less than this (standard deviation, grey levels) over
#: the picture and within every block of :data:`BLANK_BLOCK_PX` pixels: a lens cap or a dark room shows
#: sensor noise only, while one thin edge (a bar 7 grey levels darker than a flat wall) is something to track.
BLANK_STD = 2.0
BLANK_BLOCK_PX = 16


def _block_std_max(grey: NDArray[np.float32]) -> float:
    """The largest standard deviation of ``grey`` (H, W) within blocks of :data:`BLANK_BLOCK_PX` pixels."""
    h, w = grey.shape
    size = (max(1, w // BLANK_BLOCK_PX), max(1, h // BLANK_BLOCK_PX))
    mean = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    mean_sq = cv2.resize(grey * grey, size, interpolation=cv2.INTER_AREA)
    return float(np.sqrt(max(float(np.max(mean_sq - mean * mean)), 0.0)))


def frame_notes(buffers: FrameBuffers) -> list[QualityNote]:
    """Frames with nothing to track: uniform (a lens cap, a dark room, a blown-out exposure)."""
    rgb = buffers.first_rgb
    # the mean of the three channels, summed a plane at a time (numpy's mean over an axis of three takes
    # eight times as long, 6 ms of a live stream's final analysis; the same numbers)
    grey = rgb[..., 0].astype(np.float32)
    grey += rgb[..., 1]
    grey += rgb[..., 2]
    grey /= np.float32(3)
    level = float(grey.mean())
    clipped = float(np.mean((grey <= 2) | (grey >= 253)))
    change = float(np.max(buffers.frame_change)) if buffers.frame_change is not None else 0.0
    if float(grey.std()) < BLANK_STD and change < 1.0 and _block_std_max(grey) < BLANK_STD:
        what = "black" if level < 16 else "white" if level > 240 else "uniform"
        return [
            QualityNote(
                "blank_frames",
                f"the frames are {what} (no texture, nothing changes): there is nothing to track; check "
                "the exposure, the lens cap and that the right stream was recorded",
                "error",
            )
        ]
    if clipped > 0.9:
        return [
            QualityNote(
                "saturation",
                f"{clipped * 100:.0f} % of the picture is clipped black or white: only its remaining "
                "texture can be tracked; adjust the exposure",
            )
        ]
    return []


def close_pairs(
    objects: list[ObjectMeasurement], *, bin_hz: float
) -> list[tuple[ObjectMeasurement, ObjectMeasurement]]:
    """Pairs of objects closer in frequency than ``CLOSE_LINES`` lines of ``bin_hz``."""
    return [
        (a, b)
        for a, b in itertools.combinations(objects, 2)
        if abs(a.eigenfrequency_hz - b.eigenfrequency_hz) < CLOSE_LINES * bin_hz
    ]


def resolution_notes(
    objects: list[ObjectMeasurement], *, bin_hz: float, window_s: float
) -> list[QualityNote]:
    """Objects whose frequencies the window does not resolve from each other, or whose region holds a
    second oscillation close to its own."""
    notes: list[QualityNote] = []
    for a, b in close_pairs(objects, bin_hz=bin_hz):
        gap = abs(a.eigenfrequency_hz - b.eigenfrequency_hz)
        notes.append(
            QualityNote(
                "close_frequencies",
                f"objects {a.id} and {b.id} ({a.eigenfrequency_hz:.4g} and {b.eigenfrequency_hz:.4g} Hz) "
                f"are {gap:.3g} Hz apart, closer than {CLOSE_LINES:g} lines of the {window_s:.3g} s "
                f"window ({bin_hz:.3g} Hz each): they may mix; record longer to separate them",
            )
        )
    for obj in objects:
        if obj.second_motion >= SECOND_MOTION:
            notes.append(
                QualityNote(
                    "close_frequencies",
                    f"object {obj.id} ({obj.eigenfrequency_hz:.4g} Hz): its region holds a second motion "
                    f"near that frequency ({obj.second_motion * 100:.0f} % of the first's power) that the "
                    f"{window_s:.3g} s window does not resolve: record longer to separate them",
                )
            )
    return notes


def frame_rate_notes(
    objects: list[ObjectMeasurement], info: ClipInfo, *, window_s: float
) -> list[QualityNote]:
    """A frame rate that may be wrong: taken from a container while the clip looks high-speed.

    High-speed cameras write a playback rate (25, 30, 50 fps) into the file: read at that rate, a 32 Hz
    fork filmed at 1000 fps rings at 1.6 Hz. The note is given when the rate came from the container and
    the file name or metadata names a capture rate, or every vibration found is slow yet rings for many
    lightly damped periods, as struck forks and strings do at their true rate.
    """
    if info.fps_source != "container" or info.fps is None:
        return []
    hint = info.capture_fps_hint
    if hint is not None and abs(hint / info.fps - 1) > 0.05:
        return [
            QualityNote(
                "frame_rate",
                f"the frame rate {info.fps:g} fps comes from the container, but "
                f"{info.capture_fps_hint_source} says {hint:g} fps: if the clip was filmed at high speed, "
                "give the true rate with --fps "
                f"{hint:g} (API: fps); every frequency scales with it",
            )
        ]
    playback = any(abs(info.fps - r) < 0.05 for r in PLAYBACK_RATES)
    if not objects or not playback:
        return []
    slow = all(
        o.eigenfrequency_hz < 5.0
        and o.eigenfrequency_hz * window_s >= 20
        and (o.damping_ratio is None or o.damping_ratio < 0.003)
        for o in objects
    )
    if not slow:
        return []
    f = objects[0].eigenfrequency_hz
    return [
        QualityNote(
            "frame_rate",
            f"the frame rate {info.fps:g} fps comes from the container, and every vibration found is slow "
            f"yet rings for many lightly damped periods ({f:.3g} Hz over {f * window_s:.0f} periods), as a "
            "struck fork or string filmed at high speed and played back slower does: if the clip was "
            "filmed at high speed, give the true rate with --fps (API: fps); every frequency scales with "
            f"it (filmed at k times {info.fps:g} fps, {f:.3g} Hz is k times {f:.3g} Hz)",
        )
    ]


def object_quality_notes(
    objects: list[ObjectMeasurement], *, sample_rate_hz: float, band: tuple[float, float], bin_hz: float
) -> list[QualityNote]:
    """Reasons why an object's figures may be unreliable."""
    notes: list[QualityNote] = []
    for obj in objects:
        f = obj.eigenfrequency_hz
        name = f"object {obj.id} ({f:.4g} Hz)"
        if f >= 0.4 * sample_rate_hz:
            notes.append(
                QualityNote(
                    "possibly_aliased",
                    f"{name} is near the Nyquist rate ({sample_rate_hz / 2:g} Hz): the true frequency may be "
                    f"{sample_rate_hz - f:.4g} Hz or higher; record at a higher frame rate or give the true "
                    "fps",
                )
            )
        if obj.snr_db is not None and obj.snr_db < 6:
            if obj.regime == "ring_down":
                advice = "push harder, light the object better or film closer"
            else:
                advice = "light the object better, film closer or record longer"
            notes.append(
                QualityNote(
                    "low_snr",
                    f"{name}: its oscillation stands only {obj.snr_db:.1f} dB above the noise in each frame "
                    f"({obj.detection_db or 0:.0f} dB over the window); {advice}",
                )
            )
        periods = f * obj.fitted_duration_s
        if periods < 3:
            notes.append(
                QualityNote(
                    "few_periods",
                    f"{name}: only {periods:.1f} periods of motion were analysed; record longer after the "
                    "release for reliable frequency and damping",
                )
            )
        if f - band[0] < 1.5 * bin_hz or band[1] - f < 1.5 * bin_hz:
            notes.append(
                QualityNote(
                    "band_edge",
                    f"{name} lies at the edge of the analysed band [{band[0]:.3g}, {band[1]:.3g}] Hz; "
                    "widen the band or change the window length",
                )
            )
        if obj.saturated_fraction > 0.05:
            notes.append(
                QualityNote(
                    "saturation",
                    f"{name}: {obj.saturated_fraction * 100:.0f} % of its pixels are clipped (black or "
                    "white); reduce the exposure so its texture can be tracked",
                )
            )
    return notes


__all__ = [
    "CLOSE_LINES",
    "SECOND_MOTION",
    "clip_notes",
    "close_pairs",
    "frame_notes",
    "frame_rate_notes",
    "object_quality_notes",
    "resolution_notes",
]
