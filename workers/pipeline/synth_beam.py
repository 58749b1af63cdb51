"""Ground-truth RGB-D scenes of struck cantilever beams ringing in several bending modes.

A beam is a textured strip clamped at its root and free at its tip, lying along the image's x axis in a
plane facing the camera. Struck at the tip, it rings in its Euler-Bernoulli bending modes (clamped-free:
β_r L = 1.8751, 4.6941, 7.8548, 10.9955, so f_r ∝ (β_r L)^2, about 1 : 6.27 : 17.5 : 34.4), each a
damped oscillation of its own shape. The beam bends in the plane of the image's y axis and the line of
sight (``bend_direction``): the image shows the y part, the depth the z part (perspective is not drawn).

:func:`render_beams` returns the same :class:`~workers.pipeline.synth.SyntheticClip` as
:func:`workers.pipeline.synth.render`, its truth giving every mode's frequency, damping and tip amplitude;
:meth:`Beam.shape` gives a mode's analytic shape at any image column.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.errors import ParameterError
from workers.pipeline.synth import SyntheticClip, flat_shading, noise_texture

#: β_r L of a clamped-free beam's first bending modes.
CANTILEVER_BETA_L = (1.8751, 4.6941, 7.8548, 10.9955)


def cantilever_shape(beta_l: float, xi: NDArray[np.float64]) -> NDArray[np.float64]:
    """The bending shape of a clamped-free beam at ξ = x / L (0 at the root), scaled to 1 at the tip.

    Parameters
    ----------
    beta_l : float
        β_r L of the mode (see :data:`CANTILEVER_BETA_L`).
    xi : ndarray of float64
        Positions along the beam, 0 to 1.

    Returns
    -------
    ndarray of float64, shape of ``xi``
    """
    sigma = (math.cosh(beta_l) + math.cos(beta_l)) / (math.sinh(beta_l) + math.sin(beta_l))

    def phi(x: NDArray[np.float64] | float) -> Any:
        b = beta_l * np.asarray(x, np.float64)
        return np.cosh(b) - np.cos(b) - sigma * (np.sinh(b) - np.sin(b))

    return np.asarray(phi(xi) / phi(1.0), np.float64)


@dataclass(frozen=True, kw_only=True)
class Beam:
    """One struck cantilever.

    Attributes
    ----------
    root_px : (x, y)
        The clamped end's centre in the image, pixels; the beam runs to the right from there.
    length_px, thickness_px : float
    depth_m : float
        Distance of the beam from the camera at rest.
    first_hz : float
        Undamped natural frequency of the first bending mode; mode r's is first_hz (β_r L / β_1 L)^2.
    damping_ratios : tuple of float
        ζ of each mode (their count is the number of modes that ring).
    tip_amplitudes_px : tuple of float
        Each mode's deflection of the tip at the strike's peak, pixels at the beam's depth (metres =
        px depth / f).
    bend_direction : (y, z)
        Direction of the deflection: image y (down) and the line of sight (away from the camera);
        normalised.
    strike_frame : int
        Frames before this one show the beam at rest.
    """

    root_px: tuple[float, float] = (40.0, 120.0)
    length_px: float = 240.0
    thickness_px: float = 26.0
    depth_m: float = 0.8
    first_hz: float = 4.0
    damping_ratios: tuple[float, ...] = (0.012, 0.008, 0.006)
    tip_amplitudes_px: tuple[float, ...] = (4.0, 0.7, 0.25)
    bend_direction: tuple[float, float] = (1.0, 0.0)
    strike_frame: int = 8

    def natural_hz(self, r: int) -> float:
        """Undamped natural frequency of mode ``r`` (0: the first)."""
        return self.first_hz * (CANTILEVER_BETA_L[r] / CANTILEVER_BETA_L[0]) ** 2

    def damped_hz(self, r: int) -> float:
        """The frequency mode ``r`` is seen to ring at."""
        return self.natural_hz(r) * math.sqrt(1 - self.damping_ratios[r] ** 2)

    def shape(self, r: int, x_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """Mode ``r``'s analytic shape at image columns ``x_px`` (1 at the tip; 0 off the beam)."""
        xi = (np.asarray(x_px, np.float64) - self.root_px[0]) / self.length_px
        on = (xi >= 0) & (xi <= 1)
        return np.where(on, cantilever_shape(CANTILEVER_BETA_L[r], np.clip(xi, 0, 1)), 0.0)

    def deflection_px(self, t_s: float, x_px: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
        """Deflection at time ``t_s`` of the beam's columns ``x_px``, pixels."""
        tau = t_s - self.strike_frame / fps
        out = np.zeros(np.shape(x_px))
        if tau < 0:
            return out
        for r, (zeta, amp) in enumerate(zip(self.damping_ratios, self.tip_amplitudes_px, strict=True)):
            wn = 2 * math.pi * self.natural_hz(r)
            wd = wn * math.sqrt(1 - zeta**2)
            out += amp * math.exp(-zeta * wn * tau) * math.sin(wd * tau) * self.shape(r, x_px)
        return out


@dataclass(frozen=True, kw_only=True)
class BeamScene:
    """A clip of beams in front of a background plane.

    Attributes
    ----------
    width, height, frames : int
    fps : float
    focal_px : float
    beams : tuple of Beam
    background_depth_m : float
    background : ``"noise"`` or ``"shaded"``
    rgb_noise : float
        Standard deviation of colour noise, 8-bit levels.
    depth_noise_m : float
        Standard deviation of depth noise at 1 m (grows with the square of depth).
    seed : int
    """

    width: int = 320
    height: int = 240
    frames: int = 720
    fps: float = 240.0
    focal_px: float = 400.0
    beams: tuple[Beam, ...] = field(default_factory=lambda: (Beam(),))
    background_depth_m: float = 1.5
    background: Literal["noise", "shaded"] = "noise"
    rgb_noise: float = 1.0
    depth_noise_m: float = 0.001
    seed: int = 0

    @property
    def intrinsics(self) -> tuple[float, float, float, float]:
        return (self.focal_px, self.focal_px, (self.width - 1) / 2.0, (self.height - 1) / 2.0)

    def truth(self) -> dict[str, Any]:
        """Ground truth as JSON-ready data: per beam, its modes (damped and natural frequency, damping,
        tip amplitude in pixels and metres)."""
        objects = []
        for i, beam in enumerate(self.beams, start=1):
            modes = [
                {
                    "frequency_hz": beam.damped_hz(r),
                    "natural_frequency_hz": beam.natural_hz(r),
                    "damping_ratio": beam.damping_ratios[r],
                    "tip_amplitude_px": beam.tip_amplitudes_px[r],
                    "tip_amplitude_m": beam.tip_amplitudes_px[r] * beam.depth_m / self.focal_px,
                }
                for r in range(len(beam.damping_ratios))
            ]
            objects.append(
                {"id": i, "eigenfrequency_hz": modes[0]["frequency_hz"], "modes": modes, "spec": asdict(beam)}
            )
        return {
            "fps": self.fps,
            "frames": self.frames,
            "width": self.width,
            "height": self.height,
            "intrinsics": list(self.intrinsics),
            "seed": self.seed,
            "objects": objects,
        }


def _check(scene: BeamScene) -> None:
    for beam in scene.beams:
        modes = len(beam.damping_ratios)
        if not 1 <= modes <= len(CANTILEVER_BETA_L) or len(beam.tip_amplitudes_px) != modes:
            raise ParameterError(
                f"synth_beam: give 1 to {len(CANTILEVER_BETA_L)} modes, one damping ratio and one tip "
                f"amplitude each (got {modes} and {len(beam.tip_amplitudes_px)})"
            )
        x0, y0 = beam.root_px
        if x0 < 0 or x0 + beam.length_px > scene.width or not 0 <= y0 < scene.height:
            raise ParameterError(f"synth_beam: a beam from {beam.root_px} runs out of the frame")


def render_beams(scene: BeamScene) -> SyntheticClip:
    """Render ``scene`` into an RGB-D clip with its ground truth (whole clip in memory).

    Parameters
    ----------
    scene : BeamScene

    Returns
    -------
    SyntheticClip
        Colour (T, H, W, 3) uint8, depth (T, H, W) uint16 in millimetres, the beams' rest mask (label i
        for beam i) and :meth:`BeamScene.truth`.
    """

    _check(scene)
    rng = np.random.default_rng(scene.seed)
    H, W, T = scene.height, scene.width, scene.frames
    maker = flat_shading if scene.background == "shaded" else noise_texture
    background = maker(rng, H, W, base=np.array([150.0, 140.0, 130.0], np.float32))
    textures = [
        noise_texture(
            rng,
            int(b.thickness_px) + 8,
            int(b.length_px) + 8,
            base=np.array([90.0, 110.0, 150.0], np.float32),
        )
        for b in scene.beams
    ]
    rgb = np.empty((T, H, W, 3), np.uint8)
    depth = np.empty((T, H, W), np.uint16)
    mask = np.zeros((H, W), np.uint8)
    for k in range(T):
        image = background.copy()
        dmap = np.full((H, W), scene.background_depth_m, np.float32)
        for i, (beam, tex) in enumerate(zip(scene.beams, textures, strict=True), start=1):
            _draw(
                beam,
                tex,
                k / scene.fps,
                scene,
                image=image,
                depth=dmap,
                mask=mask if k == 0 else None,
                label=i,
            )
        image += rng.standard_normal(image.shape, dtype=np.float32) * np.float32(scene.rgb_noise)
        rgb[k] = np.clip(image + 0.5, 0, 255).astype(np.uint8)
        noise = rng.standard_normal(dmap.shape, dtype=np.float32) * np.float32(scene.depth_noise_m)
        depth[k] = np.clip((dmap + noise * dmap**2) * 1000.0 + 0.5, 0, 65535).astype(np.uint16)
    return SyntheticClip(
        rgb=rgb, depth=depth, fps=scene.fps, intrinsics=scene.intrinsics, mask=mask, truth=scene.truth()
    )


def _draw(
    beam: Beam,
    texture: NDArray[np.float32],
    t_s: float,
    scene: BeamScene,
    *,
    image: NDArray[np.float32],
    depth: NDArray[np.float32],
    mask: NDArray[np.uint8] | None,
    label: int,
) -> None:
    """Draw ``beam`` at time ``t_s`` into ``image`` and ``depth`` (and its label into ``mask``), over the
    rows it can reach: the texture is sheared across the beam by each column's deflection."""
    import cv2

    x0, y0 = beam.root_px
    reach = beam.thickness_px / 2 + 2 * sum(abs(a) for a in beam.tip_amplitudes_px) + 2
    r0, r1 = max(0, int(y0 - reach)), min(scene.height, math.ceil(y0 + reach) + 1)
    c0, c1 = int(x0), min(scene.width, math.ceil(x0 + beam.length_px) + 1)
    xs = np.arange(c0, c1, dtype=np.float64)
    ys = np.arange(r0, r1, dtype=np.float64)[:, None]
    w = beam.deflection_px(t_s, xs, scene.fps)
    dy, dz = np.asarray(beam.bend_direction, np.float64) / math.hypot(*beam.bend_direction)
    v = ys - y0 - (w * dy)[None, :]  # across the beam, from its centre line
    alpha = np.clip(beam.thickness_px / 2 + 0.5 - np.abs(v), 0.0, 1.0).astype(np.float32)
    alpha[:, xs > x0 + beam.length_px] = 0.0
    map_x = np.broadcast_to((xs - x0 + 4)[None, :], v.shape).astype(np.float32)
    map_y = (v + beam.thickness_px / 2 + 4).astype(np.float32)
    colour = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    block = image[r0:r1, c0:c1]
    block[...] = block * (1 - alpha[..., None]) + colour * alpha[..., None]
    z = np.broadcast_to((beam.depth_m + w * dz * beam.depth_m / scene.focal_px)[None, :], v.shape)
    on = alpha >= 0.5
    depth[r0:r1, c0:c1][on] = z[on]
    if mask is not None:
        mask[r0:r1, c0:c1][on] = label


__all__ = ["CANTILEVER_BETA_L", "Beam", "BeamScene", "cantilever_shape", "render_beams"]
