"""Modes of one object on arrays with ground truth: a struck Euler-Bernoulli cantilever's first three
bending modes (frequencies, damping, shapes against the analytic ones), harmonics told from modes by
their shapes, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.errors import ParameterError
from workers.pipeline.modes import GridDepth, align_phase, find_modes, mac

#: β_r L of a cantilever's first three bending modes.
BETA_L = (1.8751, 4.6941, 7.8548)


def cantilever_shape(beta_l: float, xi: np.ndarray) -> np.ndarray:
    """The bending mode shape of a clamped-free beam at ξ = x / L."""
    b = beta_l * xi
    sigma = (math.cosh(beta_l) + math.cos(beta_l)) / (math.sinh(beta_l) + math.sin(beta_l))
    return np.cosh(b) - np.cos(b) - sigma * (np.sinh(b) - np.sin(b))


def cantilever_motion(
    *,
    f1_hz: float = 3.0,
    zetas: tuple[float, ...] = (0.01, 0.006, 0.004),
    amplitudes_px: tuple[float, ...] = (1.0, 0.3, 0.12),
    fs: float = 240.0,
    samples: int = 1024,
    pixels: int = 60,
    noise_px: float = 0.01,
    seed: int = 0,
) -> tuple[np.ndarray, list[float], list[np.ndarray]]:
    """Flow (samples, pixels, 2) of a struck cantilever lying along x and bending in y: each mode a
    damped oscillation of its shape; the flow is each sample's displacement difference."""
    rng = np.random.default_rng(seed)
    xi = np.linspace(0.02, 1.0, pixels)
    t = np.arange(samples + 1) / fs
    disp = np.zeros((samples + 1, pixels))
    freqs, shapes = [], []
    for r, (beta_l, zeta, amp) in enumerate(zip(BETA_L, zetas, amplitudes_px, strict=True)):
        fn = f1_hz * (beta_l / BETA_L[0]) ** 2
        wn = 2 * math.pi * fn
        wd = wn * math.sqrt(1 - zeta**2)
        phi = cantilever_shape(beta_l, xi)
        phi = phi / np.abs(phi).max()
        disp += amp * np.outer(np.exp(-zeta * wn * t) * np.sin(wd * t + 0.3 * r), phi)
        freqs.append(wd / (2 * math.pi))
        shapes.append(phi)
    flow = np.zeros((samples, pixels, 2))
    flow[..., 1] = np.diff(disp, axis=0)
    flow += rng.normal(0.0, noise_px, flow.shape)
    return flow.astype(np.float32), freqs, shapes


def test_a_struck_cantilever_gives_its_three_bending_modes_with_their_shapes() -> None:
    zetas = (0.01, 0.006, 0.004)
    flow, freqs, shapes = cantilever_motion(zetas=zetas)
    found = find_modes(flow, sample_rate_hz=240.0, band_hz=(1.0, 117.0))
    assert len(found.modes) == 3, [m.frequency_hz for m in found.modes]
    assert not found.harmonics
    by_f = sorted(found.modes, key=lambda m: m.frequency_hz)
    for mode, f, zeta, shape in zip(by_f, freqs, zetas, shapes, strict=True):
        assert mode.frequency_hz == pytest.approx(f, rel=0.005)
        assert abs(mode.frequency_hz - f) <= 3 * mode.frequency_uncertainty_hz
        assert mode.regime == "ring_down"
        assert mode.damping_ratio == pytest.approx(zeta, rel=0.3)
        assert mac(mode.shape[:, 1], shape) >= 0.98
        assert mode.complexity < 0.05  # light damping: a real (standing) mode
    # The shapes differ from each other (nodes), and the first mode carries most of the motion.
    off = found.mac[~np.eye(3, dtype=bool)]
    assert off.max() < 0.5
    assert found.modes[0].frequency_hz == pytest.approx(freqs[0], rel=0.005)
    assert found.modes[0].energy_share > found.modes[1].energy_share > found.modes[2].energy_share


def test_a_second_mode_gets_its_node_and_sign_change() -> None:
    flow, _, _ = cantilever_motion()
    found = find_modes(flow, sample_rate_hz=240.0, band_hz=(1.0, 117.0))
    second = min((m for m in found.modes if m.frequency_hz > 10), key=lambda m: m.frequency_hz)
    y = second.shape[:, 1].real
    # One sign change along the beam (the second bending mode's node, near x = 0.78 L).
    changes = np.flatnonzero(np.diff(np.sign(y[np.abs(y) > 0.05 * np.abs(y).max()])))
    assert len(changes) == 1


def test_a_rigid_object_moving_periodically_but_not_sinusoidally_has_one_mode_and_its_harmonic() -> None:
    rng = np.random.default_rng(1)
    fs, n, f0 = 240.0, 960, 7.0
    t = np.arange(n) / fs
    course = np.cos(2 * np.pi * f0 * t) + 0.35 * np.cos(2 * np.pi * 2 * f0 * t + 0.4)
    direction = np.array([0.8, 0.6])
    flow = course[:, None, None] * direction[None, None, :] * np.ones((1, 40, 1))
    flow = flow + rng.normal(0, 0.01, flow.shape)
    found = find_modes(flow, sample_rate_hz=fs, band_hz=(1.0, 100.0))
    assert len(found.modes) == 1
    assert found.modes[0].frequency_hz == pytest.approx(f0, rel=0.002)
    assert found.modes[0].regime == "steady"  # a sustained motion: no damping to measure
    assert found.modes[0].damping_ratio is None
    assert len(found.harmonics) == 1
    harmonic = found.harmonics[0]
    assert harmonic.order == 2
    assert harmonic.frequency_hz == pytest.approx(2 * f0, rel=0.002)
    assert harmonic.mac > 0.99


def test_a_mode_at_twice_another_with_a_different_shape_is_a_mode_not_a_harmonic() -> None:
    rng = np.random.default_rng(2)
    fs, n, f0, pixels = 240.0, 960, 6.0, 50
    t = np.arange(n)[:, None] / fs
    x = np.linspace(0, 1, pixels)[None, :]
    # The first shape is even about the middle, the second odd (a node there): orthogonal.
    first = np.cos(2 * np.pi * f0 * t) * np.cos(np.pi * (x - 0.5))
    second = 0.5 * np.cos(2 * np.pi * 2 * f0 * t + 1.0) * np.sin(2 * np.pi * (x - 0.5))
    flow = np.zeros((n, pixels, 2))
    flow[..., 0] = first + second + rng.normal(0, 0.01, (n, pixels))
    found = find_modes(flow, sample_rate_hz=fs, band_hz=(1.0, 100.0))
    assert sorted(round(m.frequency_hz, 1) for m in found.modes) == [6.0, 12.0]
    assert not found.harmonics
    assert found.mac[0, 1] < 0.1


def test_noise_alone_has_no_mode() -> None:
    rng = np.random.default_rng(3)
    flow = rng.normal(0, 0.05, (512, 30, 2))
    found = find_modes(flow, sample_rate_hz=100.0, band_hz=(1.0, 45.0))
    assert found.modes == []


def test_mac_and_phase_alignment() -> None:
    a = np.array([1.0, -2.0, 0.5])
    assert mac(a, 3j * a) == pytest.approx(1.0)
    assert mac(a, np.array([2.0, 1.0, 0.0])) == pytest.approx(0.0)
    assert mac(a, np.zeros(3)) == 0.0
    aligned = align_phase(a * np.exp(1.1j))
    np.testing.assert_allclose(aligned, -a, atol=1e-12)  # its largest component made positive
    with pytest.raises(ParameterError, match="cannot be compared"):
        mac(a, np.ones(4))


@pytest.mark.parametrize(
    ("shape", "rate", "message"),
    [
        ((100, 10), 100.0, "samples, pixels, 2"),
        ((8, 10, 2), 100.0, "too few"),
        ((100, 10, 2), 0.0, "positive"),
    ],
)
def test_bad_input_says_what_to_give(shape: tuple[int, ...], rate: float, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        find_modes(np.zeros(shape, np.float32), sample_rate_hz=rate, band_hz=(1.0, 40.0))


def test_shapes_over_a_whole_mask_from_modes_sought_on_some_of_its_pixels(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The beam lies along a row of a (h, w) grid; the modes are sought on a subsample of its pixels and
    their shapes then taken on every pixel: each matches the analytic shape, NaN off the beam."""
    import workers.pipeline.modes as modes_module

    monkeypatch.setattr(modes_module, "MAX_MODE_PIXELS", 20)
    motion, freqs, shapes = cantilever_motion(pixels=60)
    grid = np.zeros((len(motion), 5, 64, 2), np.float16)
    grid[:, 2, 2:62, :] = motion
    mask = np.zeros((5, 64), bool)
    mask[2, 2:62] = True
    result = modes_module.object_modes(grid, mask, sample_rate_hz=240.0, band_hz=(1.0, 117.0))
    assert len(result.found.modes) == 3
    images = result.images((5, 64))
    assert images.shape == (3, 5, 64, 2)
    assert np.isnan(images[:, 0]).all()
    for m, mode in enumerate(result.found.modes):
        truth = shapes[int(np.argmin([abs(f - mode.frequency_hz) for f in freqs]))]
        assert mac(images[m, 2, 2:62, 1], truth) >= 0.98


def test_frame_shapes_are_displacements_in_input_pixels_placed_in_the_box() -> None:
    """A block of a box's grid (2 input px per grid px) moves 0.5 grid px (x) at 3 Hz: its shape over the
    frame is 1.0 input px on the block's frame pixels, NaN elsewhere."""
    from workers.pipeline.modes import object_modes
    from workers.pipeline.roi import Roi

    fs, n = 60.0, 600
    roi = Roi(x=20, y=10, width=32, height=20, grid_shape=(10, 16), frame_shape=(40, 60))
    displacement = 0.5 * np.sin(2 * np.pi * 3.0 * np.arange(n + 1) / fs)
    flow = np.random.default_rng(4).normal(0, 0.002, (n, 10, 16, 2)).astype(np.float32)
    flow[:, 3:7, 5:11, 0] += np.diff(displacement)[:, None, None]
    mask = np.zeros((10, 16), bool)
    mask[3:7, 5:11] = True
    result = object_modes(flow, mask, sample_rate_hz=fs, band_hz=(0.5, 28.0), roi=roi)
    assert [round(m.frequency_hz, 2) for m in result.found.modes] == [3.0]
    full_mask = np.zeros((40, 60), bool)
    full_mask[10 + 6 : 10 + 14, 20 + 10 : 20 + 22] = True  # the block's grid pixels, at 2 px each
    shapes = result.frame_shapes(full_mask)
    assert shapes.shape == (1, 40, 60, 2)
    inside = shapes[0][full_mask]
    np.testing.assert_allclose(np.abs(inside[:, 0]), 1.0, rtol=0.03)
    assert np.all(np.abs(inside[:, 1]) < 0.05)
    assert np.isnan(shapes[0][~full_mask]).all()


def test_shapes_in_metres_across_and_along_the_line_of_sight() -> None:
    """A block 1.5 m away moves 0.5 grid px (1 input px) across the line of sight and 3 mm along it, in
    phase, at 3 Hz; one column of its pixels sees the background (2 m) half the time. Across: 1 input px
    times depth over focal length; along: 3 mm from the depth series, same sign; NaN where the depth
    jumps between object and background, and off the object."""
    from workers.pipeline.modes import object_modes
    from workers.pipeline.roi import Roi

    fs, n, focal = 60.0, 600, 500.0
    roi = Roi(x=20, y=10, width=32, height=20, grid_shape=(10, 16), frame_shape=(40, 60))
    phase = np.sin(2 * np.pi * 3.0 * np.arange(n + 1) / fs)
    rng = np.random.default_rng(5)
    flow = rng.normal(0, 0.002, (n, 10, 16, 2)).astype(np.float32)
    flow[:, 3:7, 5:11, 0] += np.diff(0.5 * phase)[:, None, None]
    depth = np.full((n + 1, 10, 16), 2.0, np.float32)
    depth[:, 3:7, 5:11] = (1.5 + 0.003 * phase)[:, None, None]
    depth[phase > 0, 3:7, 10] = 2.0  # the block's edge column: the background shows through half the time
    depth += rng.normal(0, 0.0005, depth.shape).astype(np.float32)
    mask = np.zeros((10, 16), bool)
    mask[3:7, 5:11] = True
    result = object_modes(
        flow, mask, sample_rate_hz=fs, band_hz=(0.5, 28.0), roi=roi, depth=GridDepth(depth, (focal, focal))
    )
    full_mask = np.zeros((40, 60), bool)
    full_mask[16:24, 30:42] = True
    metres = result.frame_shapes_m(full_mask)
    assert metres is not None
    assert metres.shape == (1, 40, 60, 3)
    assert metres.dtype == np.float32
    inside = metres[0][full_mask]
    interior = metres[0][16:24, 30:40]
    np.testing.assert_allclose(np.abs(inside[:, 0]), 1.0 * 1.5 / focal, rtol=0.04)
    np.testing.assert_allclose(interior[..., 2], 0.003 * np.sign(interior[..., 0]), rtol=0.05)
    assert np.isnan(metres[0][16:24, 40:42, 2]).all()  # the edge column: no line-of-sight reading
    assert np.isnan(metres[0][~full_mask]).all()
    # One distance for the whole clip: across only, nothing along the line of sight.
    fixed = object_modes(
        flow, mask, sample_rate_hz=fs, band_hz=(0.5, 28.0), roi=roi, depth=GridDepth(1.5, (focal, focal))
    ).frame_shapes_m(full_mask)
    assert fixed is not None
    np.testing.assert_allclose(np.abs(fixed[0][full_mask][:, 0]), 1.5 / focal, rtol=0.04)
    assert np.isnan(fixed[0][..., 2]).all()
    # No intrinsics: no shapes in metres.
    plain = object_modes(flow, mask, sample_rate_hz=fs, band_hz=(0.5, 28.0), roi=roi)
    assert plain.frame_shapes_m(full_mask) is None


def test_a_travelling_wave_is_a_complex_mode_with_its_quadrature_part() -> None:
    """A wave running along a strip (one wavelength over it, 0.4 grid px at 4 Hz): a complex mode, whose
    real and imaginary shapes together have the same magnitude everywhere, 0.8 input px at 2 px a grid
    pixel, with the phase turning once along the strip."""
    from workers.pipeline.modes import object_modes
    from workers.pipeline.roi import Roi

    fs, n, f = 60.0, 600, 4.0
    roi = Roi(x=0, y=0, width=80, height=12, grid_shape=(6, 40), frame_shape=(12, 80))
    t = np.arange(n + 1)[:, None] / fs
    x = np.arange(40)[None, :] / 40
    displacement = 0.4 * np.cos(2 * np.pi * (f * t - x))
    flow = np.random.default_rng(6).normal(0, 0.002, (n, 6, 40, 2)).astype(np.float32)
    flow[:, 3, :, 1] += np.diff(displacement, axis=0)
    mask = np.zeros((6, 40), bool)
    mask[3] = True
    result = object_modes(flow, mask, sample_rate_hz=fs, band_hz=(0.5, 28.0), roi=roi)
    assert len(result.found.modes) == 1
    assert result.found.modes[0].complexity > 0.3
    full_mask = np.zeros((12, 80), bool)
    full_mask[6:8] = True
    real = result.frame_shapes(full_mask)[0][full_mask][:, 1]
    imag = result.frame_shapes(full_mask, imaginary=True)[0][full_mask][:, 1]
    np.testing.assert_allclose(np.hypot(real, imag), 0.8, rtol=0.05)
    phase = np.unwrap(np.angle((real + 1j * imag)[::2][:40]))
    assert abs(abs(phase[-1] - phase[0]) - 2 * np.pi * 39 / 40) < 0.3
