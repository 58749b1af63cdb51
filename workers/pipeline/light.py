"""Lighting: how to tell a picture whose light flickers from one in which something moves.

Lighting that flickers (mains-powered lamps at 100 or 120 Hz, folded back below the Nyquist rate of a
slower camera) scales the brightness of every pixel at once, or row after row with a rolling shutter:
each row of the picture's blocks brightens and darkens in phase. A moving textured object changes the
blocks' brightness with signs set by its texture, which cancel along a row. Used by the survey (which
frequencies are flicker, for the window's frame step) and by the detection policy (which peaks are not
objects).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.peaks import noise_floor

#: Brightness is followed frame by frame as the means of BRIGHTNESS_BLOCKS x BRIGHTNESS_BLOCKS blocks.
BRIGHTNESS_BLOCKS = 8
#: A block row's brightness oscillates when it stands this far above its own floor ...
FLICKER_SNR = 10.0
#: ... with this coherence along the row (1: every block in phase, as lighting does; 1/B at random) ...
FLICKER_COHERENCE = 0.6
#: ... and the peak is flicker when this fraction of the picture's block rows do.
FLICKER_ROWS = 0.6


def floor_of(power: NDArray[np.float64]) -> NDArray[np.float64]:
    """Running median along axis 0 of every column (each column's noise floor), at least 1e-30.

    Parameters
    ----------
    power : ndarray of float64, shape (F, ...)

    Returns
    -------
    ndarray of float64, same shape
    """
    width = max(15, power.shape[0] // 6)
    cols = power.reshape(power.shape[0], -1)
    out = np.stack([noise_floor(cols[:, j], width=width) for j in range(cols.shape[1])], axis=1)
    return np.maximum(out.reshape(power.shape), 1e-30)


def flickering_rows(
    spectra: NDArray[np.complex128],
    frequencies_hz: NDArray[np.float64],
    frequency_hz: float,
    half_width_hz: float,
) -> tuple[float, int]:
    """Fraction of the picture's block rows whose brightness oscillates in phase at a frequency.

    Parameters
    ----------
    spectra : ndarray of complex128, shape (F, B, B)
        Spectra of each block's frame-to-frame brightness change.
    frequencies_hz : ndarray of float64, shape (F,)
    frequency_hz, half_width_hz : float
        The peak, and how far from it its bins reach.

    Returns
    -------
    fraction : float
        Rows that stand ``FLICKER_SNR`` above their floor with ``FLICKER_COHERENCE`` along the row.
    bin : int
        The bin (of ``frequencies_hz``) where the rows oscillate most; -1 when no bin is near.
    """
    near = np.abs(frequencies_hz - frequency_hz) <= half_width_hz
    if not near.any():
        return 0.0, -1
    rows = spectra.mean(axis=2)  # (F, B): each block row's in-phase mean
    row_power = np.abs(rows) ** 2
    row_snr = row_power[near].max(axis=0) / floor_of(row_power)[near].max(axis=0)
    k = int(np.flatnonzero(near)[int(np.argmax(row_power[near].sum(axis=1)))])
    block_power = np.abs(spectra[k]) ** 2
    coherence = row_power[k] / np.maximum(block_power.mean(axis=1), 1e-30)
    return float(np.mean((row_snr >= FLICKER_SNR) & (coherence >= FLICKER_COHERENCE))), k


def block_brightness(gray: NDArray[np.uint8]) -> NDArray[np.float32]:
    """Mean grey level of each of ``BRIGHTNESS_BLOCKS`` x ``BRIGHTNESS_BLOCKS`` blocks of a frame."""
    return np.asarray(cv2.resize(gray, (BRIGHTNESS_BLOCKS,) * 2, interpolation=cv2.INTER_AREA), np.float32)


def block_change(previous: NDArray[np.uint8], gray: NDArray[np.uint8]) -> NDArray[np.float32]:
    """Mean absolute grey-level change of each block between two consecutive frames."""
    diff = cv2.absdiff(gray, previous)
    return np.asarray(cv2.resize(diff, (BRIGHTNESS_BLOCKS,) * 2, interpolation=cv2.INTER_AREA), np.float32)


__all__ = [
    "BRIGHTNESS_BLOCKS",
    "FLICKER_COHERENCE",
    "FLICKER_ROWS",
    "FLICKER_SNR",
    "block_brightness",
    "block_change",
    "flickering_rows",
    "floor_of",
]
