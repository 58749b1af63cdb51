"""``modes.png`` and ``modes.gif`` on arrays: a small analysis whose one object carries real modes (found by
:func:`workers.pipeline.modes.object_modes` on a synthetic flow), drawn as one panel per mode and animated.

The object is a bar of 80 x 32 input pixels that sways along x at 3 Hz (ringing down) and bends in y at
11 Hz (steadily: its two halves move in anti-phase), seen on a flow grid of 2 input pixels per grid pixel.
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.unit.render.helpers import colour_mask, decode, gif_frames
from workers.drawing import ALL_KEYS, draw_all
from workers.pipeline.figures import (
    ARTIFACT_FILES,
    MODE_CELL_PX,
    NO_MODES_NOTE,
    draw_mode_shapes,
    mode_animation_frames,
    mode_shapes_size,
    object_color,
    write_mode_animation,
)
from workers.pipeline.figures.mode_animation import ANIMATION_FRAMES, FRAME_MS, animation_size
from workers.pipeline.figures.mode_shapes import ARROW_SHARE, crop_box, panel_label, panel_origin
from workers.pipeline.model import Analysis, ObjectMeasurement
from workers.pipeline.modes import ObjectModeShapes, object_modes
from workers.pipeline.roi import Roi

FRAME_SHAPE = (120, 160)
#: The bar in input pixels (x, y, w, h) and on the flow grid (rows, columns).
BAR_PX = (40, 44, 80, 32)
BAR_GRID = (slice(12, 28), slice(10, 50))


def bar_modes() -> ObjectModeShapes:
    """The bar's modes: 11 Hz (steady bending, the stronger) and 3 Hz (a swaying ring-down)."""
    fs, n = 60.0, 600
    roi = Roi(x=20, y=20, width=120, height=80, grid_shape=(40, 60), frame_shape=FRAME_SHAPE)
    t = np.arange(n + 1) / fs
    sway = 0.5 * np.exp(-0.6 * t) * np.sin(2 * np.pi * 3.0 * t)
    bend = 0.3 * np.sin(2 * np.pi * 11.0 * t)
    profile = np.linspace(-1.0, 1.0, 40)
    flow = np.random.default_rng(4).normal(0, 0.002, (n, 40, 60, 2)).astype(np.float32)
    flow[:, BAR_GRID[0], BAR_GRID[1], 0] += np.diff(sway)[:, None, None]
    flow[:, BAR_GRID[0], BAR_GRID[1], 1] += (np.diff(bend)[:, None] * profile[None, :])[:, None, :]
    mask = np.zeros((40, 60), bool)
    mask[BAR_GRID] = True
    return object_modes(flow, mask, sample_rate_hz=fs, band_hz=(0.5, 28.0), roi=roi)


def bar_analysis(modes: ObjectModeShapes | None) -> Analysis:
    """A 160 x 120 analysis of one object, the bar, carrying ``modes``."""
    x, y, w, h = BAR_PX
    labels = np.zeros(FRAME_SHAPE, np.uint16)
    labels[y : y + h, x : x + w] = 1
    obj = ObjectMeasurement(
        id=1,
        eigenfrequency_hz=11.0,
        eigenfrequency_uncertainty_hz=0.01,
        natural_frequency_hz=11.0,
        damping_ratio=None,
        damping_ratio_uncertainty=None,
        amplitude_px=1.0,
        amplitude_m=None,
        amplitude_uncertainty_m=None,
        depth_m=None,
        motion_direction=None,
        stiffness_n_per_m=None,
        stiffness_uncertainty_n_per_m=None,
        mass_kg=None,
        mass_uncertainty_kg=None,
        pixel_count=w * h,
        bbox_px=BAR_PX,
        harmonics_hz=[],
        release_time_s=0.0,
        snr_db=30.0,
        modes=modes,
        regime="steady",
    )
    rgb = np.random.default_rng(5).integers(30, 226, (*FRAME_SHAPE, 3), dtype=np.uint8)
    return Analysis(
        objects=[obj],
        labels=labels,
        frequencies_hz=np.linspace(0.0, 30.0, 301),
        power=np.ones(301),
        frequency_map_hz=np.zeros((40, 60), np.float32),
        frequency_map_valid=np.zeros((40, 60), bool),
        frame_rgb=rgb,
        fps=60.0,
        fps_source="user",
        frames_used=(0, 601),
        band_hz=(0.5, 28.0),
        quality=[],
        timings_s={},
        parameters={},
        method="default",
    )


def first_modes(modes: ObjectModeShapes, count: int) -> ObjectModeShapes:
    """``modes`` with only its first ``count`` modes."""
    found = replace(modes.found, modes=modes.found.modes[:count], mac=modes.found.mac[:count, :count])
    return replace(modes, found=found, shapes=modes.shapes[:count])


@pytest.fixture(scope="module")
def modes() -> ObjectModeShapes:
    found = bar_modes()
    assert [round(m.frequency_hz) for m in found.found.modes] == [11, 3]
    assert [m.damping_ratio is None for m in found.found.modes] == [True, False]
    return found


def panel_of(image: np.ndarray, column: int, *, inset: int = 4) -> np.ndarray:
    """Panel (0, ``column``) of a ``modes.png`` page, without its border."""
    x, y = panel_origin(0, column)
    return image[y + inset : y + MODE_CELL_PX[1] - inset, x + inset : x + MODE_CELL_PX[0] - inset]


def bar_in_panel() -> tuple[float, float, float, float]:
    """The bar's box (x0, y0, x1, y1) in a panel's pixels, without the border's inset."""
    bx, by, bw, bh = crop_box(BAR_PX, FRAME_SHAPE)
    sx, sy = MODE_CELL_PX[0] / bw, MODE_CELL_PX[1] / bh
    x, y, w, h = BAR_PX
    return ((x - bx) * sx - 4, (y - by) * sy - 4, (x + w - bx) * sx - 4, (y + h - by) * sy - 4)


def test_one_panel_per_mode_with_arrows_in_the_objects_colour(modes: ObjectModeShapes, texts: list[str]):
    both = draw_mode_shapes(bar_analysis(modes))
    one = draw_mode_shapes(bar_analysis(first_modes(modes, 1)))
    assert both.dtype == one.dtype == np.uint8
    assert both.shape == (*mode_shapes_size(1, 2)[::-1], 3)
    assert one.shape == (*mode_shapes_size(1, 1)[::-1], 3)
    assert both.shape[1] > one.shape[1]  # a column more for the second mode
    np.testing.assert_array_equal(both, draw_mode_shapes(bar_analysis(modes)))  # the same pixels each time
    x0, y0, x1, y1 = bar_in_panel()
    reach = ARROW_SHARE * MODE_CELL_PX[0] + 4
    for column in (0, 1):
        ink = colour_mask(panel_of(both, column), object_color(1))
        ys, xs = np.nonzero(ink)
        assert ink.sum() > 300, column
        # The arrows and the deformed outline stay on the bar, within an arrow's reach of it.
        assert x0 - reach <= xs.min(), column
        assert xs.max() <= x1 + reach, column
        assert y0 - reach <= ys.min(), column
        assert ys.max() <= y1 + reach, column
        assert x0 < np.median(xs) < x1, column
        assert y0 < np.median(ys) < y1, column
    # Each panel is labelled with the object, the mode's number, f and ζ (or "steady": no decay).
    texts.clear()
    draw_mode_shapes(bar_analysis(modes))
    labels = [t for t in texts if t.startswith("#1  mode ")]
    found = [re.fullmatch(r"#1  mode (\d)   f = (\S+) ± \S+ Hz\n(.*)   shown ×\S+", t) for t in labels]
    assert all(found), labels
    assert [(int(m[1]), round(float(m[2]), 2)) for m in found] == [(1, 11.0), (2, 3.0)], labels
    assert found[0][3] == "steady"
    assert re.fullmatch(r"ζ = 0\.03\d* ± 0\.\d+", found[1][3]), labels


def test_the_panels_magnify_the_shape_to_a_share_of_the_panel(modes: ObjectModeShapes):
    from workers.pipeline.figures.mode_shapes import mode_panels

    [row] = mode_panels(bar_analysis(modes))
    assert [p.number for p in row] == [1, 2]
    for panel in row:
        shown = np.hypot(panel.field[..., 0], panel.field[..., 1])[panel.mask]
        longest = ARROW_SHARE * MODE_CELL_PX[0]
        assert 0.8 * longest < np.percentile(shown, 99) < 1.2 * longest
        assert panel.magnification > 1
        assert f"×{panel.magnification:.3g}" in panel_label(panel)
    bend, sway = row
    # The bend: y displacement of opposite signs at the bar's ends, little x; the sway: x alike everywhere.
    ys, xs = np.nonzero(bend.mask)
    left, right = bend.field[ys[xs.argmin()], xs.min()], bend.field[ys[xs.argmax()], xs.max()]
    assert left[1] * right[1] < 0
    assert abs(left[0]) < 0.2 * abs(left[1])
    assert np.all(sway.field[sway.mask][:, 0] * sway.field[sway.mask][0, 0] > 0)


def test_the_animation_moves_each_panel_and_loops(modes: ObjectModeShapes, tmp_path: Path):
    analysis = bar_analysis(modes)
    frames = mode_animation_frames(analysis)
    assert len(frames) == ANIMATION_FRAMES
    assert 16 <= ANIMATION_FRAMES <= 24
    size = animation_size(*mode_shapes_size(1, 2))
    assert all(f.shape == (size[1], size[0], 3) and f.dtype == np.uint8 for f in frames)
    rest, peak = frames[0], frames[ANIMATION_FRAMES // 4]
    for column in (0, 1):  # every panel moves ...
        assert np.abs(panel_of(rest, column).astype(int) - panel_of(peak, column)).max() > 100, column
    top = panel_origin(0, 0)[1] - 2
    np.testing.assert_array_equal(rest[:top], peak[:top])  # ... under labels that stay put
    # The still page's labels are the animation's.
    np.testing.assert_array_equal(rest[:top], draw_mode_shapes(analysis)[:top])

    path = write_mode_animation(tmp_path / "modes.gif", analysis)
    assert path == tmp_path / "modes.gif"
    assert path.read_bytes()[:6] == b"GIF89a"
    decoded, info = gif_frames(path)
    assert info["loop"] == 0  # loops forever
    assert info["duration"] == FRAME_MS
    assert len(decoded) == ANIMATION_FRAMES
    errors = [np.abs(mine.astype(int) - shown).mean() for mine, shown in zip(frames, decoded, strict=True)]
    assert max(errors) < 10  # one palette, not dithered (the frame here is random colours: the worst case)
    assert max(errors) < min(errors) + 1  # each frame drawn over the last shows what was drawn
    quarter = ANIMATION_FRAMES // 4
    moved = [np.abs(panel_of(f, 0).astype(int) - panel_of(decoded[quarter], 0)).mean() for f in (rest, peak)]
    assert moved[1] < moved[0] / 2
    assert len({f.tobytes() for f in decoded}) > ANIMATION_FRAMES // 2
    assert path.stat().st_size < 300_000
    assert [p.name for p in tmp_path.iterdir()] == ["modes.gif"]  # written atomically, nothing left over


def test_without_modes_both_images_carry_a_note(modes: ObjectModeShapes, tmp_path: Path, texts: list[str]):
    for analysis in (
        bar_analysis(None),
        bar_analysis(first_modes(modes, 0)),
        replace(bar_analysis(None), objects=[], labels=np.zeros(FRAME_SHAPE, np.uint16)),
    ):
        texts.clear()
        image = draw_mode_shapes(analysis)
        assert image.shape == (*mode_shapes_size(0, 0)[::-1], 3)
        assert NO_MODES_NOTE in texts
        assert image.std() > 10  # the frame, dimmed, behind the note
        frames, _ = gif_frames(write_mode_animation(tmp_path / "none.gif", analysis))
        assert len(frames) == 1
        assert frames[0].shape == image.shape


def test_draw_all_writes_both_and_returns_their_names(modes: ObjectModeShapes, tmp_path: Path):
    analysis = bar_analysis(modes)
    names = draw_all(analysis, tmp_path, keys=("mode_animation", "mode_shapes"))
    assert names == {"mode_shapes": "modes.png", "mode_animation": "modes.gif"}  # in ALL_KEYS order
    assert list(ALL_KEYS[-3:]) == ["modes", "mode_shapes", "mode_animation"]
    assert [ARTIFACT_FILES[k] for k in ("mode_shapes", "mode_animation")] == ["modes.png", "modes.gif"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["modes.gif", "modes.png"]
    np.testing.assert_array_equal(decode(tmp_path / "modes.png"), draw_mode_shapes(analysis))
    frames, info = gif_frames(tmp_path / "modes.gif")
    assert len(frames) == ANIMATION_FRAMES
    assert info["loop"] == 0


def test_the_modes_artifact_gives_imaginary_parts_only_for_complex_modes() -> None:
    """The bar's standing modes are real: no ``_shapes_imag``; the same bar with its bending mode made a
    travelling wave (its shape turned by a phase along it) gets them, the complex shape whole."""
    from workers.pipeline.figures.modes_file import COMPLEX_MODE, modes_arrays

    modes = bar_modes()
    assert max(m.complexity for m in modes.found.modes) < COMPLEX_MODE
    arrays = modes_arrays(bar_analysis(modes))
    assert "object_1_shapes" in arrays
    assert "object_1_shapes_imag" not in arrays
    turn = np.exp(1j * np.linspace(0.0, np.pi, len(modes.pixels)))[None, :, None].astype(np.complex64)
    travelling = replace(modes, shapes=(modes.shapes * turn).astype(np.complex64))
    found = replace(
        modes.found, modes=[replace(m, shape=m.shape * turn[0, : len(m.shape)]) for m in modes.found.modes]
    )
    travelling = replace(travelling, found=found)
    assert max(m.complexity for m in found.modes) > COMPLEX_MODE
    arrays = modes_arrays(bar_analysis(travelling))
    real, imag = arrays["object_1_shapes"], arrays["object_1_shapes_imag"]
    assert imag.shape == real.shape
    assert imag.dtype == np.float32
    # The turn changes each pixel's phase, never its magnitude.
    mask = bar_analysis(modes).labels == 1
    whole = np.hypot(modes.frame_shapes(mask), modes.frame_shapes(mask, imaginary=True))
    inside = np.isfinite(whole)
    np.testing.assert_allclose(np.hypot(real, imag)[inside], whole[inside], rtol=1e-3, atol=1e-6)
