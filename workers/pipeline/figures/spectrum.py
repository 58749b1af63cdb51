"""The spectrum: the summed motion spectrum on a log scale with its landmarks."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import (
    _axis,
    _figure,
    _finish,
    _legend,
    _no_object_message,
    _note,
    _sample_rate,
    _title,
)
from workers.pipeline.figures.style import (
    _TITLE,
    PLOT_SIZE_PX,
    _mpl_color,
    format_quantity,
)
from workers.pipeline.model import finite_or_none

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis


def _noise_floor(analysis: Analysis) -> tuple[NDArray[np.float64] | None, float | None]:
    """(noise spectrum on ``frequencies_hz`` if the analysis has one, else a flat floor level)."""
    for name in ("noise_power", "noise_spectrum", "background_power", "noise"):
        value = getattr(analysis, name, None)
        if value is None:
            continue
        arr = np.asarray(value, np.float64)
        if arr.shape == np.shape(analysis.frequencies_hz):
            return arr, None
    freqs = np.asarray(analysis.frequencies_hz, np.float64)
    power = np.asarray(analysis.power, np.float64)
    lo, hi = analysis.band_hz
    inside = (freqs >= lo) & (freqs <= hi) & np.isfinite(power) & (power > 0)
    if not inside.any():
        return None, None
    # The median bin of the band: peaks occupy few bins, so this is the level of the floor.
    return None, float(np.median(power[inside]))


def _harmonic_of(analysis: Analysis, f: float) -> int | None:
    """The id of the object ``f`` is an overtone of (an integer multiple, within 3 %), if any."""
    for obj in analysis.objects:
        f0 = finite_or_none(obj.eigenfrequency_hz)
        if (
            f0 is not None
            and f0 > 0
            and round(f / f0) >= 2
            and abs(f / f0 - round(f / f0)) < 0.03 * round(f / f0)
        ):
            return obj.id
    return None


def _rejected_peaks(analysis: Analysis) -> list[tuple[float, str]]:
    """(frequency_hz, evidence or reason) of peaks the analysis rejected, when it records them."""
    out: list[tuple[float, str]] = []
    for name in ("rejected_peaks", "artefact_peaks", "artifact_peaks"):
        for item in getattr(analysis, name, None) or []:
            f = getattr(item, "frequency_hz", None)
            if f is None and isinstance(item, int | float):
                f = float(item)
            if f is None and isinstance(item, Sequence) and item and isinstance(item[0], int | float):
                f = float(item[0])
            if f is None or not math.isfinite(f):
                continue
            reason = (
                getattr(item, "evidence", None)
                or getattr(item, "reason", None)
                or getattr(item, "code", None)
                or ""
            )
            out.append((float(f), str(reason)))
        if out:
            break
    return out


def _mark(
    ax: Any, f: float, power: float, colour: Any, label: str, *, marker: str, size: int, zorder: int
) -> None:
    """One point of the spectrum marked (outlined in black) and named in the legend."""
    ax.plot(
        [f],
        [power],
        marker=marker,
        markersize=size,
        color=colour,
        markeredgecolor="black",
        linestyle="none",
        zorder=zorder,
        label=label,
    )


def draw_spectrum(analysis: Analysis) -> NDArray[np.uint8]:
    """The summed motion spectrum on a log scale with its landmarks.

    Marks each object's eigenfrequency and harmonics (in the object's colour), the noise floor (the
    analysis's noise spectrum when it has one, else the band's median level), rejected artefact peaks
    (when the analysis records them) and the part of the spectrum outside the analysed band.

    Parameters
    ----------
    analysis : Analysis
        Uses ``frequencies_hz`` and ``power`` (float64, (F,)), ``band_hz``, ``objects``, ``fps``.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, (W, H) = :data:`PLOT_SIZE_PX` (1000 x 600) pixels.
    """
    fig, canvas = _figure(PLOT_SIZE_PX)
    ax = fig.add_axes((0.085, 0.11, 0.885, 0.8))
    freqs = np.asarray(analysis.frequencies_hz, np.float64)
    power = np.asarray(analysis.power, np.float64)
    ok = np.isfinite(power) & (power > 0)
    nyquist = _sample_rate(analysis) / 2
    ax.set_xlim(0, nyquist)
    ax.set_yscale("log")
    _title(
        ax,
        f"Summed motion spectrum ({analysis.method} method, {analysis.fps:g} fps, "
        f"{analysis.frames_used[1] - analysis.frames_used[0]} frames)",
        fontsize=_TITLE,
    )
    lo, hi = analysis.band_hz
    in_band = ok & (freqs >= lo) & (freqs <= hi)
    if ok.any():
        ax.plot(freqs[ok], power[ok], color="0.15", linewidth=1.6, label="summed spectrum", zorder=3)
        # The range follows the band: the DC bin and the edges outside it may be far below.
        ref = power[in_band] if in_band.any() else power[ok]
        top = float(ref.max())
        bottom = float(ref.min())
    else:
        top, bottom = 1.0, 1e-3
    if lo > 0:
        ax.axvspan(0, lo, color="0.9", zorder=0, label="outside analysed band")
    if hi < nyquist:
        ax.axvspan(hi, nyquist, color="0.9", zorder=0, label=None if lo > 0 else "outside analysed band")

    noise_curve, floor = _noise_floor(analysis)
    if noise_curve is not None:
        good = np.isfinite(noise_curve) & (noise_curve > 0)
        ax.plot(
            freqs[good], noise_curve[good], color="0.45", linestyle="--", linewidth=1.3, label="noise floor"
        )
        good_band = good & (freqs >= lo) & (freqs <= hi)
        if good_band.any():
            bottom = min(bottom, float(noise_curve[good_band].min()))
    elif floor is not None:
        ax.axhline(floor, color="0.45", linestyle="--", linewidth=1.3, label="noise floor (band median)")

    def power_at(f: float) -> float:
        if not ok.any():
            return top
        return float(np.interp(f, freqs[ok], power[ok]))

    for obj in analysis.objects:
        colour = _mpl_color(obj.id)
        f = finite_or_none(obj.eigenfrequency_hz)
        if f is None:
            continue
        ax.axvline(f, color=colour, linewidth=2.2, zorder=2)
        label = f"#{obj.id} f = {format_quantity(f, obj.eigenfrequency_sd_hz, 'Hz')}"
        _mark(ax, f, power_at(f), colour, label, marker="o", size=9, zorder=4)
        harmonics = [h for h in obj.harmonics_hz if math.isfinite(h) and 0 < h <= nyquist]
        for i, hf in enumerate(harmonics):
            ax.axvline(
                hf,
                color=colour,
                linestyle=":",
                linewidth=2.0,
                zorder=2,
                label=f"#{obj.id} harmonics" if i == 0 else None,
            )
    found = [(f, r) for f, r in _rejected_peaks(analysis) if 0 <= f <= nyquist]
    # A harmonic the analysis found (an overtone, rejected as an object of its own) is marked as such,
    # in its object's colour, with its frequency; the other rejected peaks are artefacts.
    for f, _ in [(f, r) for f, r in found if r == "harmonic"]:
        owner = _harmonic_of(analysis, f)
        tint: Any = _mpl_color(owner) if owner is not None else "crimson"
        of = f" of #{owner}" if owner is not None else ""
        _mark(ax, f, power_at(f), tint, f"harmonic{of} found at {f:.4g} Hz", marker="v", size=11, zorder=5)
    rejected = [(f, r) for f, r in found if r != "harmonic"]
    if rejected:
        ax.plot(
            [f for f, _ in rejected],
            [power_at(f) * 1.6 for f, _ in rejected],
            marker="x",
            markersize=11,
            markeredgewidth=2.5,
            color="crimson",
            linestyle="none",
            zorder=5,
            label="rejected artefact peak",
        )
    # Headroom above the highest peak for the legend.
    ax.set_ylim(bottom / 3.0, top * (top / bottom) ** 0.35 * 3.0 if top > bottom else top * 10.0)
    _axis(
        ax,
        PLOT_SIZE_PX,
        xlabel="frequency (Hz)",
        ylabel="summed motion power (px², log scale)",
        x_bins=8,
        log_y=True,
    )
    if not analysis.objects:
        _note(ax, _no_object_message(analysis))
    _legend(ax, PLOT_SIZE_PX)
    return _finish(canvas, PLOT_SIZE_PX)
