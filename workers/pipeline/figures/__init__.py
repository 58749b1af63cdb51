"""The images of a result, as pure functions: an :class:`~workers.pipeline.model.Analysis` in, pixels out.

Each figure is a function ``draw_<key>(analysis) -> ndarray of uint8, shape (H, W, 3)`` in a module of its
own; :data:`FIGURES` lists them by artifact key, in the order they are written. None of them writes a
file, starts a thread or keeps state between calls: test them on arrays. :mod:`~workers.pipeline.figures.png`
encodes pixels (and the label mask) as PNG files, written atomically; *how* a process draws them all
(this process, threads, order) is :func:`workers.drawing.draw_all`'s business, outside the pure pipeline.

- :mod:`~workers.pipeline.figures.style` -- sizes, the objects' palette, number formatting;
- :mod:`~workers.pipeline.figures._axes` -- matplotlib helpers shared by the figures;
- :mod:`~workers.pipeline.figures.overlay`, :mod:`~workers.pipeline.figures.frequency_map`,
  :mod:`~workers.pipeline.figures.spectrum`, :mod:`~workers.pipeline.figures.displacement`,
  :mod:`~workers.pipeline.figures.ringdown`, :mod:`~workers.pipeline.figures.mode_shapes` -- one figure
  each;
- :mod:`~workers.pipeline.figures.mode_animation` -- the mode shapes as a looping GIF (frames as arrays,
  and their writer);
- :mod:`~workers.pipeline.figures.modes_file` -- the mode shapes as data (``.npz``);
- :mod:`~workers.pipeline.figures.png` -- PNG writing of figures and of the label mask.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.figures._axes import load_matplotlib
from workers.pipeline.figures.displacement import draw_displacement
from workers.pipeline.figures.frequency_map import draw_frequency_map
from workers.pipeline.figures.mode_animation import mode_animation_frames, write_gif, write_mode_animation
from workers.pipeline.figures.mode_shapes import draw_mode_shapes
from workers.pipeline.figures.overlay import draw_overlay
from workers.pipeline.figures.png import PHOTO_FIGURES, _writer, encode_png, write_label_png, write_png
from workers.pipeline.figures.ringdown import draw_ringdown, ringdown_spectrogram
from workers.pipeline.figures.spectrum import draw_spectrum
from workers.pipeline.figures.style import (
    ARTIFACT_FILES,
    DPI,
    FREQUENCY_CMAP,
    MAP_MARGIN_PX,
    MAX_ANIMATION_PIXELS,
    MAX_DISPLAY_WIDTH_PX,
    MIN_DISPLAY_PX,
    MODE_CELL_PX,
    NO_MODES_NOTE,
    NO_OBJECT_NOTE,
    PANEL_HEIGHT_PX,
    PLOT_SIZE_PX,
    SPECTROGRAM_CMAP,
    SPECTROGRAM_RANGE_DB,
    display_scale,
    display_size,
    format_quantity,
    frequency_map_size,
    mode_shapes_size,
    object_color,
    object_label,
    panel_figure_size,
)

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis

#: Artifact key -> the figure's pure function (the mask is the analysis's ``labels``, written by
#: :func:`write_label_png`; ``modes`` and ``mode_animation`` are no single image: see
#: :func:`workers.drawing.draw_all`).
FIGURES: dict[str, Callable[[Analysis], NDArray[np.uint8]]] = {
    "overlay": draw_overlay,
    "frequency_map": draw_frequency_map,
    "spectrum": draw_spectrum,
    "displacement": draw_displacement,
    "ringdown": draw_ringdown,
    "mode_shapes": draw_mode_shapes,
}

write_overlay_png = _writer("overlay", draw_overlay)
write_frequency_map_png = _writer("frequency_map", draw_frequency_map)
write_spectrum_png = _writer("spectrum", draw_spectrum)
write_displacement_png = _writer("displacement", draw_displacement)
write_ringdown_png = _writer("ringdown", draw_ringdown)
write_mode_shapes_png = _writer("mode_shapes", draw_mode_shapes)

#: Artifact key -> the function that draws and writes it (``writer(path, analysis) -> Path``).
IMAGE_WRITERS: dict[str, Callable[[str | Path, Analysis], Path]] = {
    "overlay": write_overlay_png,
    "frequency_map": write_frequency_map_png,
    "spectrum": write_spectrum_png,
    "displacement": write_displacement_png,
    "ringdown": write_ringdown_png,
    "mode_shapes": write_mode_shapes_png,
    "mode_animation": write_mode_animation,
}

__all__ = [
    "ARTIFACT_FILES",
    "DPI",
    "FIGURES",
    "FREQUENCY_CMAP",
    "IMAGE_WRITERS",
    "MAP_MARGIN_PX",
    "MAX_ANIMATION_PIXELS",
    "MAX_DISPLAY_WIDTH_PX",
    "MIN_DISPLAY_PX",
    "MODE_CELL_PX",
    "NO_MODES_NOTE",
    "NO_OBJECT_NOTE",
    "PANEL_HEIGHT_PX",
    "PHOTO_FIGURES",
    "PLOT_SIZE_PX",
    "SPECTROGRAM_CMAP",
    "SPECTROGRAM_RANGE_DB",
    "display_scale",
    "display_size",
    "draw_displacement",
    "draw_frequency_map",
    "draw_mode_shapes",
    "draw_overlay",
    "draw_ringdown",
    "draw_spectrum",
    "encode_png",
    "format_quantity",
    "frequency_map_size",
    "load_matplotlib",
    "mode_animation_frames",
    "mode_shapes_size",
    "object_color",
    "object_label",
    "panel_figure_size",
    "ringdown_spectrogram",
    "write_displacement_png",
    "write_frequency_map_png",
    "write_gif",
    "write_label_png",
    "write_mode_animation",
    "write_mode_shapes_png",
    "write_overlay_png",
    "write_png",
    "write_ringdown_png",
    "write_spectrum_png",
]
