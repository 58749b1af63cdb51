"""The ``modes`` artifact: every object's mode shapes and frequencies as a NumPy ``.npz`` archive.

Per object ``i`` (its id in ``mask.png``) with at least one mode:

- ``object_<i>_shapes``: float32, shape (modes, H, W, 2): each mode's displacement shape (x, y) in input
  pixels over the whole frame, real (phase-aligned), NaN outside the object;
- ``object_<i>_frequencies_hz``: float64, shape (modes,);
- ``object_<i>_damping_ratio``: float64, shape (modes,), NaN where a mode does not decay;
- ``object_<i>_energy_share``: float64, shape (modes,);
- ``object_<i>_mac``: float64, shape (modes, modes), the MAC between the shapes;
- ``object_<i>_shapes_imag``: float32, same layout as ``_shapes``, only when a mode is complex (its
  :attr:`~workers.pipeline.modes.Mode.complexity` above :data:`COMPLEX_MODE`: heavy or non-proportional
  damping, a travelling wave): the imaginary parts, so that the complex shape is ``shapes + 1j * imag``;
- ``object_<i>_shapes_m``: float32, shape (modes, H, W, 3), where depth (or a given distance) and the
  camera's intrinsics allow: the same displacement in metres, x and y across the line of sight and z along
  it (positive away from the camera; NaN without a depth series), NaN off the object or without a depth
  reading.

The modes are in the order of the result's ``objects[].modes``.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from workers.pipeline._files import write_atomically

if TYPE_CHECKING:
    from workers.pipeline.model import Analysis


#: A mode whose shape's imaginary part holds more than this share of its energy is complex: its
#: imaginary parts are written too (a lightly damped standing mode's is noise, well below it).
COMPLEX_MODE = 0.1


def modes_arrays(analysis: Analysis) -> dict[str, NDArray[np.generic]]:
    """The arrays of the ``modes`` artifact (see the module docstring) of ``analysis``."""
    out: dict[str, NDArray[np.generic]] = {}
    for obj in analysis.objects:
        if obj.modes is None or not obj.modes.found.modes or obj.modes.roi is None:
            continue
        modes = obj.modes.found.modes
        key = f"object_{obj.id}"
        out[f"{key}_shapes"] = obj.modes.frame_shapes(analysis.labels == obj.id)
        out[f"{key}_frequencies_hz"] = np.array([m.frequency_hz for m in modes], np.float64)
        damping = [np.nan if m.damping_ratio is None else m.damping_ratio for m in modes]
        out[f"{key}_damping_ratio"] = np.array(damping, np.float64)
        out[f"{key}_energy_share"] = np.array([m.energy_share for m in modes], np.float64)
        out[f"{key}_mac"] = np.asarray(obj.modes.found.mac, np.float64)
        if any(m.complexity > COMPLEX_MODE for m in modes):
            out[f"{key}_shapes_imag"] = obj.modes.frame_shapes(analysis.labels == obj.id, imaginary=True)
        metres = obj.modes.frame_shapes_m(analysis.labels == obj.id)
        if metres is not None:
            out[f"{key}_shapes_m"] = metres
    return out


def write_modes_npz(path: str | Path, analysis: Analysis) -> Path:
    """Write the ``modes`` artifact of ``analysis`` to ``path`` (compressed, atomically)."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **modes_arrays(analysis))  # type: ignore[arg-type]
    return write_atomically(path, buffer.getvalue())


__all__ = ["COMPLEX_MODE", "modes_arrays", "write_modes_npz"]
