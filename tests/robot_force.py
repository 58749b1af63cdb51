"""A robot that pushes a rendered spring-mass and records the force it applied: the scene and the force
profile its wrist sensor reads, shared by the tests of the force sensor as the excitation (bags written by
the accuracy tier, logs sent through the API by the integration tier)."""

from __future__ import annotations

import math

import numpy as np

from workers.pipeline.synth import Scene, SceneObject

FPS = 30.0
#: The frame at which the robot lets go (or strikes).
RELEASE_FRAME = 24


def pushed_spring(excitation: str, seed: int, *, frames: int = 150, release_s: float = 0.04) -> Scene:
    """A 2.5 Hz spring-mass of 0.8 kg at 0.9 m, 320x240 at :data:`FPS`, held by 6 N and let go at
    :data:`RELEASE_FRAME` over ``release_s`` (``step_release``: the force falls linearly, and the scene
    moves as that release makes it) or struck there by 0.16 N·s (``impulse``), moving along +x of the
    camera."""
    obj = SceneObject(
        center_px=(160.0, 120.0),
        size_px=(90.0, 70.0),
        frequency_hz=2.5,
        damping_ratio=0.02,
        mass_kg=0.8,
        excitation=excitation,  # type: ignore[arg-type]
        force_n=6.0,
        impulse_ns=0.16,
        direction=(1.0, 0.0, 0.0),
        release_frame=RELEASE_FRAME,
        depth_m=0.9,
        release_s=release_s if excitation == "step_release" else 0.0,
    )
    return Scene(width=320, height=240, frames=frames, fps=FPS, objects=(obj,), seed=seed)


def robot_force(
    obj: SceneObject, t: np.ndarray, rng: np.random.Generator, *, noise: float = 0.03, drift: float = 0.0
) -> np.ndarray:
    """The robot's force along the push (N) at times ``t`` (s from the clip's first frame), consistent with
    the scene: held at ``force_n`` until the release (falling linearly over the scene's ``release_s``,
    centred on the release frame; the push began before the clip), a 9 ms half-sine strike of
    ``impulse_ns`` centred on it, or a ``forced`` object's driving force; plus the sensor's white noise (SD
    ``noise``) and a linear drift of ``drift`` over the record."""
    release = RELEASE_FRAME / FPS
    if obj.excitation == "forced":
        force = obj.force_n_at(t, FPS)
    elif obj.excitation == "step_release":
        width = obj.release_s
        fall = (release + width / 2 - t) / width if width > 0 else np.where(t < release, 1.0, 0.0)
        held = obj.force_n * np.clip(fall, 0.0, 1.0)
        force = held * np.clip((t + 0.6) / 0.2, 0.0, 1.0)
    else:
        width = 0.009
        phase = (t - release + width / 2) / width
        pulse = np.where((phase >= 0) & (phase <= 1), np.sin(np.pi * np.clip(phase, 0, 1)), 0.0)
        force = obj.impulse_ns * math.pi / (2 * width) * pulse  # its integral is the impulse
    return np.asarray(force + rng.normal(0.0, noise, t.shape) + drift * (t - t[0]) / (t[-1] - t[0]))
