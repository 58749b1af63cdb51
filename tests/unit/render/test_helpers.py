"""The render module's small public pieces: palette, sizes, number formatting, spectrogram."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workers.pipeline.figures import (
    display_scale,
    format_quantity,
    object_color,
    panel_figure_size,
    ringdown_spectrogram,
)


def test_palette_gives_distinct_colours_and_cycles():
    colours = [object_color(i) for i in range(1, 10)]
    assert len(set(colours)) == 9
    for c in colours:
        assert len(c) == 3
        assert all(isinstance(v, int) and 0 <= v <= 255 for v in c)
        assert max(c) - min(c) > 60, f"{c} is too grey to tell apart from the plots' black and grey"
    assert object_color(10) == object_color(1)


@pytest.mark.parametrize(
    ("value", "sd", "unit", "text"),
    [
        (4.99777, 0.00047, "Hz", "4.99777 ± 0.00047 Hz"),
        (494.27, 15.2, "N/m", "494 ± 15 N/m"),
        (0.0123, 0.00012, "m", "0.01230 ± 0.00012 m"),
        (0.5008, None, "kg", "0.5008 kg"),
        (3.0, 0.0, "Hz", "3 Hz"),
        (5.0, math.inf, "Hz", "5 Hz"),
        (1.5e7, 2e5, "N/m", "(1.500 ± 0.020)×10⁷ N/m"),
        (2e-9, 1e-10, "m", "(2.00 ± 0.10)×10⁻⁹ m"),
        (None, 1.0, "kg", "n/a"),
        (math.nan, 1.0, "kg", "n/a"),
    ],
)
def test_format_quantity(value, sd, unit, text):
    assert format_quantity(value, sd, unit) == text


def test_display_scale():
    assert display_scale(640, 480) == 1.0
    assert display_scale(320, 240) == 2.0
    assert display_scale(100, 80) == 7.0
    assert display_scale(2560, 1440) == 0.5
    with pytest.raises(ValueError, match="empty"):
        display_scale(0, 480)


def test_panel_figures_grow_with_the_object_count():
    heights = [panel_figure_size(n)[1] for n in range(0, 9)]
    assert heights == sorted(heights)
    assert all(panel_figure_size(n)[0] == 1000 for n in range(9))


def damped(f_hz: float, *, fps: float = 30.0, n: int = 128, release: int = 20, zeta: float = 0.02):
    t = (np.arange(n + 1) - release) / fps
    w = 2 * math.pi * f_hz
    x = np.where(t >= 0, np.exp(-zeta * w * np.maximum(t, 0)) * np.cos(w * np.maximum(t, 0)), 1.0)
    return 7.5 * x  # pixels


@pytest.mark.parametrize("f_hz", [3.0, 6.0, 11.0])
def test_spectrogram_ridge_follows_the_ringdown(f_hz):
    fps, n, release = 30.0, 128, 20
    times, freqs, power = ringdown_spectrogram(
        damped(f_hz, fps=fps, n=n, release=release), sample_rate_hz=fps
    )
    assert times.shape == (n + 1,)
    assert power.shape == (len(freqs), len(times))
    assert freqs[0] == 0.0
    assert freqs[-1] == pytest.approx(fps / 2)
    assert times[0] == 0.0
    assert times[-1] == pytest.approx(n / fps)
    # After release, the ridge is at f within one display bin of the 32-sample window.
    after = (times > (release + 16) / fps) & (times < (n - 16) / fps)
    ridge = freqs[np.argmax(power[:, after], axis=0)]
    assert np.all(np.abs(ridge - f_hz) <= fps / 32), ridge
    # Before release (window entirely before it) nothing moves: only the analytic signal's Hilbert
    # tails leak there, below the -30 dB that the image's 40 dB range would show brightly.
    before = times < (release - 16) / fps
    assert power[:, before].max() < 1e-3 * power.max()


def test_spectrogram_of_a_short_or_bad_series_is_refused():
    with pytest.raises(ValueError, match="at least 5"):
        ringdown_spectrogram(np.zeros(4), sample_rate_hz=30.0)
    with pytest.raises(ValueError, match="fps"):
        ringdown_spectrogram(np.zeros(40), sample_rate_hz=0.0)


def test_drawing_leaves_out_the_3d_toolkit_and_keeps_it_importable():
    """matplotlib's import loads its 3-D toolkit (a sixth of the import) for a projection never drawn
    here, and writes every artist's set() signature for help() (a third): a fresh process that renders
    an image loads matplotlib without either, warns nothing, can still import the toolkit afterwards, and
    sets artist properties as before."""
    import subprocess
    import sys

    code = (
        "import sys, warnings\n"
        "warnings.simplefilter('error')\n"
        "from workers.drawing import warm_up\n"
        "warm_up().join()\n"
        "assert 'matplotlib.figure' in sys.modules\n"
        "assert not any(m.startswith('mpl_toolkits.mplot3d') for m in sys.modules)\n"
        "from mpl_toolkits.mplot3d import Axes3D\n"
        "assert Axes3D is not None\n"
        # Artists' set() is unchanged (aliases included), only its help() signature is not written.
        "from matplotlib.lines import Line2D\n"
        "line = Line2D([0, 1], [0, 1])\n"
        "line.set(lw=3, color='red', label='x')\n"
        "assert (line.get_linewidth(), line.get_color(), line.get_label()) == (3, 'red', 'x')\n"
        "import matplotlib.artist as a\n"
        "assert isinstance(a.Artist.__dict__['_update_set_signature_and_docstring'], classmethod)\n"
        "class Mine(a.Artist):\n"
        "    def set_size(self, value): self.size = value\n"
        "m = Mine(); m.set(size=2, alpha=0.5)\n"
        "assert (m.size, m.get_alpha()) == (2, 0.5)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
