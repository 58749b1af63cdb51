"""Ground-truth RGB-D scenes of spring-mass objects ringing down.

A scene is a textured background plane and one or more textured planar objects facing the camera. Each
object is a damped spring-mass oscillator excited either by a held force that is released
(``step_release``) or by an impulse (``impulse``); its displacement along a 3-D direction in camera
coordinates is projected through a pinhole camera. Sensor noise is added to colour and depth.

Everything is seeded: the same :class:`Scene` always renders the same clip. :func:`render` holds the whole
clip in memory; :class:`SceneReader` is a clip reader that renders each frame when it is read, for long
clips. Objects may be thin and plain (strings) and carry overtones in their motion.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import ClipInfo, ClosingReader, Frame, Intrinsics
from workers.pipeline.errors import ParameterError


@dataclass(frozen=True, kw_only=True)
class SceneObject:
    """One oscillating object.

    Attributes
    ----------
    center_px : (x, y)
        Rest position of the object's centre in the image, pixels.
    size_px : (w, h)
        Size at rest, pixels.
    shape : ``"rect"`` or ``"ellipse"``
    depth_m : float
        Distance of the object plane from the camera at rest.
    frequency_hz : float
        Undamped natural frequency f = ω / 2π.
    damping_ratio : float
        ζ, dimensionless.
    mass_kg : float
    excitation : ``"step_release"``, ``"impulse"``, ``"steady"`` or ``"forced"``
        ``steady``: a sustained (forced) oscillation of ``steady_amplitude_m`` from ``release_frame`` on
        at ``frequency_hz``, with no decay (a shaker table, a running motor); ``damping_ratio`` is unused.
        ``forced``: from rest, driven from ``release_frame`` on by a force that keeps acting
        (:meth:`force_n_at`: cosines at ``forcing_hz``, each of ``forcing_n``), the spring-mass's exact
        response, its start-up transient included.
    force_n : float
        Holding force before release (step_release): A = F / k.
    impulse_ns : float
        Impulse (impulse): v0 = J / m.
    direction : (x, y, z)
        Motion direction in camera coordinates (x right, y down, z away); normalised.
    steady_amplitude_m : float
        Amplitude of a ``steady`` oscillation, metres.
    release_frame : int
        Frames before this one show the object held still.
    spin_hz : float
        When non-zero, the object also turns about its own centre at this many revolutions per second (a
        rotating wheel; its texture passes every image point once a revolution).
    spin_symmetry : int
        The spinning object's texture repeats this many times a turn (a wheel with two spokes: its
        marks pass every point twice a turn), apart from ``spin_mark`` of its level.
    spin_mark : float
        How much of the texture breaks that symmetry (a valve, a scuff), 0 to 1.
    pivot_px : (x, y) or None
        When set, the object swings about this image point like a pendulum: its displacement is the arc
        travelled by its centre, the object turns with the angle, and a rod (flat, ``rod_px`` wide)
        joins it to the pivot. None: it translates along ``direction``.
    rod_px : float
        Width of the pendulum's rod, pixels.
    shadow_offset_px : (dx, dy) or None
        When set, a shadow of the object falls on the background at this offset and moves with it.
    harmonics : tuple of float
        Relative displacement amplitudes of the 2nd, 3rd, ... partials (a plucked string's overtones):
        partial n rings at n times the damped frequency, in phase with the fundamental at release, and
        decays n times faster (same damping ratio). Empty: a pure damped oscillation.
    texture : ``"noise"`` or ``"flat"``
        Band-limited colour noise (easy to track), or one uniform colour (a string, a bare bar: only its
        edges can be tracked).
    forcing_hz : tuple of float
        A ``forced`` object's driving frequencies (one: a shaker's tone; several: a multisine).
    forcing_n : float
        Amplitude of each driving cosine, newtons.
    forcing_seed : int
        Seeds the cosines' phases.
    release_s : float
        A ``step_release`` lets go over this long, the force falling linearly, centred on
        ``release_frame`` (a gripper opening, a hand pulled away): the oscillation it starts is smaller
        than a sudden release's, by sin(ω T / 2) / (ω T / 2) for an undamped spring. 0: sudden.
    """

    center_px: tuple[float, float] = (320.0, 240.0)
    size_px: tuple[float, float] = (140.0, 110.0)
    shape: Literal["rect", "ellipse"] = "rect"
    depth_m: float = 1.0
    frequency_hz: float = 5.0
    damping_ratio: float = 0.03
    mass_kg: float = 0.5
    excitation: Literal["step_release", "impulse", "steady", "forced"] = "step_release"
    force_n: float = 10.0
    impulse_ns: float = 0.3
    steady_amplitude_m: float = 0.005
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    release_frame: int = 0
    shadow_offset_px: tuple[float, float] | None = None
    harmonics: tuple[float, ...] = ()
    texture: Literal["noise", "flat"] = "noise"
    pivot_px: tuple[float, float] | None = None
    rod_px: float = 6.0
    spin_hz: float = 0.0
    spin_symmetry: int = 1
    spin_mark: float = 0.0
    forcing_hz: tuple[float, ...] = ()
    forcing_n: float = 0.3
    forcing_seed: int = 0
    release_s: float = 0.0

    @property
    def stiffness_n_per_m(self) -> float:
        return self.mass_kg * (2 * math.pi * self.frequency_hz) ** 2

    @property
    def damped_frequency_hz(self) -> float:
        """The frequency the object is seen to oscillate at (a steady oscillation's own)."""
        if self.excitation == "steady":
            return self.frequency_hz
        return self.frequency_hz * math.sqrt(1 - self.damping_ratio**2)

    @property
    def regime(self) -> str:
        """``"steady"`` for a sustained or driven oscillation, else ``"ring_down"``."""
        return "steady" if self.excitation in ("steady", "forced") else "ring_down"

    @property
    def amplitude_m(self) -> float:
        """Envelope amplitude at release: F/k, v0/ωd for an impulse, or a steady oscillation's own (a
        forced one's: √2 × the RMS of its steady response)."""
        if self.excitation == "steady":
            return self.steady_amplitude_m
        if self.excitation == "forced":
            freqs, amps, _ = self._forcing_lines()
            return float(np.sqrt(np.sum((amps * np.abs(self._receptance(freqs))) ** 2)))
        if self.excitation == "step_release":
            return self.force_n / self.stiffness_n_per_m
        wd = 2 * math.pi * self.damped_frequency_hz
        return self.impulse_ns / self.mass_kg / wd

    def displacement_m(self, t_s: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
        """Displacement along ``direction`` at times ``t_s`` (seconds from the first frame)."""
        wn = 2 * math.pi * self.frequency_hz
        z = self.damping_ratio
        wd = wn * math.sqrt(1 - z * z)
        tau = t_s - self.release_frame / fps
        after = tau >= 0
        tt = np.where(after, tau, 0.0)
        if self.excitation == "steady":
            return np.where(after, self.steady_amplitude_m * np.sin(wn * tt), 0.0)
        if self.excitation == "forced":
            return np.where(after, self._forced_response(tt), 0.0)
        if self.excitation == "step_release" and self.release_s > 0:
            return self._ramped_release(t_s - self.release_frame / fps)
        env = np.exp(-z * wn * tt)
        if self.excitation == "step_release":
            a = self.force_n / self.stiffness_n_per_m
            x = a * env * (np.cos(wd * tt) + z / math.sqrt(1 - z * z) * np.sin(wd * tt))
            held = a
            for order, rel in enumerate(self.harmonics, start=2):
                x = x + rel * a * np.exp(-z * order * wn * tt) * np.cos(order * wd * tt)
                held += rel * a
            return np.where(after, x, held)
        v0 = self.impulse_ns / self.mass_kg
        x = v0 / wd * env * np.sin(wd * tt)
        for order, rel in enumerate(self.harmonics, start=2):
            x = x + rel * v0 / wd * np.exp(-z * order * wn * tt) * np.sin(order * wd * tt)
        return np.where(after, x, 0.0)

    def _ramped_release(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """Displacement ``tau`` seconds after the middle of a release that takes ``release_s``: held at
        F/k, then the exact response to the force falling linearly to zero, as two ramp responses."""
        wn = 2 * math.pi * self.frequency_hz
        z = self.damping_ratio
        wd = wn * math.sqrt(1 - z * z)
        width = self.release_s

        def ramp(t: NDArray[np.float64]) -> NDArray[np.float64]:  # unit-slope ramp response, x k
            t = np.maximum(t, 0.0)
            free = np.exp(-z * wn * t) * (2 * z / wn * np.cos(wd * t) + (2 * z * z - 1) / wd * np.sin(wd * t))
            return np.asarray(t - 2 * z / wn + free)

        start = np.asarray(tau, np.float64) + width / 2
        held = self.force_n / self.stiffness_n_per_m
        return np.asarray(held * (1.0 - (ramp(start) - ramp(start - width)) / width))

    def force_n_at(self, t_s: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
        """The force driving a ``forced`` object along ``direction`` at times ``t_s`` (seconds from the
        first frame), newtons: zero before ``release_frame``."""
        freqs, amps, phases = self._forcing_lines()
        tau = np.asarray(t_s, np.float64) - self.release_frame / fps
        waves = amps[:, None] * np.cos(2 * math.pi * freqs[:, None] * tau[None, :] + phases[:, None])
        return np.where(tau >= 0, waves.sum(axis=0), 0.0)

    def _forcing_lines(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        freqs = np.asarray(self.forcing_hz, np.float64)
        phases = np.random.default_rng(self.forcing_seed).uniform(0.0, 2 * math.pi, freqs.size)
        return freqs, np.full(freqs.size, self.forcing_n), phases

    def _receptance(self, freqs: NDArray[np.float64]) -> NDArray[np.complex128]:
        """X / F of the spring-mass at ``freqs``: 1 / (k - m ω² + i c ω), metres per newton."""
        w = 2 * math.pi * freqs
        k, m = self.stiffness_n_per_m, self.mass_kg
        c = 2 * self.damping_ratio * math.sqrt(k * m)
        return np.asarray(1.0 / (k - m * w**2 + 1j * c * w))

    def _forced_response(self, tau: NDArray[np.float64]) -> NDArray[np.float64]:
        """Displacement ``tau`` seconds after the force began, from rest: the steady response to each
        cosine, plus the free response that starts it from zero displacement and velocity."""
        freqs, amps, phases = self._forcing_lines()
        gain = amps * self._receptance(freqs)
        w = 2 * math.pi * freqs
        steady = np.real(gain[:, None] * np.exp(1j * (w[:, None] * tau[None, :] + phases[:, None]))).sum(0)
        x0 = float(np.real(gain * np.exp(1j * phases)).sum())
        v0 = float(np.real(1j * w * gain * np.exp(1j * phases)).sum())
        wn = 2 * math.pi * self.frequency_hz
        sigma, wd = self.damping_ratio * wn, wn * math.sqrt(1 - self.damping_ratio**2)
        a = -x0
        b = (-v0 + sigma * a) / wd
        return np.asarray(steady + np.exp(-sigma * tau) * (a * np.cos(wd * tau) + b * np.sin(wd * tau)))


@dataclass(frozen=True, kw_only=True)
class Scene:
    """A whole clip to render.

    Attributes
    ----------
    width, height : int
        Frame size, pixels.
    frames : int
    fps : float
    focal_px : float or None
        fx = fy; default 525 px scaled with the width relative to 640.
    background_depth_m : float
    objects : tuple of SceneObject
    rgb_noise : float
        Standard deviation of additive colour noise, 8-bit levels.
    shake_px, shake_hz : float
        Camera shake: the whole image moves diagonally by ``shake_px`` at ``shake_hz``.
    drift_px_per_s : (dx, dy)
        Slow camera drift of the whole image.
    flicker, flicker_hz : float
        Lighting flicker: brightness scaled by 1 + flicker sin(2π flicker_hz t).
    flicker_rolling_px : float
        With a rolling shutter, flicker shows as bands that roll through the picture: the phase falls by
        a cycle every ``flicker_rolling_px`` rows. 0: a global shutter (the whole frame at once).
    keyframe_every, keyframe_pulse : int, float
        Codec keyframes: every ``keyframe_every`` frames the image jumps by ``keyframe_pulse`` levels.
    depth_noise_m : float
        Standard deviation of depth noise at 1 m (grows with the square of depth).
    background : ``"noise"`` or ``"shaded"``
        A textured plane (band-limited colour noise, easy to track), or a flat wall in faint, smooth
        shading (a few levels over the picture: where optical flow has nothing to hold on to).
    seed : int
    """

    width: int = 640
    height: int = 480
    frames: int = 128
    fps: float = 30.0
    focal_px: float | None = None
    background_depth_m: float = 2.0
    objects: tuple[SceneObject, ...] = field(default_factory=lambda: (SceneObject(),))
    rgb_noise: float = 2.0
    depth_noise_m: float = 0.002
    seed: int = 0
    shake_px: float = 0.0
    shake_hz: float = 0.0
    drift_px_per_s: tuple[float, float] = (0.0, 0.0)
    flicker: float = 0.0
    flicker_hz: float = 0.0
    flicker_rolling_px: float = 0.0
    keyframe_every: int = 0
    keyframe_pulse: float = 6.0
    background: Literal["noise", "shaded"] = "noise"

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        f = self.focal_px if self.focal_px is not None else 525.0 * self.width / 640.0
        return (f, f, (self.width - 1) / 2.0, (self.height - 1) / 2.0)

    def truth(self) -> dict[str, Any]:
        """Ground truth as JSON-ready data."""
        objs = []
        for i, o in enumerate(self.objects, start=1):
            objs.append(
                {
                    "id": i,
                    "eigenfrequency_hz": o.damped_frequency_hz,
                    "natural_frequency_hz": o.frequency_hz,
                    "damping_ratio": o.damping_ratio,
                    "stiffness_n_per_m": o.stiffness_n_per_m,
                    "mass_kg": o.mass_kg,
                    "amplitude_m": o.amplitude_m,
                    "release_time_s": o.release_frame / self.fps,
                    "spec": asdict(o),
                }
            )
        return {
            "fps": self.fps,
            "frames": self.frames,
            "width": self.width,
            "height": self.height,
            "intrinsics": list(self.intrinsics),
            "seed": self.seed,
            "objects": objs,
        }


@dataclass(frozen=True)
class SyntheticClip:
    """A rendered scene.

    Attributes
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    depth : ndarray of uint16, shape (T, H, W)
        Millimetres (depth scale 0.001 m); 0 = no reading.
    fps : float
    intrinsics : (fx, fy, cx, cy)
    mask : ndarray of uint8, shape (H, W)
        True labels at rest: 0 background, i for object i.
    truth : dict
        See :meth:`Scene.truth`.
    """

    rgb: NDArray[np.uint8]
    depth: NDArray[np.uint16]
    fps: float
    intrinsics: tuple[float, float, float, float]
    mask: NDArray[np.uint8]
    truth: dict[str, Any]
    #: Pixels of the objects' shadows at rest that no object covers.
    shadow_mask: NDArray[np.bool_] | None = None


def noise_texture(
    rng: np.random.Generator, height: int, width: int, *, base: NDArray[np.float32]
) -> NDArray[np.float32]:
    """Band-limited colour noise with structure at several scales (good for optical flow)."""
    import cv2

    out = np.zeros((height, width, 3), np.float32)
    for sigma, weight in ((1.5, 0.45), (4.0, 0.35), (12.0, 0.2)):
        noise = rng.standard_normal((height, width, 3)).astype(np.float32)
        blurred = cv2.GaussianBlur(noise, (0, 0), sigma)
        blurred /= blurred.std() + 1e-6
        out += weight * blurred
    return np.asarray(np.clip(base + 38.0 * out, 0, 255), dtype=np.float32)


def flat_shading(
    rng: np.random.Generator, height: int, width: int, *, base: NDArray[np.float32], levels: float = 6.0
) -> NDArray[np.float32]:
    """A flat wall in faint, smooth shading: a gentle gradient and broad blotches, ``levels`` grey levels
    across the picture (nothing for optical flow to hold on to, as on a painted wall)."""
    import cv2

    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    ramp = (x / max(width - 1, 1) - 0.5) * 0.6 + (y / max(height - 1, 1) - 0.5) * 0.4
    blotch = cv2.GaussianBlur(rng.standard_normal((height, width)).astype(np.float32), (0, 0), width / 8)
    blotch /= float(np.abs(blotch).max()) + 1e-6
    shade = levels * (ramp + 0.5 * blotch)
    return np.asarray(base[None, None, :] + shade[..., None], np.float32)


def _symmetric(tex: NDArray[np.float32], n: int, mark: float) -> NDArray[np.float32]:
    """A texture made to repeat ``n`` times a turn about its centre, keeping ``mark`` of the original."""
    import cv2

    h, w = tex.shape[:2]
    centre = ((w - 1) / 2, (h - 1) / 2)
    turns = [
        cv2.warpAffine(
            tex,
            _turn_about(2 * math.pi * k / n, centre).astype(np.float32),
            (w, h),
            borderMode=cv2.BORDER_REFLECT,
        )
        for k in range(n)
    ]
    even = np.mean(turns, axis=0)
    return np.asarray((1 - mark) * even + mark * tex, np.float32)


def _turn_about(angle_rad: float, centre: tuple[float, float]) -> NDArray[np.float64]:
    """2 x 3 matrix turning points by ``angle_rad`` (counter-clockwise on screen) about ``centre``."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    cx, cy = centre
    return np.array([[c, s, cx - c * cx - s * cy], [-s, c, cy + s * cx - c * cy]], np.float64)


def _shape_alpha(shape: str, w: int, h: int) -> NDArray[np.float32]:
    import cv2

    ss = 4  # supersampled edges
    big = np.zeros((h * ss, w * ss), np.uint8)
    if shape == "ellipse":
        cv2.ellipse(big, (w * ss // 2, h * ss // 2), (w * ss // 2 - 1, h * ss // 2 - 1), 0, 0, 360, 255, -1)
    else:
        big[:, :] = 255
    small = np.asarray(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA), np.float32)
    return small / np.float32(255.0)


def _check(scene: Scene) -> None:
    if scene.frames < 2 or scene.width < 16 or scene.height < 16:
        raise ParameterError("synth: need at least 2 frames of at least 16x16 pixels")
    if not scene.fps > 0:
        raise ParameterError(f"synth: fps={scene.fps} must be positive")
    for o in scene.objects:
        if not 0 <= o.damping_ratio < 1:
            raise ParameterError(f"synth: damping_ratio={o.damping_ratio} must be in [0, 1)")
        if o.frequency_hz <= 0 or o.mass_kg <= 0 or o.depth_m <= 0:
            raise ParameterError("synth: frequency_hz, mass_kg and depth_m must be positive")
        if o.depth_m >= scene.background_depth_m:
            raise ParameterError(
                "synth: objects must be in front of the background (depth_m < background_depth_m)"
            )
        if o.texture not in ("noise", "flat"):
            raise ParameterError(f"synth: texture={o.texture!r} is unknown; use 'noise' or 'flat'")
        if o.release_s < 0 or (o.release_s > 0 and o.harmonics):
            raise ParameterError("synth: release_s must be >= 0, and a ramped release has no harmonics")
        if o.excitation == "forced" and not o.forcing_hz:
            raise ParameterError("synth: a forced object needs its driving frequencies (forcing_hz)")
        if o.spin_hz and o.pivot_px is not None:
            raise ParameterError("synth: an object either spins (spin_hz) or swings (pivot_px), not both")
    if scene.background not in ("noise", "shaded"):
        raise ParameterError(f"synth: background={scene.background!r} is unknown; use 'noise' or 'shaded'")


class _Layer:
    """One object's texture and alpha, and where they go in frame k: a translating object is anchored at
    its centre and scaled by its depth; a swinging one turns about its pivot."""

    def __init__(
        self,
        label: int,
        obj: SceneObject,
        tex: NDArray[np.float32],
        alpha: NDArray[np.float32],
        *,
        anchor: tuple[float, float],
    ) -> None:
        self.label, self.obj, self.tex, self.alpha, self.anchor = label, obj, tex, alpha, anchor
        self.positions: NDArray[np.float64] | None = None  # (T, 3) camera coordinates of the centre
        self.fps = 1.0  # frame rate (a spinning object's angle in frame k)
        self.angles: NDArray[np.float64] | None = None  # (T,) swing angle, radians, from the rest angle
        self.rest_angle = 0.0

    def rest_matrix(self) -> NDArray[np.float32]:
        """Canvas to image at rest (unit scale)."""
        if self.obj.pivot_px is not None:
            return self._rotation(self.rest_angle)
        ax, ay = self.anchor
        cx, cy = self.obj.center_px
        return np.array([[1, 0, cx - ax], [0, 1, cy - ay]], np.float32)

    def _rotation(self, angle: float) -> NDArray[np.float32]:
        assert self.obj.pivot_px is not None
        c, s = math.cos(angle), math.sin(angle)
        rot = np.array([[c, s], [-s, c]])
        pivot = np.asarray(self.obj.pivot_px, np.float64)
        shift = pivot - rot @ np.asarray(self.anchor, np.float64)
        return np.hstack([rot, shift[:, None]]).astype(np.float32)

    def matrix(
        self, k: int, intrinsics: tuple[float, float, float, float]
    ) -> tuple[NDArray[np.float32], float]:
        """Canvas to image in frame k, and the object's depth then."""
        if self.angles is not None:
            return self._rotation(self.rest_angle + float(self.angles[k])), self.obj.depth_m
        assert self.positions is not None
        fx, fy, cx, cy = intrinsics
        X, Y, Z = self.positions[k]
        scale = self.obj.depth_m / Z
        u = fx * X / Z + cx
        v = fy * Y / Z + cy
        th, tw = self.alpha.shape
        M = np.array([[scale, 0, u - scale * (tw - 1) / 2], [0, scale, v - scale * (th - 1) / 2]], np.float32)
        if self.obj.spin_hz:
            turn = _turn_about(2 * math.pi * self.obj.spin_hz * k / self.fps, ((tw - 1) / 2, (th - 1) / 2))
            M = (np.vstack([M, [0, 0, 1]]) @ np.vstack([turn, [0, 0, 1]]))[:2].astype(np.float32)
        return M, float(Z)


def _swing_layer(
    label: int,
    obj: SceneObject,
    tex: NDArray[np.float32],
    alpha: NDArray[np.float32],
    *,
    pad: int,
    fx: float,
    disp_m: NDArray[np.float64],
) -> _Layer:
    """A pendulum: the object hangs on a flat rod from its pivot, and turns by the arc it travels over the
    rod's length."""
    assert obj.pivot_px is not None
    th, tw = alpha.shape
    dx = obj.center_px[0] - obj.pivot_px[0]
    dy = obj.center_px[1] - obj.pivot_px[1]
    length = math.hypot(dx, dy)
    if length < 1:
        raise ParameterError("synth: a swinging object's pivot_px must lie away from its centre")
    rod = max(1, round(obj.rod_px))
    width = max(tw, rod + 2 * pad)
    height = round(length) + th // 2 + 2 * pad
    canvas = np.zeros((height, width, 3), np.float32)
    canvas_alpha = np.zeros((height, width), np.float32)
    mid = (width - 1) / 2
    top = pad
    # The rod, from the pivot to the object's centre, in the object's average colour.
    x0 = round(mid - rod / 2)
    canvas[top : top + round(length), x0 : x0 + rod] = tex.reshape(-1, 3).mean(axis=0)
    canvas_alpha[top : top + round(length), x0 : x0 + rod] = 1.0
    # The object, centred at the rod's end.
    oy = round(top + length - (th - 1) / 2)
    ox = round(mid - (tw - 1) / 2)
    region = (slice(oy, oy + th), slice(ox, ox + tw))
    a = alpha[..., None]
    canvas[region] = canvas[region] * (1 - a) + tex * a
    canvas_alpha[region] = np.maximum(canvas_alpha[region], alpha)
    layer = _Layer(label, obj, canvas, canvas_alpha, anchor=(mid, float(top)))
    layer.rest_angle = math.atan2(dx, dy)
    length_m = length * obj.depth_m / fx
    layer.angles = disp_m / length_m
    return layer


class _Renderer:
    """The static parts of a scene (textures, masks, trajectories), and one frame at a time on demand."""

    def __init__(self, scene: Scene) -> None:
        import cv2

        _check(scene)
        self.scene = scene
        #: Draws the textures, then (in :func:`render`) the per-frame noise in frame order.
        self.rng = rng = np.random.default_rng(scene.seed)
        H, W, T = scene.height, scene.width, scene.frames
        fx, fy, cx, cy = self.intrinsics = scene.intrinsics
        base = np.array([110, 120, 100], np.float32)
        if scene.background == "shaded":
            self.background = flat_shading(rng, H, W, base=base)
        else:
            self.background = noise_texture(rng, H, W, base=base)
        t = np.arange(T, dtype=np.float64) / scene.fps

        layers: list[_Layer] = []
        true_mask = np.zeros((H, W), np.uint8)
        shadow_mask = np.zeros((H, W), bool)
        for label, obj in enumerate(scene.objects, start=1):
            w, h = max(2, round(obj.size_px[0])), max(2, round(obj.size_px[1]))
            pad = 2
            base = rng.uniform(70, 190, 3).astype(np.float32)
            if obj.texture == "flat":
                tex = np.broadcast_to(base, (h + 2 * pad, w + 2 * pad, 3)).astype(np.float32)
            else:
                tex = noise_texture(rng, h + 2 * pad, w + 2 * pad, base=base)
            if obj.spin_hz and obj.spin_symmetry > 1:
                tex = _symmetric(tex, obj.spin_symmetry, obj.spin_mark)
            alpha = np.zeros((h + 2 * pad, w + 2 * pad), np.float32)
            alpha[pad : pad + h, pad : pad + w] = _shape_alpha(obj.shape, w, h)
            direction = np.asarray(obj.direction, np.float64)
            direction /= np.linalg.norm(direction)
            disp = obj.displacement_m(t, scene.fps)
            # Rest centre in camera coordinates.
            X0 = (obj.center_px[0] - cx) * obj.depth_m / fx
            Y0 = (obj.center_px[1] - cy) * obj.depth_m / fy
            Z0 = obj.depth_m
            rest = np.array([X0, Y0, Z0])
            if obj.pivot_px is None:
                positions = rest[None, :] + disp[:, None] * direction[None, :]
                layer = _Layer(label, obj, tex, alpha, anchor=((w + 2 * pad - 1) / 2, (h + 2 * pad - 1) / 2))
                layer.positions = positions
                layer.fps = scene.fps
            else:
                layer = _swing_layer(label, obj, tex, alpha, pad=pad, fx=fx, disp_m=disp)
            layers.append(layer)
            # True mask at rest position.
            m = cv2.warpAffine(layer.alpha, layer.rest_matrix(), (W, H), flags=cv2.INTER_LINEAR)
            true_mask[m >= 0.5] = label
            if obj.shadow_offset_px is not None:
                shifted = np.roll(
                    m >= 0.5, (round(obj.shadow_offset_px[1]), round(obj.shadow_offset_px[0])), (0, 1)
                )
                shadow_mask |= shifted
        # Draw far objects first.
        layers.sort(key=lambda layer: -layer.obj.depth_m)
        self.layers = layers
        self.true_mask = true_mask
        self.shadow_mask = shadow_mask & (true_mask == 0)
        self.bg_depth = np.full((H, W), scene.background_depth_m, np.float32)

    def frame(
        self, k: int, rng: np.random.Generator, *, depth: bool = True
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint16] | None]:
        """Frame ``k``: RGB (H, W, 3) uint8 and depth (H, W) uint16 millimetres (None without depth).
        Noise is drawn from ``rng``: colour first, then depth."""
        import cv2

        scene = self.scene
        H, W = scene.height, scene.width
        frame = self.background.copy()
        dmap = self.bg_depth.copy()
        for layer in self.layers:
            obj, alpha = layer.obj, layer.alpha
            M, Z = layer.matrix(k, self.intrinsics)
            a = cv2.warpAffine(alpha, M, (W, H), flags=cv2.INTER_LINEAR)
            if obj.shadow_offset_px is not None:
                sdx, sdy = obj.shadow_offset_px
                Ms = M.copy()
                Ms[0, 2] += sdx
                Ms[1, 2] += sdy
                sh = cv2.warpAffine(alpha, Ms, (W, H), flags=cv2.INTER_LINEAR)
                sh = cv2.GaussianBlur(sh, (0, 0), 2.0)
                frame *= (1.0 - 0.55 * sh)[..., None]
            col = cv2.warpAffine(layer.tex, M, (W, H), flags=cv2.INTER_LINEAR)
            # Blend where the layer covers (its alpha is exactly 0 elsewhere, which would leave the frame
            # as it is: the same numbers, less work).
            rows, cols = np.flatnonzero(a.any(axis=1)), np.flatnonzero(a.any(axis=0))
            if rows.size:
                box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
                cover = a[box][..., None]
                frame[box] = frame[box] * (1 - cover) + col[box] * cover
                dmap[box] = np.where(a[box] >= 0.5, np.float32(Z), dmap[box])
        tk = k / scene.fps
        gx = scene.shake_px * math.sin(2 * math.pi * scene.shake_hz * tk) + scene.drift_px_per_s[0] * tk
        gy = scene.shake_px * math.sin(2 * math.pi * scene.shake_hz * tk) + scene.drift_px_per_s[1] * tk
        if gx or gy:
            g = np.array([[1, 0, gx], [0, 1, gy]], np.float32)
            frame = cv2.warpAffine(frame, g, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            dmap = cv2.warpAffine(dmap, g, (W, H), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        if scene.flicker:
            if scene.flicker_rolling_px:
                # A rolling shutter reads row y later than row 0: the flicker's phase moves down the picture.
                phase = (
                    2
                    * math.pi
                    * (scene.flicker_hz * tk - np.arange(H, dtype=np.float32) / scene.flicker_rolling_px)
                )
                gain = (1 + scene.flicker * np.sin(phase)).astype(np.float32)
                frame *= gain[:, None, None]
            else:
                frame *= np.float32(1 + scene.flicker * math.sin(2 * math.pi * scene.flicker_hz * tk))
        if scene.keyframe_every and k % scene.keyframe_every == 0:
            frame += np.float32(scene.keyframe_pulse)
        noise = rng.standard_normal(frame.shape, dtype=np.float32)
        noise *= np.float32(scene.rgb_noise)
        frame += noise
        rgb = np.clip(frame, 0, 255, out=frame).astype(np.uint8)
        if not depth:
            return rgb, None
        dn = rng.standard_normal((H, W), dtype=np.float32)
        dn *= np.float32(scene.depth_noise_m)
        dn *= dmap**2
        dn += dmap
        dn *= 1000.0
        return rgb, np.clip(np.rint(dn, out=dn), 0, 65535, out=dn).astype(np.uint16)


def render(scene: Scene) -> SyntheticClip:
    """Render ``scene`` into an RGB-D clip with its ground truth.

    The whole clip is held in memory; for long clips use :class:`SceneReader`, which renders frames on
    demand.

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    SyntheticClip
    """
    renderer = _Renderer(scene)
    H, W, T = scene.height, scene.width, scene.frames
    rgb = np.empty((T, H, W, 3), np.uint8)
    depth = np.empty((T, H, W), np.uint16)
    for k in range(T):
        frame, dmap = renderer.frame(k, renderer.rng)
        assert dmap is not None
        rgb[k] = frame
        depth[k] = dmap
    return SyntheticClip(
        rgb=rgb,
        depth=depth,
        fps=scene.fps,
        intrinsics=scene.intrinsics,
        mask=renderer.true_mask,
        truth=scene.truth(),
        shadow_mask=renderer.shadow_mask,
    )


class SceneReader(ClosingReader):
    """A scene as a clip reader (:class:`~workers.pipeline.clipio.types.ClipReader`) that renders each
    frame when it is read: memory stays at one frame whatever the clip's length.

    Each frame's noise is seeded by (seed, frame index), so any frame range reads the same pixels every
    time (they differ from :func:`render`'s, which draws the noise in frame order).

    Parameters
    ----------
    scene : Scene
    depth : bool
        Deliver depth frames and intrinsics (an RGB-D camera); False for an RGB-only clip.

    Attributes
    ----------
    mask : ndarray of uint8, shape (H, W)
        True labels at rest (see :class:`SyntheticClip`).
    truth : dict
        See :meth:`Scene.truth`.
    """

    def __init__(self, scene: Scene, *, depth: bool = True) -> None:
        self._renderer = _Renderer(scene)
        self._depth = depth
        self.scene = scene
        self.mask = self._renderer.true_mask
        self.truth = scene.truth()
        fx, fy, cx, cy = scene.intrinsics
        self._info = ClipInfo(
            format="synthetic",
            frames=scene.frames,
            width=scene.width,
            height=scene.height,
            fps=scene.fps,
            fps_source="bundle",
            has_depth=depth,
            depth_scale=0.001 if depth else None,
            intrinsics=Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy) if depth else None,
            container_fps=scene.fps,
            depth_source="rendered" if depth else None,
        )

    @property
    def info(self) -> ClipInfo:
        return self._info

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop``, rendered one at a time."""
        total = self.scene.frames
        stop = total if stop is None else min(stop, total)
        if not 0 <= start <= stop:
            raise ParameterError(f"synth: frame range [{start}, {stop}) is outside the clip's {total} frames")
        for k in range(start, stop):
            rng = np.random.default_rng([self.scene.seed, k])
            rgb, dmap = self._renderer.frame(k, rng, depth=self._depth)
            depth_m = None
            if dmap is not None:
                depth_m = dmap.astype(np.float32) * np.float32(0.001)
                depth_m[dmap == 0] = np.nan
            yield Frame(index=k, rgb=rgb, depth_m=depth_m, timestamp_s=k / self.scene.fps)

    def close(self) -> None:
        """Nothing to release (frames are rendered on demand)."""
