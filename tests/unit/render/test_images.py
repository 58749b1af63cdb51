"""Every image of an analysis: decodes, has its stated size, is not blank, and tells the truth.

Sizes come from the public size functions (``display_size``, ``frequency_map_size``, ``PLOT_SIZE_PX``,
``panel_figure_size``, ``mode_shapes_size``), whose values are also pinned here for a 640x480 frame.
"""

from __future__ import annotations

import os
import stat
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.unit.render.conftest import Analysed
from tests.unit.render.helpers import (
    assert_not_blank,
    colour_mask,
    decode,
    gif_frames,
    mode_panels_of,
    size_of,
)
from workers.drawing import draw_all
from workers.pipeline.analysis import Analysis
from workers.pipeline.figures import (
    ARTIFACT_FILES,
    NO_MODES_NOTE,
    NO_OBJECT_NOTE,
    PLOT_SIZE_PX,
    display_size,
    frequency_map_size,
    mode_shapes_size,
    object_color,
    panel_figure_size,
    write_displacement_png,
    write_frequency_map_png,
    write_label_png,
    write_mode_animation,
    write_mode_shapes_png,
    write_overlay_png,
    write_ringdown_png,
    write_spectrum_png,
)
from workers.pipeline.figures.mode_animation import ANIMATION_FRAMES, animation_size
from workers.pipeline.figures.mode_shapes import panel_origin


def expected_sizes(analysis: Analysis) -> dict[str, tuple[int, int]]:
    h, w = analysis.labels.shape
    n = len(analysis.objects)
    return {
        "mask": (w, h),
        "overlay": display_size(w, h),
        "frequency_map": frequency_map_size(w, h),
        "spectrum": PLOT_SIZE_PX,
        "displacement": panel_figure_size(n),
        "ringdown": panel_figure_size(n),
        "mode_shapes": mode_shapes_size(*mode_panels_of(analysis)),
    }


def check_animation(analysis: Analysis, path: Path) -> list[np.ndarray]:
    """The mode animation at ``path``: a looping GIF of modes.png's layout (shrunk to its budget), one
    cycle of frames that differ when an object has modes, a still note when none has."""
    frames, info = gif_frames(path)
    assert info["loop"] == 0
    size = animation_size(*expected_sizes(analysis)["mode_shapes"])
    assert all(size_of(f) == size for f in frames)
    if mode_panels_of(analysis)[0]:
        assert len(frames) == ANIMATION_FRAMES
        assert len({f.tobytes() for f in frames}) > ANIMATION_FRAMES // 2
    else:
        assert len(frames) == 1
    assert path.stat().st_size < 400_000
    return frames


def check_all(analysis: Analysis, out: Path) -> dict[str, np.ndarray]:
    names = draw_all(analysis, out)
    assert names == ARTIFACT_FILES
    images = {}
    shapes = np.load(out / names.pop("modes"))  # the mode shapes: data, not an image
    check_animation(analysis, out / names.pop("mode_animation"))  # an animation, not a still image
    for obj in analysis.objects:
        if obj.modes is not None and obj.modes.found.modes:
            assert shapes[f"object_{obj.id}_shapes"].shape == (
                len(obj.modes.found.modes),
                *analysis.labels.shape,
                2,
            )
    for key, name in names.items():
        img = decode(out / name)
        assert size_of(img) == expected_sizes(analysis)[key], key
        if key != "mask":
            assert_not_blank(img, name)
        images[key] = img
    mask = images["mask"]
    assert mask.ndim == 2
    np.testing.assert_array_equal(mask, analysis.labels)
    return images


def test_sizes_for_a_vga_frame_are_the_documented_ones():
    assert display_size(640, 480) == (640, 480)
    assert frequency_map_size(640, 480) == (790, 530)
    assert PLOT_SIZE_PX == (1000, 600)
    assert panel_figure_size(0) == panel_figure_size(1) == panel_figure_size(2) == (1000, 600)
    assert panel_figure_size(3) == (1000, 850)
    # Small frames are upscaled by an integer factor for legible labels; wide ones shrunk.
    assert display_size(320, 240) == (640, 480)
    assert display_size(160, 120) == (640, 480)
    assert display_size(1920, 1080) == (1280, 720)
    # One 320 x 240 panel per mode under its label, one row per object; the animation within 360 000 px.
    assert mode_shapes_size(0, 0) == mode_shapes_size(1, 1) == (340, 320)
    assert mode_shapes_size(2, 3) == (1000, 610)
    assert animation_size(340, 320) == (340, 320)
    assert animation_size(1000, 610) == (768, 468)


def test_one_object_every_image(one_object: Analysed, tmp_path: Path, texts: list[str]):
    a = one_object.analysis
    assert len(a.objects) == 1
    images = check_all(a, tmp_path)
    obj = a.objects[0]
    # The overlay labels the object with f, k and m, with units and uncertainties.
    label = next(t for t in texts if t.startswith("#1  f = "))
    assert "Hz" in label
    assert "N/m" in label
    assert "kg" in label
    assert label.count("±") == 3, label
    # Its outline is drawn in its colour around its mask.
    x, y, w, h = obj.bbox_px
    outline = colour_mask(images["overlay"], object_color(1))
    assert outline[y - 4 : y + h + 4, x - 4 : x + w + 4].sum() > 2 * (w + h)
    # The displacement is in millimetres (the amplitude in metres is known) with the fit and release.
    assert "displacement (mm)" in texts
    assert "damped-oscillation fit" in texts
    assert any(t.startswith("release ") for t in texts)
    # Axes are labelled with units.
    for axis_label in ("frequency (Hz)", "time (s)", "dominant frequency (Hz)"):
        assert axis_label in texts
    # The mode shapes: the object's mode, labelled, drawn in its colour in its panel.
    assert obj.modes is not None
    assert mode_panels_of(a) == (1, len(obj.modes.found.modes))
    assert any(t.startswith("#1  mode 1   f = ") for t in texts)
    x, y = panel_origin(0, 0)
    panel = images["mode_shapes"][y + 4 : y + 236, x + 4 : x + 316]
    assert colour_mask(panel, object_color(1)).sum() > 300


def test_mask_is_a_palette_png_any_viewer_shows_in_colour(tmp_path: Path):
    from PIL import Image

    labels = np.zeros((40, 60), np.uint16)
    labels[5:15, 5:25] = 1
    labels[20:35, 30:55] = 2
    path = write_label_png(tmp_path / "mask.png", labels)
    with Image.open(path) as img:
        assert img.mode == "P"
        np.testing.assert_array_equal(np.asarray(img), labels)  # the pixel values are the label ids
        palette = img.getpalette()
    assert palette is not None
    assert palette[:3] == [0, 0, 0]
    assert tuple(palette[3:6]) == object_color(1)
    assert tuple(palette[6:9]) == object_color(2)
    # What a viewer shows: OpenCV (like any viewer) expands the palette to colours.
    import cv2

    shown = cv2.cvtColor(cv2.imread(str(path), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert tuple(int(v) for v in shown[10, 10]) == object_color(1)
    assert tuple(int(v) for v in shown[30, 40]) == object_color(2)
    assert tuple(int(v) for v in shown[0, 0]) == (0, 0, 0)


def test_mask_of_more_than_255_objects_stays_exact_in_16_bits(tmp_path: Path):
    import cv2

    labels = np.arange(40 * 60, dtype=np.uint16).reshape(40, 60) % 700
    path = write_label_png(tmp_path / "mask.png", labels)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, labels)


def test_files_are_written_atomically_and_readable(one_object: Analysed, tmp_path: Path):
    out = tmp_path / "new" / "dir"
    names = draw_all(one_object.analysis, out)
    assert sorted(p.name for p in out.iterdir()) == sorted(names.values())  # no temporary leftovers
    for name in names.values():
        mode = stat.S_IMODE(os.stat(out / name).st_mode)
        assert mode & 0o444 == 0o444, f"{name} is not readable by all: {oct(mode)}"


def test_each_image_has_its_own_writer(one_object: Analysed, tmp_path: Path):
    a = one_object.analysis
    sizes = expected_sizes(a)
    for key, writer in {
        "overlay": write_overlay_png,
        "frequency_map": write_frequency_map_png,
        "spectrum": write_spectrum_png,
        "displacement": write_displacement_png,
        "ringdown": write_ringdown_png,
        "mode_shapes": write_mode_shapes_png,
    }.items():
        path = writer(tmp_path / f"{key}.png", a)
        assert path == tmp_path / f"{key}.png"
        assert size_of(decode(path)) == sizes[key]
    path = write_mode_animation(tmp_path / "modes.gif", a)
    assert path == tmp_path / "modes.gif"
    check_animation(a, path)


def test_two_objects_keep_their_own_colour_in_every_image(two_objects: Analysed, tmp_path: Path):
    a = two_objects.analysis
    assert [round(o.eigenfrequency_hz) for o in a.objects] == [4, 7]
    c1, c2 = object_color(1), object_color(2)
    assert max(abs(p - q) for p, q in zip(c1, c2, strict=True)) > 60, "colours must be distinct"
    images = check_all(a, tmp_path)

    # Overlay: each colour outlines its own object and not the other.
    for oid, other in ((1, 2), (2, 1)):
        ink = colour_mask(images["overlay"], object_color(oid))
        x, y, w, h = a.objects[oid - 1].bbox_px
        ox, oy, ow, oh = a.objects[other - 1].bbox_px
        assert ink[y - 4 : y + h + 4, x - 4 : x + w + 4].sum() > 2 * (w + h), oid
        assert ink[oy + 8 : oy + oh - 8, ox + 8 : ox + ow - 8].sum() == 0, oid

    # Spectrum: the 4 Hz marker (colour 1) lies left of the 7 Hz one (colour 2).
    s1 = colour_mask(images["spectrum"], c1)
    s2 = colour_mask(images["spectrum"], c2)
    assert s1.sum() > 200
    assert s2.sum() > 200
    assert np.median(np.nonzero(s1)[1]) + 100 < np.median(np.nonzero(s2)[1])

    # Displacement and ring-down: object 1 is the top panel, object 2 the bottom one.
    for key in ("displacement", "ringdown"):
        img = images[key]
        d1, d2 = colour_mask(img, c1), colour_mask(img, c2)
        assert d1.sum() > 200, key
        assert d2.sum() > 200, key
        mid = img.shape[0] / 2
        assert np.median(np.nonzero(d1)[0]) < mid < np.median(np.nonzero(d2)[0]), key

    # Frequency map: both outlines and both colour-bar marks.
    for colour in (c1, c2):
        assert colour_mask(images["frequency_map"], colour).sum() > 200

    # Mode shapes: object 1's modes in the top row, object 2's in the one below, each in its colour.
    assert mode_panels_of(a)[0] == 2
    for row, colour in enumerate((c1, c2)):
        x, y = panel_origin(row, 0)
        panel = images["mode_shapes"][y + 4 : y + 236, x + 4 : x + 316]
        assert colour_mask(panel, colour).sum() > 200, row
        assert colour_mask(panel, (c2, c1)[row]).sum() == 0, row


def test_no_object_still_renders_every_image(no_object: Analysed, tmp_path: Path, texts: list[str]):
    a = no_object.analysis
    assert a.objects == []
    images = check_all(a, tmp_path)
    notes = [t for t in texts if t.startswith(NO_OBJECT_NOTE)]
    # overlay, frequency map, spectrum, displacement and ring-down each carry the note
    assert len(notes) >= 5, notes
    # the mode shapes (and their animation, drawn from the same page) theirs
    assert texts.count(NO_MODES_NOTE) >= 2
    # The overlay's note is a light box in the middle of the frame.
    h, w = images["overlay"].shape[:2]
    centre = images["overlay"][h // 2 - 10 : h // 2 + 10, w // 4 : 3 * w // 4]
    assert (centre.min(axis=2) > 200).mean() > 0.5


def test_paper_method_renders_without_displacement_series(paper: Analysed, tmp_path: Path, texts: list[str]):
    a = paper.analysis
    assert a.method == "paper"
    assert a.objects
    assert all(o.displacement_px is None for o in a.objects)
    check_all(a, tmp_path)
    assert sum("no displacement series" in t for t in texts) >= 2  # displacement and ring-down


def test_small_frames_are_upscaled_and_unknowns_say_so(small: Analysed, tmp_path: Path, texts: list[str]):
    a = small.analysis
    assert a.labels.shape == (240, 320)
    images = check_all(a, tmp_path)
    assert size_of(images["overlay"]) == (640, 480)
    label = next(t for t in texts if t.startswith("#1  f = "))
    assert "k = n/a" in label
    assert "m = n/a" in label
    # With depth the displacement is in millimetres; without metres, in pixels.
    assert "displacement (mm)" in texts
    texts.clear()
    no_metres = replace(
        a, objects=[replace(o, amplitude_m=None, amplitude_uncertainty_m=None) for o in a.objects]
    )
    write_displacement_png(tmp_path / "px.png", no_metres)
    assert "displacement (px)" in texts


def test_rendering_is_thread_safe_and_deterministic(two_objects: Analysed, tmp_path: Path):
    a = two_objects.analysis
    drawn = draw_all(a, tmp_path / "ref")
    reference = {k: decode(tmp_path / "ref" / v) for k, v in drawn.items() if v.endswith(".png")}
    animation = (tmp_path / "ref" / ARTIFACT_FILES["mode_animation"]).read_bytes()
    errors: list[BaseException] = []

    def work(i: int) -> None:
        try:
            draw_all(a, tmp_path / f"t{i}")
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors, errors
    for i in range(3):
        for key in reference:
            name = ARTIFACT_FILES[key]
            np.testing.assert_array_equal(decode(tmp_path / f"t{i}" / name), reference[key], err_msg=key)
        assert (tmp_path / f"t{i}" / ARTIFACT_FILES["mode_animation"]).read_bytes() == animation


def test_write_errors_surface(one_object: Analysed, tmp_path: Path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(FileExistsError):
        draw_all(one_object.analysis, blocker)


def test_the_spectrum_marks_the_harmonic_it_found(one_object: Analysed, texts: list[str]):
    """A peak rejected as an overtone of an object is marked as that object's harmonic, with its
    frequency, in the object's colour; not as an artefact."""
    from workers.pipeline.figures import FIGURES
    from workers.pipeline.model import RejectedPeak

    a = one_object.analysis
    f0 = a.objects[0].eigenfrequency_hz
    harmonic = RejectedPeak(2 * f0, f"{2 * f0:.4g} Hz is overtone 2 of the object", "harmonic")
    flicker = RejectedPeak(11.0, "rows flicker", "illumination_flicker")
    plain = FIGURES["spectrum"](replace(a, rejected_peaks=[flicker]))
    marked = FIGURES["spectrum"](replace(a, rejected_peaks=[harmonic, flicker]))
    assert f"harmonic of #1 found at {2 * f0:.4g} Hz" in texts
    assert "rejected artefact peak" in texts  # the flicker still is one
    assert colour_mask(marked, object_color(1)).sum() > colour_mask(plain, object_color(1)).sum()
