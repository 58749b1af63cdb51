"""The figures as pure functions: an analysis in, an RGB array out, the same pixels every time, no files.

``draw_all`` writes exactly these pixels (PNG is lossless), so the image tests in test_images.py hold for
the arrays too.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tests.unit.render.conftest import Analysed
from tests.unit.render.helpers import decode, mode_panels_of
from workers.drawing import ALL_KEYS, draw_all
from workers.pipeline.figures import (
    ARTIFACT_FILES,
    FIGURES,
    PLOT_SIZE_PX,
    display_size,
    frequency_map_size,
    mode_shapes_size,
    panel_figure_size,
)


def test_every_artifact_but_the_mask_the_mode_shapes_and_their_animation_is_a_figure():
    assert list(FIGURES) == [k for k in ARTIFACT_FILES if k not in ("mask", "modes", "mode_animation")]
    assert tuple(ARTIFACT_FILES) == ALL_KEYS


def test_figures_are_rgb_arrays_of_their_stated_size_and_deterministic(
    two_objects: Analysed, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    a = two_objects.analysis
    h, w = a.labels.shape
    sizes = {
        "overlay": display_size(w, h),
        "frequency_map": frequency_map_size(w, h),
        "spectrum": PLOT_SIZE_PX,
        "displacement": panel_figure_size(len(a.objects)),
        "ringdown": panel_figure_size(len(a.objects)),
        "mode_shapes": mode_shapes_size(*mode_panels_of(a)),
    }
    monkeypatch.chdir(tmp_path)
    for key, draw in FIGURES.items():
        first, again = draw(a), draw(a)
        assert first.dtype == np.uint8, key
        assert first.shape == (sizes[key][1], sizes[key][0], 3), key
        assert first.std() > 5, f"{key} is blank"
        np.testing.assert_array_equal(first, again, err_msg=key)
    assert os.listdir(tmp_path) == [], "drawing a figure wrote a file"


def test_draw_all_writes_the_figures_pixels(one_object: Analysed, tmp_path: Path):
    a = one_object.analysis
    names = draw_all(a, tmp_path, keys=("spectrum", "mask"))
    assert names == {"mask": "mask.png", "spectrum": "spectrum.png"}  # in ALL_KEYS order
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mask.png", "spectrum.png"]
    np.testing.assert_array_equal(decode(tmp_path / "spectrum.png"), FIGURES["spectrum"](a))


def test_draw_all_refuses_an_unknown_key_and_names_the_known_ones(one_object: Analysed, tmp_path: Path):
    with pytest.raises(ValueError, match="overlay"):
        draw_all(one_object.analysis, tmp_path, keys=("overlay", "histogram"))
    assert not any(tmp_path.iterdir())
