"""Lighting (``workers.pipeline.light``), on small arrays with known answers: block brightness and change,
running noise floors, and which block rows flicker in phase at a frequency (lamps) rather than with the
signs of a moving texture (objects)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.light import (
    BRIGHTNESS_BLOCKS,
    FLICKER_ROWS,
    block_brightness,
    block_change,
    flickering_rows,
    floor_of,
)

FPS = 30.0
#: 257 frames: 256 changes, bins of 30/256 Hz; 7.5 Hz is bin 64.
FRAMES = 257
F_HZ = 7.5
B = BRIGHTNESS_BLOCKS


def _spectra(brightness: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The spectra of each block's frame-to-frame brightness change (as the survey and the window's
    evidence take them), and their frequencies."""
    change = np.diff(brightness.astype(np.float64), axis=0)
    freqs = np.fft.rfftfreq(len(change), d=1.0 / FPS)
    return np.fft.rfft(change - change.mean(axis=0), axis=0), freqs


def _brightness(amplitude: np.ndarray, phase: np.ndarray, *, noise: float = 0.3, seed: int = 0) -> np.ndarray:
    """(T, B, B) block brightness: 120 plus a 7.5 Hz oscillation of each block's amplitude and phase, plus
    noise."""
    t = np.arange(FRAMES) / FPS
    wave = np.sin(2 * math.pi * F_HZ * t[:, None, None] + phase[None])
    rng = np.random.default_rng(seed)
    return 120.0 + amplitude[None] * wave + rng.normal(0, noise, (FRAMES, B, B))


def _ones() -> np.ndarray:
    return np.ones((B, B))


def test_lamps_flickering_together_flicker_in_every_row():
    fraction, k = flickering_rows(*_spectra(_brightness(3 * _ones(), 0 * _ones())), F_HZ, 0.2)
    assert fraction == 1.0
    assert np.fft.rfftfreq(FRAMES - 1, d=1 / FPS)[k] == pytest.approx(F_HZ)


def test_a_rolling_shutter_shifts_the_phase_from_row_to_row_and_still_flickers():
    rows = np.arange(B)[:, None] * 0.7 * _ones()  # in phase along a row, later row by row
    fraction, _ = flickering_rows(*_spectra(_brightness(3 * _ones(), rows)), F_HZ, 0.2)
    assert fraction == 1.0


def test_a_moving_texture_brightens_some_blocks_and_darkens_others_and_does_not_flicker():
    """The same oscillation, but three of the eight blocks of every row in anti-phase (a texture's signs):
    each row's in-phase mean keeps a quarter of the amplitude, well above the noise, but a sixteenth of
    the blocks' power: not coherent along the row."""
    signs = np.ones((B, B))
    for i in range(B):
        signs[i, np.random.default_rng(i).permutation(B)[:3]] = -1
    phase = np.where(signs > 0, 0.0, math.pi)
    fraction, _ = flickering_rows(*_spectra(_brightness(3 * _ones(), phase)), F_HZ, 0.2)
    assert fraction == 0.0


def test_the_fraction_counts_the_rows_that_flicker():
    amplitude = np.zeros((B, B))
    amplitude[:3] = 3.0  # the top three block rows lit by a flickering lamp
    fraction, _ = flickering_rows(*_spectra(_brightness(amplitude, 0 * _ones())), F_HZ, 0.2)
    assert fraction == pytest.approx(3 / B)
    assert fraction < FLICKER_ROWS


def test_noise_and_other_frequencies_do_not_flicker():
    spectra, freqs = _spectra(_brightness(0 * _ones(), 0 * _ones()))
    assert flickering_rows(spectra, freqs, F_HZ, 0.2)[0] == 0.0
    spectra, freqs = _spectra(_brightness(3 * _ones(), 0 * _ones()))
    assert flickering_rows(spectra, freqs, 3.0, 0.2)[0] == 0.0  # it flickers at 7.5 Hz, not at 3


def test_a_frequency_no_bin_is_near_gives_no_bin():
    spectra, freqs = _spectra(_brightness(3 * _ones(), 0 * _ones()))
    assert flickering_rows(spectra, freqs, 40.0, 0.2) == (0.0, -1)


def test_the_floor_is_a_running_median_blind_to_isolated_peaks():
    rng = np.random.default_rng(3)
    power = rng.uniform(0.9, 1.1, (200, 2, 3))
    power[[20, 90, 150]] = 1000.0  # peaks
    floor = floor_of(power)
    assert floor.shape == power.shape
    assert np.all((floor > 0.9) & (floor < 1.1))
    ramp = np.linspace(1.0, 3.0, 300)[:, None]  # a slope is followed (away from the ends)
    np.testing.assert_allclose(floor_of(ramp)[40:-40], ramp[40:-40], rtol=1e-9)
    assert np.all(floor_of(np.zeros((50, 4))) == 1e-30)


def test_block_brightness_is_the_mean_of_each_block():
    """A 64 x 80 frame: blocks of 8 x 10 pixels, each of its own level, textured around it (a
    checkerboard of +-5 that averages out)."""
    levels = (np.arange(B)[:, None] * 20 + np.arange(B)[None] * 3 + 40).astype(np.int32)
    frame = np.kron(levels, np.ones((8, 10), np.int32))
    checker = (np.indices(frame.shape).sum(axis=0) % 2) * 10 - 5
    gray = (frame + checker).astype(np.uint8)
    out = block_brightness(gray)
    assert out.shape == (B, B)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, levels, atol=0.5)


def test_block_change_is_the_mean_absolute_change_of_each_block():
    rng = np.random.default_rng(4)
    previous = rng.integers(50, 200, (64, 80)).astype(np.uint8)
    gray = previous.copy()
    gray[16:24, 50:60] += 20  # block (2, 5) brightens
    gray[56:64, 0:10] -= 15  # block (7, 0) darkens
    gray[0:4, 0:10] += 8  # half of block (0, 0)
    expected = np.zeros((B, B))
    expected[2, 5], expected[7, 0], expected[0, 0] = 20, 15, 4
    out = block_change(previous, gray)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, expected, atol=0.5)
    np.testing.assert_array_equal(block_change(previous, previous), 0)
