"""How the figures of an analysis get drawn and written: the one interface to the pure figures.

:mod:`workers.pipeline.figures` holds the figures as pure functions (an analysis in, pixels out). This
module decides how a process runs them: :func:`draw_all` draws each figure in the calling thread, one
after the other, while one helper thread encodes and writes the previous figure's PNG (encoding and
writing release the GIL; matplotlib does not); the mode animation's frames are drawn the same way, the
helper thread encoding them as a GIF. :func:`warm_up` imports matplotlib in a background thread
where a process starts (the stream worker), so that its first figures do not pay for the import; an
analysis imports it when it draws (:func:`workers.runner.run_analysis`: started beside the measurement,
the import held the interpreter the registration needs).

Drawing in a helper process, forking a child per render or a child forked as the command line starts,
a cache of rendered text and leaving the command line with ``os._exit`` were each measured
(``bench/devices.py``, ``bench/README.md``) to save less than 10 % of a figure a user sees, and removed
(issue 18).
"""

from __future__ import annotations

import threading
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis

#: Every artifact key, in the order :func:`draw_all` writes them: the mask first, then the figures.
ALL_KEYS = (
    "mask",
    "overlay",
    "frequency_map",
    "spectrum",
    "displacement",
    "ringdown",
    "modes",
    "mode_shapes",
    "mode_animation",
)


def draw_all(analysis: Analysis, out_dir: str | Path, keys: Iterable[str] | None = None) -> dict[str, str]:
    """Draw the images ``keys`` of ``analysis`` and write them into ``out_dir``, each file atomically.

    Parameters
    ----------
    analysis : Analysis
    out_dir : path-like
        Existing or new directory; files get the names of
        :data:`workers.pipeline.figures.ARTIFACT_FILES`.
    keys : iterable of str, optional
        Artifact keys among :data:`ALL_KEYS` (default all of them): ``mask`` is the label image
        (``analysis.labels``), ``modes`` the objects' mode shapes
        (:mod:`workers.pipeline.figures.modes_file`), ``mode_animation`` the same shapes as a looping GIF
        (:mod:`workers.pipeline.figures.mode_animation`), the others the figures of
        :data:`workers.pipeline.figures.FIGURES`.

    Returns
    -------
    dict of str to str
        Artifact key -> file name relative to ``out_dir``, in the order of :data:`ALL_KEYS`.

    Raises
    ------
    ValueError
        For a key that is not an artifact; the message lists the keys.
    OSError
        When a file cannot be written (e.g. ``out_dir`` is a file); images already written stay in place.
    """
    from workers.pipeline.figures import ARTIFACT_FILES, FIGURES, PHOTO_FIGURES, write_label_png, write_png
    from workers.pipeline.figures.mode_animation import mode_animation_frames, write_gif
    from workers.pipeline.figures.modes_file import write_modes_npz

    wanted = ALL_KEYS if keys is None else tuple(keys)
    unknown = [k for k in wanted if k not in ARTIFACT_FILES]
    if unknown:
        raise ValueError(f"unknown image key(s) {unknown}: pass some of {list(ALL_KEYS)}")
    ordered = [k for k in ALL_KEYS if k in wanted]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="eigenscope-png") as pool:
        pending: list[Future[Path]] = []
        try:
            for key in ordered:
                path = out / ARTIFACT_FILES[key]
                if key == "mask":
                    pending.append(pool.submit(write_label_png, path, analysis.labels))
                elif key == "modes":
                    pending.append(pool.submit(write_modes_npz, path, analysis))
                elif key == "mode_animation":
                    pending.append(pool.submit(write_gif, path, mode_animation_frames(analysis)))
                else:
                    image = FIGURES[key](analysis)
                    pending.append(pool.submit(write_png, path, image, photo=key in PHOTO_FIGURES))
        finally:
            # Surface the first write error, after letting every submitted write finish.
            errors = [e for e in (f.exception() for f in pending) if e is not None]
    if errors:
        raise errors[0]
    return {key: ARTIFACT_FILES[key] for key in ordered}


def warm_up() -> threading.Thread:
    """Import matplotlib and load its fonts in a background thread.

    Importing matplotlib and its font cache costs about half a second: a process that will draw later
    and has nothing else to do now (the stream worker as it starts) pays it here. Not beside an analysis:
    there it held the interpreter the measurement needs (``eigenscope analyze`` 7 % slower).

    Returns
    -------
    threading.Thread
        Already started (daemon); joining it is optional.
    """

    def load() -> None:
        from workers.pipeline.figures import load_matplotlib

        load_matplotlib()
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(1, 1), dpi=50)
        ax = fig.add_subplot()
        ax.plot([0, 1], [0, 1])
        ax.set_title("warm-up")
        FigureCanvasAgg(fig).draw()

    thread = threading.Thread(target=load, name="render-warm-up", daemon=True)
    thread.start()
    return thread


__all__ = ["ALL_KEYS", "draw_all", "warm_up"]
