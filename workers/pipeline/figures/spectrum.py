"""The spectrum: the summed motion spectrum on a log scale with its landmarks."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import (
    AxisStyle,
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
    from workers.pipeline.model import Analysis, ObjectMeasurement


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


#: The spectrum's axes: a log power scale, more frequency ticks than the default.
_SPECTRUM_AXIS = AxisStyle(x_bins=8, log_y=True)


@dataclass(frozen=True)
class _Curve:
    """The summed spectrum as drawn on the log scale.

    Attributes
    ----------
    freqs, power : ndarray of float64, shape (F,)
        The analysis's summed spectrum.
    ok : ndarray of bool, shape (F,)
        Bins that show on a log scale (finite, positive power).
    band : (float, float)
        The analysed band, Hz.
    nyquist : float
        Half the sample rate, Hz: the right edge of the plot.
    top, bottom : float
        The highest and lowest power of the band's bins (of all shown bins when none is in the band;
        1 and 1e-3 when none shows).
    """

    freqs: NDArray[np.float64]
    power: NDArray[np.float64]
    ok: NDArray[np.bool_]
    band: tuple[float, float]
    nyquist: float
    top: float
    bottom: float

    def at(self, f: float) -> float:
        """The curve's power at ``f`` (interpolated), where a mark sits; ``top`` without a curve."""
        if not self.ok.any():
            return self.top
        return float(np.interp(f, self.freqs[self.ok], self.power[self.ok]))


def _curve(analysis: Analysis) -> _Curve:
    """The analysis's summed spectrum, its shown bins and its range (which follows the band: the DC bin
    and the edges outside it may be far below)."""
    freqs = np.asarray(analysis.frequencies_hz, np.float64)
    power = np.asarray(analysis.power, np.float64)
    ok = np.isfinite(power) & (power > 0)
    lo, hi = analysis.band_hz
    in_band = ok & (freqs >= lo) & (freqs <= hi)
    if ok.any():
        ref = power[in_band] if in_band.any() else power[ok]
        top, bottom = float(ref.max()), float(ref.min())
    else:
        top, bottom = 1.0, 1e-3
    return _Curve(freqs, power, ok, (lo, hi), _sample_rate(analysis) / 2, top, bottom)


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
    curve = _curve(analysis)
    ax.set_xlim(0, curve.nyquist)
    ax.set_yscale("log")
    _title(
        ax,
        f"Summed motion spectrum ({analysis.method} method, {analysis.fps:g} fps, "
        f"{analysis.frames_used[1] - analysis.frames_used[0]} frames)",
        fontsize=_TITLE,
    )
    _draw_curve_and_band(ax, curve)
    bottom = _draw_noise_floor(ax, analysis, curve)
    for obj in analysis.objects:
        _mark_object(ax, obj, curve)
    _mark_rejected_peaks(ax, analysis, curve)
    # Headroom above the highest peak for the legend.
    top = curve.top
    ax.set_ylim(bottom / 3.0, top * (top / bottom) ** 0.35 * 3.0 if top > bottom else top * 10.0)
    ylabel = "summed motion power (px², log scale)"
    _axis(ax, PLOT_SIZE_PX, xlabel="frequency (Hz)", ylabel=ylabel, style=_SPECTRUM_AXIS)
    if not analysis.objects:
        _note(ax, _no_object_message(analysis))
    _legend(ax, PLOT_SIZE_PX)
    return _finish(canvas, PLOT_SIZE_PX)


def _draw_curve_and_band(ax: Any, curve: _Curve) -> None:
    """The summed spectrum's line and grey spans over the frequencies outside the analysed band."""
    if curve.ok.any():
        ok = curve.ok
        ax.plot(
            curve.freqs[ok], curve.power[ok], color="0.15", linewidth=1.6, label="summed spectrum", zorder=3
        )
    lo, hi = curve.band
    if lo > 0:
        ax.axvspan(0, lo, color="0.9", zorder=0, label="outside analysed band")
    if hi < curve.nyquist:
        ax.axvspan(
            hi, curve.nyquist, color="0.9", zorder=0, label=None if lo > 0 else "outside analysed band"
        )


def _draw_noise_floor(ax: Any, analysis: Analysis, curve: _Curve) -> float:
    """The noise floor: the analysis's noise spectrum (dashed), else the band's median level.

    Returns the bottom of the plotted range: the curve's, lowered to the noise spectrum's lowest level
    in the band.
    """
    bottom = curve.bottom
    noise_curve, floor = _noise_floor(analysis)
    if noise_curve is not None:
        freqs, (lo, hi) = curve.freqs, curve.band
        good = np.isfinite(noise_curve) & (noise_curve > 0)
        ax.plot(
            freqs[good], noise_curve[good], color="0.45", linestyle="--", linewidth=1.3, label="noise floor"
        )
        good_band = good & (freqs >= lo) & (freqs <= hi)
        if good_band.any():
            bottom = min(bottom, float(noise_curve[good_band].min()))
    elif floor is not None:
        ax.axhline(floor, color="0.45", linestyle="--", linewidth=1.3, label="noise floor (band median)")
    return bottom


def _mark_object(ax: Any, obj: ObjectMeasurement, curve: _Curve) -> None:
    """An object's eigenfrequency (a line and a point on the curve) and its harmonics, in its colour."""
    colour = _mpl_color(obj.id)
    f = finite_or_none(obj.eigenfrequency_hz)
    if f is None:
        return
    ax.axvline(f, color=colour, linewidth=2.2, zorder=2)
    label = f"#{obj.id} f = {format_quantity(f, obj.eigenfrequency_uncertainty_hz, 'Hz')}"
    _mark(ax, f, curve.at(f), colour, label, marker="o", size=9, zorder=4)
    harmonics = [h for h in obj.harmonics_hz if math.isfinite(h) and 0 < h <= curve.nyquist]
    for i, hf in enumerate(harmonics):
        ax.axvline(
            hf,
            color=colour,
            linestyle=":",
            linewidth=2.0,
            zorder=2,
            label=f"#{obj.id} harmonics" if i == 0 else None,
        )


def _mark_rejected_peaks(ax: Any, analysis: Analysis, curve: _Curve) -> None:
    """The peaks the analysis rejected: found harmonics (a triangle) and artefacts (a cross above)."""
    found = [(f, r) for f, r in _rejected_peaks(analysis) if 0 <= f <= curve.nyquist]
    # A harmonic the analysis found (an overtone, rejected as an object of its own) is marked as such,
    # in its object's colour, with its frequency; the other rejected peaks are artefacts.
    for f, _ in [(f, r) for f, r in found if r == "harmonic"]:
        owner = _harmonic_of(analysis, f)
        tint: Any = _mpl_color(owner) if owner is not None else "crimson"
        of = f" of #{owner}" if owner is not None else ""
        _mark(ax, f, curve.at(f), tint, f"harmonic{of} found at {f:.4g} Hz", marker="v", size=11, zorder=5)
    rejected = [(f, r) for f, r in found if r != "harmonic"]
    if rejected:
        ax.plot(
            [f for f, _ in rejected],
            [curve.at(f) * 1.6 for f, _ in rejected],
            marker="x",
            markersize=11,
            markeredgewidth=2.5,
            color="crimson",
            linestyle="none",
            zorder=5,
            label="rejected artefact peak",
        )
