"""Help texts of the analysis options ``analyze`` and ``submit`` share, with their units: one wording."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from api_schemas import ForceLog

#: Help of each analysis option, by its parameter name (``--min-frequency-hz`` is ``min_frequency_hz``).
PARAMETER_HELP = {
    "force_n": "force that held the object before its release (step release), N",
    "impulse_ns": "impulse that struck the object, N·s",
    "method": "estimation method: default (signed flow, ring-down fit) or paper (the paper's recipe, kept "
    "for comparison)",
    "flow": "optical flow algorithm (default: the method's)",
    "frames": "analysis window length, frames (default: up to 256, or the window a survey of a longer clip "
    "chooses)",
    "start_frame": "first frame of the window, a frame index (default 0, or the survey's choice)",
    "fps": "true recording frame rate, frames per second (wins over the file's)",
    "fx": "camera focal length along x, pixels (wins over the file's intrinsics)",
    "fy": "camera focal length along y, pixels (wins over the file's intrinsics)",
    "cx": "camera principal point x, pixels (wins over the file's intrinsics)",
    "cy": "camera principal point y, pixels (wins over the file's intrinsics)",
    "depth_scale": "metres per depth unit, m (wins over the file's)",
    "depth_m": "object distance for clips without depth, m",
    "force_topic": "bag topic of the wrist force/torque sensor whose push, hold and release (or strike) is "
    "the excitation (default: the bag's one force topic, if any; --force-n / --impulse-ns override it)",
    "force_log": "CSV or JSON log of the force sensor (columns time_s and fx, fy, fz, or force_n; time 0 = "
    "the clip's first frame): its push, hold and release (or strike) is the excitation",
    "force_log_offset_s": "seconds added to the force log's times: minus the log's time at the clip's first "
    "frame (default 0)",
    "min_frequency_hz": "lowest eigenfrequency searched, Hz (default: two cycles per window)",
    "max_frequency_hz": "highest eigenfrequency searched, Hz (default: 0.98 x the Nyquist frequency, fps/2)",
}


def read_force_log_file(path: str, offset_s: float = 0.0) -> ForceLog:
    """A force log file (CSV or JSON, see :func:`workers.pipeline.clipio.force_log.read_force_log`) as the
    request's :class:`~api_schemas.ForceLog` (its times on the clip's clock).

    Raises
    ------
    FileNotFoundError, IsADirectoryError, PermissionError
        The file cannot be read.
    workers.pipeline.errors.ForceError
        The file is not a force log (the message says what is wrong).
    """
    from pathlib import Path

    from pydantic import ValidationError

    from api_schemas import ForceLog
    from workers.pipeline.clipio.force_log import read_force_log
    from workers.pipeline.errors import ForceError

    file = Path(path)
    series = read_force_log(file.read_bytes(), name=file.name, offset_s=offset_s)
    force = series.force_n
    columns = (
        {"force_n": force[:, 0].tolist()}
        if force.shape[1] == 1
        else {
            "fx": force[:, 0].tolist(),
            "fy": force[:, 1].tolist(),
            "fz": force[:, 2].tolist(),
        }
    )
    try:
        return ForceLog(time_s=series.times_s.tolist(), **columns, frame_id=series.frame_id, name=file.name)
    except ValidationError as exc:  # what a request may carry: at most MAX_FORCE_SAMPLES samples
        error = exc.errors()[0]
        where = ".".join(str(part) for part in error["loc"])
        raise ForceError(f"the force log {file.name}: {where}: {error['msg']}") from None
