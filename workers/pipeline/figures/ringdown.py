"""The ring-down: the spectrogram of each object's ring-down, with its eigenfrequency and release."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import (
    AxisStyle,
    ColourBar,
    Underlay,
    _axes_box_px,
    _axis,
    _colour_bar,
    _colour_index,
    _colour_lut,
    _figure,
    _finish,
    _legend,
    _no_object_message,
    _note,
    _panels,
    _raster,
    _sample_rate,
    _times_s,
    _title,
    _window_span_s,
)
from workers.pipeline.figures.style import (
    _TITLE,
    SPECTROGRAM_CMAP,
    SPECTROGRAM_RANGE_DB,
    _mpl_color,
    format_quantity,
    panel_figure_size,
)
from workers.pipeline.model import finite_or_none

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis, ObjectMeasurement


def ringdown_spectrogram(
    displacement: NDArray[np.floating[Any]],
    *,
    sample_rate_hz: float,
    window: int | None = None,
    hop: int = 1,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Short-time power spectrum of the velocity of a displacement series.

    The velocity (first difference times ``fps``, mean removed) is made analytic (negative frequencies
    removed, so an oscillation gives one ridge at f instead of beats between +f and -f in short
    windows), padded with ``window / 2`` zeros at both ends so that segments centre on every ``hop``-th
    sample, Hann-windowed, zero-padded to 4x the window and Fourier transformed.

    Parameters
    ----------
    displacement : ndarray of float, shape (N + 1,)
        Displacement per frame (any length unit); NaNs are treated as 0.
    sample_rate_hz : float
        Sample rate, frames per second.
    window : int, optional
        Segment length in samples; default the largest power of two <= N / 3, clipped to [8, 64].
    hop : int
        Samples between segment centres.

    Returns
    -------
    times_s : ndarray of float64, shape (T,)
        Segment centres, seconds from the series' first sample.
    frequencies_hz : ndarray of float64, shape (F,)
        0 to ``fps / 2``.
    power : ndarray of float64, shape (F, T)
        Power of the velocity, (unit/s)² per bin.
    """
    if not (math.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise ValueError(f"fps={sample_rate_hz} must be a positive number")
    x = np.nan_to_num(np.asarray(displacement, np.float64).ravel())
    v = np.diff(x) * sample_rate_hz
    n = len(v)
    if n < 4:
        raise ValueError(f"a spectrogram needs at least 5 displacement samples, got {len(x)}")
    v = v - v.mean()
    if window is None:
        window = 1 << max(3, min(6, int(math.log2(max(n // 3, 1)))))
    window = max(4, min(int(window), n))
    hop = max(1, int(hop))
    # Analytic signal: keep DC and Nyquist, double the positive frequencies, drop the negative ones.
    # Computed on the series zero-padded to twice its length, so its start does not wrap onto its end.
    m = 2 * n
    gain = np.zeros(m)
    gain[0] = gain[n] = 1.0
    gain[1:n] = 2.0
    analytic = np.fft.ifft(np.fft.fft(v, m) * gain)[:n]
    half = window // 2
    padded = np.concatenate([np.zeros(half, complex), analytic, np.zeros(window - half, complex)])
    centres = np.arange(0, n + 1, hop)
    segments = np.lib.stride_tricks.sliding_window_view(padded, window)[centres]
    nfft = 4 * window
    spec = np.fft.fft(segments * np.hanning(window), n=nfft, axis=1)[:, : nfft // 2 + 1]
    power = (np.abs(spec) ** 2).T
    freqs = np.arange(nfft // 2 + 1) * (sample_rate_hz / nfft)
    # Segment k spans velocity samples k - half .. k - half + window - 1; velocity sample i lies between
    # frames i and i + 1, so the segment's centre is at frame k (for an even window).
    times = centres / sample_rate_hz
    return times.astype(np.float64), freqs.astype(np.float64), power.astype(np.float64)


#: The axes of a spectrogram panel: few frequency ticks, no grid over the image.
_PANEL_AXIS = AxisStyle(y_bins=4, grid=False)


def draw_ringdown(analysis: Analysis) -> NDArray[np.uint8]:
    """The spectrogram of each object's ring-down, with its eigenfrequency and release instant.

    The spectrogram comes from the analysis when it has one, else from :func:`ringdown_spectrogram` of
    the object's ``displacement_px``; power is shown in dB relative to each panel's maximum
    (:data:`SPECTROGRAM_RANGE_DB` range).

    Parameters
    ----------
    analysis : Analysis

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, (W, H) = :func:`panel_figure_size` ``(len(objects))``; objects without a series
        (e.g. the paper method) and clips without objects get a note instead.
    """
    size = panel_figure_size(len(analysis.objects))
    fig, canvas = _figure(size, transparent=True)
    fig.suptitle(
        "Ring-down spectrogram (short-time spectrum of the velocity)",
        fontsize=_TITLE,
        y=1 - 12 / size[1],
        va="top",
    )
    if not analysis.objects:
        ax = _panels(fig, 1, right_px=110.0)[0]
        ax.set_xlim(*_window_span_s(analysis))
        ax.set_ylim(0, _sample_rate(analysis) / 2)
        _axis(ax, size, xlabel="time (s)", ylabel="frequency (Hz)", style=_PANEL_AXIS)
        _note(ax, _no_object_message(analysis))
        return _finish(canvas, size)
    axes = _panels(fig, len(analysis.objects), right_px=110.0)
    underlays: list[Underlay] = []
    for ax, obj in zip(axes, analysis.objects, strict=True):
        image = _object_panel(ax, size, analysis, obj)
        if image is not None:
            underlays.append(image)
    if underlays:
        width, height = size
        bar = ColourBar(
            x=width - 92,
            y=70,
            height=height - 130,
            vmin=-SPECTROGRAM_RANGE_DB,
            vmax=0.0,
            cmap=SPECTROGRAM_CMAP,
            label="power (dB re. panel max)",
            bins=2,
            width=16,
        )
        underlays.append(_colour_bar(fig, size, bar))
    return _finish(canvas, size, underlays=underlays)


def _object_panel(
    ax: Any, size: tuple[int, int], analysis: Analysis, obj: ObjectMeasurement
) -> Underlay | None:
    """Draw ``obj``'s panel on ``ax``: its axes, eigenfrequency, release and legend.

    Returns the spectrogram's image to lay under the (transparent) axes, or None (and a note on the
    panel) when the object has no displacement series.
    """
    nyquist = _sample_rate(analysis) / 2
    ax.set_ylim(0, nyquist)
    _title(ax, f"#{obj.id}")
    spectrogram = _spectrogram_of(analysis, obj)
    if spectrogram is None:
        ax.set_xlim(*_window_span_s(analysis))
        _axis(ax, size, xlabel="time (s)", ylabel="frequency (Hz)", style=_PANEL_AXIS)
        _note(ax, f"#{obj.id}: no displacement series ({analysis.method} method)")
        return None
    times, freqs, _ = spectrogram
    xlim = (float(times[0]), float(times[-1])) if len(times) > 1 else _window_span_s(analysis)
    ylim = (0.0, min(nyquist, float(freqs[-1])))
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    _axis(ax, size, xlabel="time (s)", ylabel="frequency (Hz)", style=_PANEL_AXIS)
    ax.patch.set_visible(False)
    image = _spectrogram_image(ax, size, spectrogram, xlim=xlim, ylim=ylim)
    _mark_frequency_and_release(ax, obj)
    _legend(ax, size, fontsize=9.5)
    return image


def _spectrogram_image(
    ax: Any,
    size: tuple[int, int],
    spectrogram: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    *,
    xlim: tuple[float, float],
    ylim: tuple[float, float],
) -> Underlay:
    """The spectrogram in dB re. its maximum, rasterised to the pixels of ``ax`` (an underlay)."""
    times, freqs, power = spectrogram
    peak = float(np.max(power)) if power.size else 0.0
    db = 10 * np.log10(np.maximum(power, 1e-300) / max(peak, 1e-300))
    x0, y0, x1, y1 = _axes_box_px(ax, size)
    flat = _raster(db, times, freqs, xlim=xlim, ylim=ylim, shape=(y1 - y0, x1 - x0))
    shown = db.ravel()[flat]
    return (_colour_lut(SPECTROGRAM_CMAP)[_colour_index(shown, -SPECTROGRAM_RANGE_DB, 0.0)], x0, y0)


def _mark_frequency_and_release(ax: Any, obj: ObjectMeasurement) -> None:
    """A dashed line at the object's eigenfrequency and a dotted one at its release, when measured."""
    colour = _mpl_color(obj.id)
    f = finite_or_none(obj.eigenfrequency_hz)
    if f is not None:
        ax.axhline(
            f,
            color=colour,
            linestyle="--",
            linewidth=2.0,
            label=f"#{obj.id} f = {format_quantity(f, obj.eigenfrequency_uncertainty_hz, 'Hz')}",
        )
    release = finite_or_none(obj.release_time_s)
    if release is not None:
        ax.axvline(release, color=colour, linestyle=":", linewidth=2.2, label=f"release {release:.3f} s")


def _spectrogram_of(
    analysis: Analysis, obj: ObjectMeasurement
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """(times_s from the clip's start, frequencies_hz, power (F, T)) or None without a series."""
    given = getattr(obj, "spectrogram", None)
    if given is None:
        whole = getattr(analysis, "spectrogram", None)
        given = whole.get(obj.id) if isinstance(whole, dict) else None
    if given is not None:
        times = getattr(given, "times_s", None)
        freqs = getattr(given, "frequencies_hz", None)
        power = getattr(given, "power", None)
        if times is not None and freqs is not None and power is not None:
            p = np.asarray(power, np.float64)
            if p.shape == (len(freqs), len(times)):
                return np.asarray(times, np.float64), np.asarray(freqs, np.float64), p
    if obj.displacement_px is None or len(obj.displacement_px) < 5:
        return None
    times, freqs, power = ringdown_spectrogram(obj.displacement_px, sample_rate_hz=_sample_rate(analysis))
    t0 = float(_times_s(analysis, len(obj.displacement_px))[0])
    return times + t0, freqs, power
