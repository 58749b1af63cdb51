"""The result's quality notes (``workers.pipeline.quality``): each condition it checks gives its note, with
the figures that let a user act on it, and a clean case gives none."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from workers.pipeline.clipio.types import ClipInfo
from workers.pipeline.flow import FlowConfig
from workers.pipeline.model import ObjectMeasurement
from workers.pipeline.quality import (
    CLOSE_LINES,
    SECOND_MOTION,
    clip_notes,
    close_pairs,
    frame_notes,
    frame_rate_notes,
    object_quality_notes,
    resolution_notes,
)
from workers.pipeline.stream import FrameBuffers
from workers.pipeline.window import Plan


def _object(**changes) -> ObjectMeasurement:
    """A clean object: 5 Hz, 20 dB, 4 s of a lightly damped ring-down, nothing clipped."""
    base = {
        "id": 1,
        "eigenfrequency_hz": 5.0,
        "eigenfrequency_uncertainty_hz": 0.01,
        "natural_frequency_hz": 5.0,
        "damping_ratio": 0.02,
        "damping_ratio_uncertainty": 0.001,
        "amplitude_px": 2.0,
        "amplitude_m": None,
        "amplitude_uncertainty_m": None,
        "depth_m": None,
        "motion_direction": None,
        "stiffness_n_per_m": None,
        "stiffness_uncertainty_n_per_m": None,
        "mass_kg": None,
        "mass_uncertainty_kg": None,
        "pixel_count": 100,
        "bbox_px": (0, 0, 10, 10),
        "harmonics_hz": [],
        "release_time_s": 0.0,
        "snr_db": 20.0,
        "detection_db": 45.0,
        "fitted_duration_s": 4.0,
    }
    return ObjectMeasurement(**{**base, **changes})


def _info(**changes) -> ClipInfo:
    base = {
        "format": "video",
        "frames": 300,
        "width": 64,
        "height": 48,
        "fps": 30.0,
        "fps_source": "container",
        "has_depth": False,
        "depth_scale": None,
        "intrinsics": None,
    }
    return ClipInfo(**{**base, **changes})


def _buffers(count: int = 255, *, announced: int | None = None, rgb=None, change=None) -> FrameBuffers:
    rng = np.random.default_rng(0)
    if rgb is None:
        rgb = rng.integers(40, 220, (48, 64, 3), dtype=np.uint8)
    return FrameBuffers(
        flow=np.zeros((count, 12, 16, 2), np.float32),
        depth=None,
        gray=None,
        first_rgb=rgb,
        count=count,
        times_s=np.arange(count + 1) / 30.0,
        camera_px=np.zeros((count, 2), np.float32),
        start_s=0.0,
        frame_change=change,
        announced=count if announced is None else announced,
    )


def _plan(*, start: int = 0, step: int = 1, decodable: int = 300) -> Plan:
    return Plan(
        sample_rate_hz=30.0 / step,
        fps=30.0,
        start=start,
        stop=start + 256 * step,
        step=step,
        flow=FlowConfig(),
        grid=(12, 16),
        pixel_scale=4.0,
        decodable_frames=decodable,
    )


def _codes(notes) -> list[str]:
    return [n.code for n in notes]


# --- clip_notes ---------------------------------------------------------------------------------------


def test_a_clip_that_decodes_whole_has_no_clip_notes():
    assert clip_notes(_plan(), _buffers(), _info()) == []


def test_frames_that_did_not_decode_are_a_damaged_file_with_the_frames_named():
    notes = clip_notes(_plan(start=10, decodable=200), _buffers(189), _info(frames=300))
    assert _codes(notes) == ["damaged_file"]
    text = notes[0].message
    assert "lists 300 frames but only the first 200" in text
    assert "frames 200-299 are missing" in text
    assert "frames 10-199 were analysed" in text
    assert notes[0].severity == "warning"


def test_a_stream_that_ended_early_counts_as_damaged_where_it_ended():
    """The survey counted 300 decodable frames, but the window's stream stopped after 100 of its 256."""
    notes = clip_notes(_plan(start=20), _buffers(100, announced=255), _info(frames=300))
    assert _codes(notes) == ["damaged_file"]
    assert "only the first 121 could be decoded" in notes[0].message


def test_a_rate_from_capture_metadata_is_an_info_note():
    info = _info(fps=240.0, fps_source="metadata", container_fps=30.0)
    notes = clip_notes(_plan(), _buffers(), info)
    assert _codes(notes) == ["frame_rate"]
    assert notes[0].severity == "info"
    assert "240 fps" in notes[0].message
    assert "30 fps" in notes[0].message


# --- frame_notes --------------------------------------------------------------------------------------


@pytest.mark.parametrize(("level", "what"), [(0, "black"), (255, "white"), (128, "uniform")])
def test_blank_frames_are_an_error_that_names_what_they_are(level, what):
    rgb = np.full((48, 64, 3), level, np.uint8)
    notes = frame_notes(_buffers(rgb=rgb, change=np.zeros((255, 8, 8), np.float32)))
    assert _codes(notes) == ["blank_frames"]
    assert notes[0].severity == "error"
    assert f"the frames are {what}" in notes[0].message


def test_a_uniform_first_frame_that_later_changes_is_not_blank():
    rgb = np.full((48, 64, 3), 128, np.uint8)
    change = np.zeros((255, 8, 8), np.float32)
    change[100, 3, 3] = 6.0  # something comes into view
    assert frame_notes(_buffers(rgb=rgb, change=change)) == []


def test_a_thin_bar_on_a_flat_wall_is_something_to_track_not_a_blank_picture():
    """Issue 25: a bar 7 grey levels darker than a flat wall, 7 px of a 640 px picture, through H.264
    (the picture's grey level varies by 1.35 over the whole frame) was called uniform; sensor noise of the
    same size alone still is."""
    rng = np.random.default_rng(2)
    wall = 113 + rng.normal(0, 1.3, (480, 640))
    still = np.zeros((255, 8, 8), np.float32)
    noise_only = np.repeat(np.clip(wall, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    assert _codes(frame_notes(_buffers(rgb=noise_only, change=still))) == ["blank_frames"]
    wall[108:372, 349:356] -= 7.0
    assert float(wall.std()) < 2.0  # the whole picture alone would look uniform
    bar = np.repeat(np.clip(wall, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    assert frame_notes(_buffers(rgb=bar, change=still)) == []


def test_a_mostly_clipped_picture_is_saturated_and_a_textured_one_is_fine():
    rng = np.random.default_rng(1)
    grey = np.where(rng.random((48, 64)) < 0.5, 0, 255).astype(np.uint8)
    grey[:3] = rng.integers(60, 200, (3, 64))  # 6 % of the picture keeps some texture
    notes = frame_notes(_buffers(rgb=np.repeat(grey[..., None], 3, axis=2)))
    assert _codes(notes) == ["saturation"]
    assert "94 %" in notes[0].message
    assert frame_notes(_buffers()) == []


# --- close_pairs, resolution_notes --------------------------------------------------------------------


def test_objects_closer_than_three_lines_are_pairs():
    a, b, c = _object(id=1, eigenfrequency_hz=5.0), _object(id=2, eigenfrequency_hz=5.25), _object(id=3)
    c = dataclasses.replace(c, eigenfrequency_hz=8.0)
    assert [(x.id, y.id) for x, y in close_pairs([a, b, c], bin_hz=0.1)] == [(1, 2)]
    assert close_pairs([a, b, c], bin_hz=0.24 / CLOSE_LINES) == []
    # Lines of 1 Hz: 2.75 Hz apart is closer than three of them, 3 Hz apart is not.
    assert [(x.id, y.id) for x, y in close_pairs([a, b, c], bin_hz=1.0)] == [(1, 2), (2, 3)]


def test_unresolved_objects_and_second_motions_are_noted():
    objects = [
        _object(id=1, eigenfrequency_hz=5.0),
        _object(id=2, eigenfrequency_hz=5.2),
        _object(id=3, eigenfrequency_hz=9.0, second_motion=SECOND_MOTION + 0.05),
    ]
    notes = resolution_notes(objects, bin_hz=0.125, window_s=8.0)
    assert _codes(notes) == ["close_frequencies", "close_frequencies"]
    assert "objects 1 and 2" in notes[0].message
    assert "0.2 Hz apart" in notes[0].message
    assert "object 3" in notes[1].message
    assert "second motion" in notes[1].message
    assert (
        resolution_notes([objects[0], objects[2]], bin_hz=0.125, window_s=8.0)[0].message == notes[1].message
    )
    clean = [_object(id=1), _object(id=2, eigenfrequency_hz=9.0, second_motion=SECOND_MOTION - 0.05)]
    assert resolution_notes(clean, bin_hz=0.125, window_s=8.0) == []


# --- frame_rate_notes ---------------------------------------------------------------------------------


def test_a_container_rate_beside_a_named_capture_rate_is_doubted():
    info = _info(capture_fps_hint=1000.0, capture_fps_hint_source="the file name")
    notes = frame_rate_notes([_object()], info, window_s=8.0)
    assert _codes(notes) == ["frame_rate"]
    assert "the file name says 1000 fps" in notes[0].message
    assert "--fps 1000" in notes[0].message
    assert (
        frame_rate_notes([_object()], _info(capture_fps_hint=30.5, capture_fps_hint_source="x"), window_s=8)
        == []
    )


def test_slow_long_ringing_vibrations_at_a_playback_rate_are_doubted():
    """A 1.6 Hz ring-down over 20 s (32 periods) at damping 0.001, read at 30 fps from a container: a fork
    filmed fast and played back slower."""
    fork = _object(eigenfrequency_hz=1.6, damping_ratio=0.001)
    notes = frame_rate_notes([fork], _info(), window_s=20.0)
    assert _codes(notes) == ["frame_rate"]
    assert "32 periods" in notes[0].message
    # Not when the rate is the user's, the vibration damps, rings for few periods, or the rate is not a
    # playback rate.
    assert frame_rate_notes([fork], _info(fps_source="user"), window_s=20.0) == []
    assert frame_rate_notes([dataclasses.replace(fork, damping_ratio=0.02)], _info(), window_s=20.0) == []
    assert frame_rate_notes([fork], _info(), window_s=8.0) == []
    assert frame_rate_notes([fork], _info(fps=37.0), window_s=20.0) == []
    assert frame_rate_notes([], _info(), window_s=20.0) == []


# --- object_quality_notes -----------------------------------------------------------------------------


BAND = (0.5, 14.0)


def test_a_clean_object_has_no_notes():
    assert object_quality_notes([_object()], sample_rate_hz=30.0, band=BAND, bin_hz=0.12) == []


@pytest.mark.parametrize(
    ("changes", "code", "words"),
    [
        ({"eigenfrequency_hz": 12.5}, "possibly_aliased", "may be 17.5 Hz or higher"),
        ({"snr_db": 4.0, "detection_db": 28.0}, "low_snr", "push harder"),
        ({"snr_db": 4.0, "regime": "steady"}, "low_snr", "record longer"),
        ({"fitted_duration_s": 0.5}, "few_periods", "only 2.5 periods"),
        ({"eigenfrequency_hz": 0.6, "fitted_duration_s": 10.0}, "band_edge", "edge of the analysed band"),
        ({"saturated_fraction": 0.2}, "saturation", "20 % of its pixels"),
    ],
)
def test_each_unreliable_figure_gets_its_note(changes, code, words):
    notes = object_quality_notes([_object(**changes)], sample_rate_hz=30.0, band=BAND, bin_hz=0.12)
    assert _codes(notes) == [code]
    assert words in notes[0].message
    assert notes[0].message.startswith("object 1 (")
