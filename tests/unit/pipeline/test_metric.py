"""An object's amplitude in metres (``workers.pipeline.metric``), on small arrays with known answers: the
pinhole scaling (pixels x depth / focal length), the depth track that follows the object, the component of
a second signal that rings with a fit, the object's distance, and the uncertainties."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.clipio.types import Intrinsics
from workers.pipeline.metric import (
    DEPTH_OVERRIDE_REL_SD,
    FLOW_AMPLITUDE_REL_SD,
    REGISTRATION_REL_SD,
    DepthContext,
    ImageAmplitude,
    depth_track,
    fit_component,
    metric_amplitude,
    object_depth,
)
from workers.pipeline.ringdown import RingdownFit

FPS = 30.0


def _fit(**changes) -> RingdownFit:
    """A ring-down at 5 Hz, decaying at 0.4/s, of 4 px at the fit start."""
    base = {
        "frequency_hz": 5.0,
        "natural_frequency_hz": 5.0,
        "damping_ratio": 0.4 / (2 * math.pi * 5.0),
        "amplitude": 4.0,
        "phase_rad": 0.3,
        "decay_per_s": 0.4,
        "start_index": 0,
        "frequency_sd_hz": 0.001,
        "damping_sd": 1e-4,
        "amplitude_sd": 0.01,
        "residual_rms": 0.01,
        "snr_db": 30.0,
        "samples": 120,
    }
    return RingdownFit(**{**base, **changes})


def _image(fit: RingdownFit | None = None, **changes) -> ImageAmplitude:
    fit = fit or _fit()
    base = {
        "fit": fit,
        "amplitude_px": fit.amplitude,
        "amplitude_sd_px": 0.04,
        "axis_px": (1.0, 0.0),
        "source": "flow",
    }
    return ImageAmplitude(**{**base, **changes})


def _mask(shape=(48, 64), box=(20, 28, 26, 38)) -> np.ndarray:
    """A rectangle (rows y0:y1, columns x0:x1) centred on (x, y) = (31.5, 23.5)."""
    y0, y1, x0, x1 = box
    mask = np.zeros(shape, bool)
    mask[y0:y1, x0:x1] = True
    return mask


def _constant_distance(metres: float | None, region: np.ndarray, frames: int = 121) -> DepthContext:
    return DepthContext(
        depth=None,
        region=region,
        shifts_grid_px=None,
        times_from_onset_s=np.arange(frames) / FPS,
        onset=0,
        override_m=metres,
    )


# --- metric_amplitude --------------------------------------------------------------------------------


@pytest.mark.parametrize(("depth_m", "focal"), [(1.5, 500.0), (0.4, 620.0), (3.0, 300.0)])
def test_a_pixel_amplitude_at_a_known_depth_is_pixels_times_depth_over_focal(depth_m, focal):
    mask = _mask()
    intrinsics = Intrinsics(focal, focal, 31.5, 23.5)
    out = metric_amplitude(_image(), _constant_distance(depth_m, mask), full_mask=mask, intrinsics=intrinsics)
    assert out.null_reasons == []
    assert out.amplitude_m == pytest.approx(4.0 * depth_m / focal, rel=1e-9)
    assert out.depth_m == depth_m
    assert out.direction == pytest.approx((1.0, 0.0, 0.0))
    assert out.notes == []


def test_the_amplitude_at_release_is_scaled_not_the_fits():
    """The fit gives the axis and the scale; the amplitude at release (here 3 px of a 4 px fit) is what
    is converted."""
    mask = _mask()
    out = metric_amplitude(
        _image(amplitude_px=3.0),
        _constant_distance(2.0, mask),
        full_mask=mask,
        intrinsics=Intrinsics(400.0, 400.0, 31.5, 23.5),
    )
    assert out.amplitude_m == pytest.approx(3.0 * 2.0 / 400.0, rel=1e-9)


def test_each_image_axis_uses_its_own_focal_length():
    """Motion along (0.6, 0.8) with fx = 500 and fy = 400: dX = 0.6 A Z / fx, dY = 0.8 A Z / fy."""
    mask = _mask()
    out = metric_amplitude(
        _image(axis_px=(0.6, 0.8)),
        _constant_distance(1.0, mask),
        full_mask=mask,
        intrinsics=Intrinsics(500.0, 400.0, 31.5, 23.5),
    )
    dx, dy = 0.6 * 4.0 / 500.0, 0.8 * 4.0 / 400.0
    assert out.amplitude_m == pytest.approx(math.hypot(dx, dy), rel=1e-9)
    assert out.direction == pytest.approx((dx / math.hypot(dx, dy), dy / math.hypot(dx, dy), 0.0))


def test_the_direction_has_its_largest_component_positive():
    mask = _mask()
    out = metric_amplitude(
        _image(axis_px=(-0.8, 0.6)),
        _constant_distance(1.0, mask),
        full_mask=mask,
        intrinsics=Intrinsics(500.0, 500.0, 31.5, 23.5),
    )
    assert out.direction == pytest.approx((0.8, -0.6, 0.0))


@pytest.mark.parametrize(
    ("source", "systematic"), [("flow", FLOW_AMPLITUDE_REL_SD), ("registration", REGISTRATION_REL_SD)]
)
def test_the_uncertainty_adds_the_image_the_source_and_the_distance(source, systematic):
    """In-plane motion at a given distance: relative uncertainty = sqrt(image² + source² + distance²)."""
    mask = _mask()
    out = metric_amplitude(
        _image(source=source, amplitude_sd_px=0.04),
        _constant_distance(1.5, mask),
        full_mask=mask,
        intrinsics=Intrinsics(500.0, 500.0, 31.5, 23.5),
    )
    expected = math.sqrt((0.04 / 4.0) ** 2 + systematic**2 + DEPTH_OVERRIDE_REL_SD**2)
    assert out.amplitude_uncertainty_m / out.amplitude_m == pytest.approx(expected, rel=1e-9)


def test_without_depth_or_intrinsics_or_motion_the_amplitude_is_null_with_a_reason():
    mask = _mask()
    camera = Intrinsics(500.0, 500.0, 31.5, 23.5)
    no_depth = metric_amplitude(_image(), _constant_distance(None, mask), full_mask=mask, intrinsics=camera)
    assert no_depth.amplitude_m is None
    assert no_depth.depth_m is None
    assert any("no depth" in r for r in no_depth.null_reasons)
    no_camera = metric_amplitude(_image(), _constant_distance(1.0, mask), full_mask=mask, intrinsics=None)
    assert no_camera.amplitude_m is None
    assert no_camera.depth_m == 1.0
    assert any("intrinsics" in r for r in no_camera.null_reasons)
    still = metric_amplitude(
        _image(_fit(amplitude=0.0), amplitude_px=0.0),
        _constant_distance(1.0, mask),
        full_mask=mask,
        intrinsics=camera,
    )
    assert still.amplitude_m is None
    assert any("zero" in r for r in still.null_reasons)


def _ringing_depth(fit: RingdownFit, *, frames: int, shape, mask, mean_m: float, z_amp_m: float):
    """Depth maps (T, h, w): ``mean_m`` plus a motion along the line of sight of ``z_amp_m`` in phase with
    ``fit`` inside the mask, 5 m of background outside."""
    t = np.arange(frames) / FPS
    z = mean_m + z_amp_m * np.exp(-fit.decay_per_s * t) * np.cos(
        2 * math.pi * fit.frequency_hz * t + fit.phase_rad
    )
    depth = np.full((frames, *shape), 5.0, np.float32)
    depth[:, mask] = z[:, None].astype(np.float32)
    return depth, t


def test_depth_maps_give_the_distance_and_the_motion_along_the_line_of_sight():
    """The depth track rings with the fit (2 mm at 0.9 m): the amplitude is the 3-D one and the direction
    has its line-of-sight share; a depth map that does not ring gives the in-plane amplitude only."""
    fit = _fit()
    mask = _mask()
    focal = 500.0
    camera = Intrinsics(focal, focal, 31.5, 23.5)  # the mask's centroid: no perspective coupling
    in_plane = 4.0 * 0.9 / focal
    for z_amp in (0.002, 0.0):
        depth, t = _ringing_depth(fit, frames=121, shape=mask.shape, mask=mask, mean_m=0.9, z_amp_m=z_amp)
        context = DepthContext(depth=depth, region=mask, shifts_grid_px=None, times_from_onset_s=t, onset=0)
        out = metric_amplitude(_image(fit), context, full_mask=mask, intrinsics=camera)
        assert out.depth_m == pytest.approx(0.9, abs=5e-4)
        assert out.amplitude_m == pytest.approx(math.hypot(in_plane, z_amp), rel=2e-3)
        assert out.direction[2] == pytest.approx(z_amp / math.hypot(in_plane, z_amp), abs=2e-3)
        assert bool(out.notes) == (z_amp > 0), out.notes


# --- depth_track, object_depth ----------------------------------------------------------------------


def test_the_depth_track_is_the_median_over_the_regions_core_per_frame():
    frames, shape = 6, (30, 40)
    region = _mask(shape, (10, 20, 12, 26))
    depth = np.full((frames, *shape), 3.0, np.float32)
    for k in range(frames):
        depth[k, region] = 0.8 + 0.01 * k
    depth[2, 12:17, 14:24] = np.nan  # most of the core unread: the rest still gives the value
    depth[4, region] = np.nan  # no reading at all: NaN
    track = depth_track(depth, region)
    expected = 0.8 + 0.01 * np.arange(frames)
    expected[4] = np.nan
    np.testing.assert_allclose(track, expected, rtol=1e-6)


def test_the_depth_track_follows_the_object_with_its_shifts():
    """The object (0.7 m before 2 m of background) moves 6 px right and 4 up in the last frames: followed
    with its shifts, the track stays on it; without them it reads the background."""
    frames, shape = 4, (40, 50)
    region = _mask(shape, (12, 22, 15, 25))
    shifts = np.array([[0, 0], [0, 0], [6, -4], [6, -4]], np.float64)
    depth = np.full((frames, *shape), 2.0, np.float32)
    for k, (dx, dy) in enumerate(shifts.astype(int)):
        depth[k, 12 + dy : 22 + dy, 15 + dx : 25 + dx] = 0.7
    np.testing.assert_allclose(depth_track(depth, region, shifts_px=shifts), 0.7, rtol=1e-6)
    unfollowed = depth_track(depth, region)
    assert unfollowed[0] == pytest.approx(0.7)
    assert unfollowed[2] == pytest.approx(2.0)


@pytest.mark.parametrize("shifted", [False, True], ids=["still", "followed"])
def test_the_depth_track_is_each_frames_median_of_its_finite_readings_exactly(shifted: bool, monkeypatch):
    """Against the plain per-frame definition (np.median of the finite readings under the eroded core,
    moved by the frame's shift), bit for bit: frames with unread pixels, an infinite reading, a frame
    without any, shifts reaching past the grid's edge, and more frames than one block of the track."""
    import cv2

    import workers.pipeline.metric as metric

    rng = np.random.default_rng(7)
    frames, shape = 40, (36, 48)
    depth = (0.5 + 2 * rng.random((frames, *shape))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    depth[3] = np.nan
    depth[5, 12, 20] = np.inf
    region = _mask(shape, (8, 26, 10, 30))
    shifts = rng.normal(0.0, 9.0, (frames, 2)) if shifted else None
    core = cv2.erode(region.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    ys, xs = np.nonzero(core)
    expected = np.full(frames, np.nan)
    for k in range(frames):
        dx, dy = np.rint(shifts[k]).astype(int) if shifts is not None else (0, 0)
        ok = (ys + dy >= 0) & (ys + dy < shape[0]) & (xs + dx >= 0) & (xs + dx < shape[1])
        values = depth[k, ys[ok] + dy, xs[ok] + dx]
        values = values[np.isfinite(values)]
        if values.size:
            expected[k] = float(np.median(values))
    monkeypatch.setattr(metric, "TRACK_BLOCK_VALUES", 7 * ys.size)  # blocks of 7 frames
    track = depth_track(depth, region, shifts_px=shifts)
    assert np.array_equal(track, expected, equal_nan=True), track - expected
    assert np.isnan(track[3])


def test_the_objects_depth_ignores_its_mask_edge():
    """A 12 x 12 mask whose 2-pixel rim (80 of its 144 pixels) sees the background at 3 m: the median of the
    mask would be 3 m; its interior gives the object's 1.2 m."""
    shape = (30, 30)
    mask = _mask(shape, (9, 21, 9, 21))
    depth = np.full((5, *shape), 3.0, np.float32)
    depth[:, 11:19, 11:19] = 1.2
    assert object_depth(depth, mask) == pytest.approx(1.2)
    assert float(np.median(depth[:, mask])) == pytest.approx(3.0)  # what the rim would have given


def test_the_objects_depth_without_readings_is_none_and_a_small_mask_is_used_whole():
    shape = (20, 20)
    assert object_depth(None, _mask(shape, (5, 15, 5, 15))) is None
    assert object_depth(np.full((3, *shape), np.nan, np.float32), _mask(shape, (5, 15, 5, 15))) is None
    small = _mask(shape, (8, 11, 8, 11))  # 3 x 3: nothing is left after erosion
    depth = np.full((3, *shape), 2.5, np.float32)
    depth[:, small] = 0.5
    assert object_depth(depth, small) == pytest.approx(0.5)


# --- fit_component ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("phase_offset", "sign"), [(0.0, 1.0), (math.pi, -1.0), (0.4, 1.0), (2.5, -1.0)])
def test_a_second_signal_ringing_with_the_fit_gives_its_signed_amplitude_and_phase(phase_offset, sign):
    fit = _fit()
    t = np.arange(150) / FPS
    amplitude = 0.003
    x = 0.9 + amplitude * np.exp(-fit.decay_per_s * t) * np.cos(
        2 * math.pi * fit.frequency_hz * t + fit.phase_rad + phase_offset
    )
    x += np.random.default_rng(1).normal(0, 1e-5, len(t))
    x[[7, 40, 41]] = np.nan  # missing readings are skipped
    a, sd, offset = fit_component(x, t, fit, start_index=0)
    assert a == pytest.approx(sign * amplitude, abs=4 * sd)
    assert 0 < sd < 1e-4
    assert abs((offset - phase_offset + math.pi) % (2 * math.pi) - math.pi) < 0.02, offset


def test_a_signal_that_does_not_ring_with_the_fit_has_no_component():
    fit = _fit()
    t = np.arange(150) / FPS
    noise = np.random.default_rng(2).normal(0, 1e-3, len(t))
    a, sd, _ = fit_component(1.0 + noise, t, fit, start_index=0)
    assert abs(a) < 3 * sd


def test_the_component_starts_at_the_release_and_needs_five_samples():
    fit = _fit()
    t = np.arange(60) / FPS
    x = np.where(t < 1.0, 7.0, 0.0)  # whatever happened before the release does not count
    ring = (
        0.002 * np.exp(-fit.decay_per_s * (t - 1.0)) * np.cos(2 * math.pi * 5.0 * (t - 1.0) + fit.phase_rad)
    )
    x = x + np.where(t >= 1.0, ring, 0.0)
    a, _, _ = fit_component(x, t - 1.0, fit, start_index=30)
    assert a == pytest.approx(0.002, rel=1e-6)
    assert fit_component(x, t, fit, start_index=56) == (0.0, float("inf"), 0.0)
    assert fit_component(np.full(60, np.nan), t, fit, start_index=0) == (0.0, float("inf"), 0.0)
