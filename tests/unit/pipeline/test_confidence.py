"""Flow confidence from the image (workers.pipeline.confidence): flat, clipped and noise-level texture
weigh nothing; along an edge only the normal component of the flow counts."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from workers.pipeline.confidence import constrained_flow, flow_confidence, structure_tensor, tensor_sqrt


def _texture(h: int = 48, w: int = 64, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.uniform(40, 200, (h, w)).astype(np.float32), (0, 0), 1.0)


def test_texture_weighs_and_flatness_does_not():
    image = np.full((48, 64), 120.0, np.float32)
    image[:, 32:] = _texture()[:, 32:]
    conf = flow_confidence(image, frame_noise=1.0)
    assert float(np.median(conf.weight[:, 40:])) > 0.9
    assert float(conf.weight[:, :28].max()) < 0.05


def test_faint_shading_is_flat_against_one_frame_noise():
    """A wall shaded by a few grey levels across the picture: its gradient is far below what one frame's
    noise gives, so its flow is noise (whatever the mean frame's own smoothness)."""
    y, x = np.mgrid[0:48, 0:64].astype(np.float32)
    shading = 120 + 4 * x / 64 + 2 * y / 48
    assert float(flow_confidence(shading, frame_noise=1.0).weight.max()) < 0.05


def test_clipped_pixels_weigh_nothing():
    image = _texture()
    image[10:20, 10:20] = 255
    conf = flow_confidence(image, frame_noise=1.0)
    assert float(conf.weight[12:18, 12:18].max()) == 0.0


def test_tensor_square_root_squares_back():
    conf = flow_confidence(_texture(), frame_noise=1.0)
    a, b, c = tensor_sqrt(conf)
    np.testing.assert_allclose(a * a + b * b, conf.jxx, rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(a * b + b * c, conf.jxy, rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(b * b + c * c, conf.jyy, rtol=1e-3, atol=1e-3)


def test_along_an_edge_only_the_normal_motion_counts():
    """A vertical edge (the gradient along x): flow along the edge (y) is not seen, flow across it is."""
    image = np.full((32, 32), 60.0, np.float32)
    image[:, 16:] = 180.0
    conf = flow_confidence(image, frame_noise=1.0)
    along = np.zeros((32, 32, 2), np.float32)
    along[..., 1] = 1.0
    across = np.zeros((32, 32, 2), np.float32)
    across[..., 0] = 1.0
    z_along = constrained_flow(along, conf)[14:18, 14:18]
    z_across = constrained_flow(across, conf)[14:18, 14:18]
    assert float(np.abs(z_along).max()) < 1e-3 * float(np.abs(z_across).max())


def test_isotropic_texture_keeps_the_flow_s_direction():
    image = _texture()
    jxx, _jxy, jyy = structure_tensor(image)
    conf = flow_confidence(image, frame_noise=1.0)
    flow = np.zeros((2, 48, 64, 2), np.float32)
    flow[0, ..., 0] = 0.5
    flow[1, ..., 1] = 0.5
    z = constrained_flow(flow, conf)
    assert z.shape == flow.shape
    power_x = (z[0] ** 2).sum(axis=-1)
    power_y = (z[1] ** 2).sum(axis=-1)
    # u^T J u: the x motion weighs by Jxx, the y motion by Jyy.
    np.testing.assert_allclose(power_x, 0.25 * jxx, rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(power_y, 0.25 * jyy, rtol=1e-3, atol=1e-4)


def test_grids_must_match():
    conf = flow_confidence(_texture(), frame_noise=1.0)
    with pytest.raises(ValueError, match="grid"):
        constrained_flow(np.zeros((3, 10, 10, 2), np.float32), conf)


def test_spectra_of_the_constrained_flow_need_no_copy_of_it():
    """``pixel_spectra(..., mix=tensor_sqrt(conf))`` transforms J^(1/2) u block by block: the same spectra
    as those of ``constrained_flow``'s copy, a window's worth of memory less."""
    from workers.pipeline.spectra import pixel_spectra

    conf = flow_confidence(_texture(37, 41), frame_noise=1.0)
    flow = np.random.default_rng(3).standard_normal((300, 37, 41, 2)).astype(np.float32)
    copied = pixel_spectra(constrained_flow(flow, conf), sample_rate_hz=100.0).power
    mixed = pixel_spectra(flow, sample_rate_hz=100.0, mix=tensor_sqrt(conf)).power
    np.testing.assert_allclose(mixed, copied, rtol=1e-5, atol=1e-6 * float(copied.max()))
    whole = constrained_flow(flow, conf)
    np.testing.assert_array_equal(constrained_flow(flow[7], conf), whole[7])  # one map as in a window
