"""Help texts of the analysis options ``analyze`` and ``submit`` share, with their units: one wording."""

from __future__ import annotations

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
    "min_frequency_hz": "lowest eigenfrequency searched, Hz (default: two cycles per window)",
    "max_frequency_hz": "highest eigenfrequency searched, Hz (default: 0.98 x the Nyquist frequency, fps/2)",
}
