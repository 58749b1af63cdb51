"""Rendered scenes of the classes real footage showed, and still scenes for the null corpus, with the
codecs real cameras use.

Real cameras compress (H.264, MPEG-4 part 2, 1-2 Mbit/s at 640 x 480, a keyframe every 12-30 frames) and
real objects are often small; :func:`encode` puts a rendered clip through such a codec. Each factory here
gives a :class:`~workers.pipeline.synth.Scene` with its ground truth:

- :func:`thin_bar`: a plain bar a few per cent of the picture wide vibrating a fraction of a pixel on a
  shaker, in front of a flat, faintly shaded wall (action-camera footage of a small object);
- :func:`drumhead`: a surface filling the frame vibrating along the line of sight under mains-flicker
  lighting (a scene-filling surface with flicker);
- :func:`wheel`: a textured wheel turning at a steady rate (its rate, not its marks' passing, is the
  motion's fundamental);
- :func:`fork_and_motor`: a struck fork ringing down beside a motor's steady vibration at a higher
  frequency (an object in a narrowed band);
- :func:`spring_near_comb`: a spring whose frequency lies near a multiple of the keyframe rate;
- :func:`still`: nothing vibrates (textured or flat, with sensor noise): the null corpus;
- :data:`REAL_STILL_CROPS` and :class:`ColumnCrop`: still parts of the shared real clips (the flat
  background beside the forks), the null corpus's real part.

Used by the accuracy tier (tests/accuracy/pipeline/test_real_world_classes.py, test_compressed_footage.py,
test_real_footage.py) and by ``bench/null_corpus.py``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from workers.pipeline.clipio.types import ClipInfo, ClipReader, ClosingReader, Frame
from workers.pipeline.clipio.writers import write_compressed
from workers.pipeline.synth import Scene, SceneObject, render

Codec = Literal["libx264", "mpeg4"]

#: The codecs and settings of phones and action cameras: (codec, bits per second, keyframe every).
CAMERA_CODECS: tuple[tuple[Codec, int, int], ...] = (
    ("mpeg4", 1_200_000, 12),
    ("libx264", 1_500_000, 15),
    ("libx264", 2_000_000, 30),
    ("mpeg4", 1_000_000, 30),
)


def encode(scene: Scene, path: Path, *, codec: Codec, bit_rate: int, keyframe_every: int) -> Path:
    """Render ``scene`` and encode its colour frames (no depth) as a camera would."""
    clip = render(scene)
    return write_compressed(
        path, clip.rgb, fps=scene.fps, codec=codec, bit_rate=bit_rate, keyframe_every=keyframe_every
    )


def _pixels_to_metres(pixels: float, depth_m: float, width: int) -> float:
    focal = 525.0 * width / 640.0
    return pixels * depth_m / focal


def thin_bar(
    *,
    fps: float = 240.0,
    frequency_hz: float = 37.0,
    amplitude_px: float = 0.2,
    frames: int = 256,
    seed: int = 1,
) -> Scene:
    """A plain bar 7 x 264 px (0.6 % of a 640 x 480 picture) in steady vibration across itself,
    ``amplitude_px`` peak, in front of a flat wall shaded by a few grey levels."""
    depth = 1.0
    bar = SceneObject(
        center_px=(352.0, 240.0),
        size_px=(7.0, 264.0),
        texture="flat",
        depth_m=depth,
        frequency_hz=frequency_hz,
        excitation="steady",
        steady_amplitude_m=_pixels_to_metres(amplitude_px, depth, 640),
        direction=(1.0, 0.0, 0.0),
    )
    return Scene(frames=frames, fps=fps, objects=(bar,), background="shaded", rgb_noise=1.5, seed=seed)


def drumhead(
    *,
    fps: float = 1900.0,
    frequency_hz: float = 77.0,
    flicker_hz: float = 100.0,
    frames: int = 400,
    seed: int = 5,
) -> Scene:
    """A textured surface filling the frame ringing along the line of sight (struck), lit by lamps
    flickering at ``flicker_hz`` with a rolling shutter."""
    surface = SceneObject(
        center_px=(320.0, 240.0),
        size_px=(700.0, 540.0),
        depth_m=1.0,
        frequency_hz=frequency_hz,
        damping_ratio=0.01,
        mass_kg=0.05,
        excitation="impulse",
        impulse_ns=0.04,
        direction=(0.0, 0.0, 1.0),
    )
    return Scene(
        frames=frames,
        fps=fps,
        objects=(surface,),
        flicker=0.02,
        flicker_hz=flicker_hz,
        flicker_rolling_px=960.0,
        seed=seed,
    )


def wheel(*, fps: float = 300.0, turns_per_s: float = 3.62, frames: int = 900, seed: int = 4) -> Scene:
    """A wheel 240 px across with two spokes' worth of texture (its marks pass every point twice a turn,
    so its second harmonic is its strongest line) and a scuff breaking the symmetry, turning at
    ``turns_per_s`` about an axle that wobbles by a tenth of a millimetre once a turn."""
    disc = SceneObject(
        center_px=(320.0, 240.0),
        size_px=(240.0, 240.0),
        shape="ellipse",
        spin_hz=turns_per_s,
        spin_symmetry=2,
        spin_mark=0.15,
        frequency_hz=turns_per_s,
        excitation="steady",
        steady_amplitude_m=0.0001,
        direction=(1.0, 0.0, 0.0),
    )
    return Scene(frames=frames, fps=fps, objects=(disc,), seed=seed)


def fork_and_motor(
    *, fps: float = 1000.0, fork_hz: float = 32.0, motor_hz: float = 53.5, frames: int = 1000, seed: int = 6
) -> Scene:
    """A struck fork (a bar ringing down at ``fork_hz``) and, beside it, a motor housing in steady
    vibration at ``motor_hz``, weaker."""
    fork = SceneObject(
        center_px=(200.0, 240.0),
        size_px=(24.0, 300.0),
        frequency_hz=fork_hz,
        damping_ratio=0.002,
        mass_kg=0.05,
        excitation="impulse",
        impulse_ns=0.01,
    )
    motor = SceneObject(
        center_px=(440.0, 260.0),
        size_px=(160.0, 120.0),
        frequency_hz=motor_hz,
        excitation="steady",
        steady_amplitude_m=_pixels_to_metres(0.3, 1.0, 640),
    )
    return Scene(frames=frames, fps=fps, objects=(fork, motor), seed=seed)


def spring_near_comb(
    *, fps: float = 30.0, frequency_hz: float = 7.86, frames: int = 128, seed: int = 3
) -> Scene:
    """A spring whose damped frequency (``frequency_hz``) lies 5 % from the third multiple of a 12-frame
    keyframe rate at 30 fps (7.5 Hz)."""
    zeta = 0.03
    spring = SceneObject(frequency_hz=frequency_hz / math.sqrt(1 - zeta**2), damping_ratio=zeta)
    return Scene(frames=frames, fps=fps, objects=(spring,), seed=seed)


@dataclass(frozen=True)
class StillScene:
    """A scene of the null corpus and the codec it goes through."""

    name: str
    scene: Scene
    codec: Codec
    bit_rate: int
    keyframe_every: int


def still_corpus(
    *, frames_per_second: tuple[float, ...] = (30.0, 60.0, 240.0), round_index: int = 0
) -> Iterator[StillScene]:
    """Still scenes, textured and flat, at several rates and noise levels, each through one of
    :data:`CAMERA_CODECS` in turn: the null corpus (nothing vibrates). Each ``round_index`` gives the same
    scenes with other seeds (round 0 is the corpus the tests use)."""
    i = 0
    for background in ("noise", "shaded"):
        for fps in frames_per_second:
            for noise in (1.0, 2.5):
                codec, bit_rate, gop = CAMERA_CODECS[i % len(CAMERA_CODECS)]
                suffix = f"-r{round_index}" if round_index else ""
                yield StillScene(
                    f"still-{background}-{fps:g}fps-noise{noise:g}-{codec}-{gop}{suffix}",
                    still(background=background, fps=fps, rgb_noise=noise, seed=100 + 1000 * round_index + i),
                    codec,
                    bit_rate,
                    gop,
                )
                i += 1


def still(
    *,
    background: Literal["noise", "shaded"] = "noise",
    fps: float = 30.0,
    rgb_noise: float = 2.0,
    seed: int = 0,
) -> Scene:
    """Nothing moves: a textured object at rest in front of a textured wall, or a flat wall alone."""
    frames = {30.0: 128, 60.0: 192}.get(fps, 256)
    rest = SceneObject(
        center_px=(300.0, 250.0),
        size_px=(150.0, 120.0) if background == "noise" else (4.0, 4.0),
        texture="noise" if background == "noise" else "flat",
        excitation="steady",
        steady_amplitude_m=0.0,
    )
    return Scene(
        frames=frames, fps=fps, objects=(rest,), background=background, rgb_noise=rgb_noise, seed=seed
    )


#: Still parts of the shared fork clips (``../shared/data/real/tuning-forks``): (fork Hz, fps, x0, x1),
#: columns ``[x0, x1)`` of the flat background beside the forks, holding the camera's sensor and codec
#: noise but nothing that vibrates.
REAL_STILL_CROPS = [
    (32, 1000, 430, 640),
    (32, 1000, 0, 240),
    (64, 250, 430, 640),
    (64, 250, 0, 240),
    (128, 500, 430, 640),
]


class ColumnCrop(ClosingReader):
    """Columns ``[x0, x1)`` of another reader's frames, without depth (a still part of a real clip)."""

    def __init__(self, inner: ClipReader, x0: int, x1: int) -> None:
        self._inner, self._x0, self._x1 = inner, x0, x1
        self._info = dataclasses.replace(inner.info, width=x1 - x0, has_depth=False)

    @property
    def info(self) -> ClipInfo:
        return self._info

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        for frame in self._inner.frames(start, stop):
            rgb = np.ascontiguousarray(frame.rgb[:, self._x0 : self._x1])
            yield Frame(index=frame.index, rgb=rgb, depth_m=None, timestamp_s=frame.timestamp_s)

    def close(self) -> None:
        self._inner.close()


__all__ = [
    "CAMERA_CODECS",
    "REAL_STILL_CROPS",
    "ColumnCrop",
    "StillScene",
    "drumhead",
    "encode",
    "fork_and_motor",
    "spring_near_comb",
    "still",
    "still_corpus",
    "thin_bar",
    "wheel",
]
