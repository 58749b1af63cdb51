"""The displacement: each object's displacement against time with the fitted damped oscillation."""

from __future__ import annotations

from typing import TYPE_CHECKING

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
    _panels,
    _times_s,
    _title,
    _window_span_s,
)
from workers.pipeline.figures.style import (
    _TITLE,
    _mpl_color,
    format_quantity,
    panel_figure_size,
)
from workers.pipeline.model import finite_or_none

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis, ObjectMeasurement

#: The axes of a panel without a series: no y scale to show.
_NO_Y_TICKS = AxisStyle(y_ticks=False)


def _metres_per_px(obj: ObjectMeasurement) -> float | None:
    a_m, a_px = finite_or_none(obj.amplitude_m), finite_or_none(obj.amplitude_px)
    if a_m is None or a_px is None or a_m <= 0 or a_px <= 0:
        return None
    return a_m / a_px


def _displacement_series(
    obj: ObjectMeasurement,
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, str, float] | None:
    """(measured, model, unit, factor from the stored series to the unit) or None without a series."""
    disp_m = getattr(obj, "displacement_m", None)
    if disp_m is not None:
        model_m = getattr(obj, "model_displacement_m", None)
        measured = np.asarray(disp_m, np.float64) * 1e3
        model = None if model_m is None else np.asarray(model_m, np.float64) * 1e3
        return measured, model, "mm", 1e3
    if obj.displacement_px is None:
        return None
    measured = np.asarray(obj.displacement_px, np.float64)
    model = None if obj.model_displacement_px is None else np.asarray(obj.model_displacement_px, np.float64)
    scale = _metres_per_px(obj)
    if scale is not None:
        factor = scale * 1e3
        return measured * factor, None if model is None else model * factor, "mm", factor
    return measured, model, "px", 1.0


def draw_displacement(analysis: Analysis) -> NDArray[np.uint8]:
    """Each object's displacement against time with the fitted damped oscillation and the release instant.

    Displacement is in millimetres when the object's amplitude in metres is known (from
    ``displacement_m`` or ``amplitude_m / amplitude_px``), in image pixels otherwise.

    Parameters
    ----------
    analysis : Analysis
        Uses each object's ``displacement_px`` and ``model_displacement_px`` (float64, (N + 1,); the model
        NaN before release), ``release_time_s``, ``fps`` and ``frames_used``.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, (W, H) = :func:`panel_figure_size` ``(len(objects))``; objects without a series
        (e.g. the paper method) and clips without objects get a note instead of a curve.
    """
    size = panel_figure_size(len(analysis.objects))
    fig, canvas = _figure(size)
    fig.suptitle("Displacement along the motion axis", fontsize=_TITLE, y=1 - 12 / size[1], va="top")
    if not analysis.objects:
        ax = _panels(fig, 1)[0]
        ax.set_xlim(*_window_span_s(analysis))
        _axis(ax, size, xlabel="time (s)", ylabel="displacement (px)", style=_NO_Y_TICKS)
        _note(ax, _no_object_message(analysis))
        return _finish(canvas, size)
    axes = _panels(fig, len(analysis.objects))
    for ax, obj in zip(axes, analysis.objects, strict=True):
        colour = _mpl_color(obj.id)
        series = _displacement_series(obj)
        if series is None:
            ax.set_xlim(*_window_span_s(analysis))
            _axis(ax, size, xlabel="time (s)", ylabel="displacement", style=_NO_Y_TICKS)
            _note(ax, f"#{obj.id}: no displacement series ({analysis.method} method)")
            continue
        measured, model, unit, _ = series
        t = _times_s(analysis, len(measured))
        ax.plot(
            t,
            measured,
            color=colour,
            linewidth=2.0,
            marker="o",
            markersize=4,
            label=f"#{obj.id} measured",
            zorder=2,
        )
        if model is not None and len(model) == len(t) and np.isfinite(model).any():
            ax.plot(
                t,
                model,
                color="black",
                linestyle="--",
                linewidth=1.2,
                label="damped-oscillation fit",
                zorder=3,
            )
        release = finite_or_none(obj.release_time_s)
        if release is not None:
            ax.axvline(release, color=colour, linestyle=":", linewidth=2.2, label=f"release {release:.3f} s")
        ax.set_xlim(float(t[0]), float(t[-1]))
        _axis(ax, size, xlabel="time (s)", ylabel=f"displacement ({unit})")
        zeta = finite_or_none(obj.damping_ratio)
        f = format_quantity(obj.eigenfrequency_hz, obj.eigenfrequency_uncertainty_hz, "Hz")
        info = f"#{obj.id}: f = {f}"
        if zeta is not None:
            info += f", ζ = {format_quantity(zeta, obj.damping_ratio_uncertainty, '')}"
        _title(ax, info)
        _legend(ax, size)
    return _finish(canvas, size)
