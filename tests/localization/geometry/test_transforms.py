"""The conventions of localization.geometry.transforms against their numpy definitions."""

from __future__ import annotations

import numpy as np

from localization.geometry import invert, look_at


def _look_at_numpy(eye, target, up=(0.0, 0.0, 1.0)):
    """look_at written with np.cross and np.linalg.inv: the definition it must equal."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3] = np.column_stack([x, y, z])
    world_from_cam[:3, 3] = eye
    return world_from_cam


def test_look_at_equals_its_numpy_definition_bit_for_bit():
    """Its cross products on Python floats are np.cross's to the bit."""
    rng = np.random.default_rng(0)
    for _ in range(2000):
        eye = rng.normal(size=3) * 10 ** rng.uniform(-4, 4)
        target = eye + rng.normal(size=3)
        rotation = invert(look_at(eye, target))[:3, :3]  # transposes: exact
        np.testing.assert_array_equal(rotation, _look_at_numpy(eye, target)[:3, :3])


def test_scaled_intrinsics_moves_projections_as_the_pixel_edges_scale():
    """A point projects at ``(u + 0.5) s - 0.5`` in the resized image: integer pixel centres in both."""
    from localization.geometry import project, scaled_intrinsics
    from localization.geometry.camera import PAPER_K

    points = np.random.default_rng(3).uniform([-5, -5, 10], [5, 5, 40], (20, 3))
    uv, _ = project(PAPER_K, np.eye(4), points)
    for sx, sy in ((0.25, 0.25), (0.5, 1.5)):
        small, _ = project(scaled_intrinsics(PAPER_K, sx, sy), np.eye(4), points)
        np.testing.assert_allclose(small, (uv + 0.5) * [sx, sy] - 0.5, atol=1e-9)
    assert scaled_intrinsics(PAPER_K, 0.5, 0.5)[2].tolist() == [0.0, 0.0, 1.0]


def test_kernel_array_is_c_contiguous_and_writable_and_copies_only_when_it_must():
    from localization.geometry.kernels import kernel_array

    mine = np.arange(12.0).reshape(3, 4)
    assert kernel_array(mine) is mine and kernel_array(mine, dtype=np.float64) is mine
    frozen = mine.copy()
    frozen.flags.writeable = False  # as a site's landmarks are
    for odd in (frozen, np.asfortranarray(mine), mine[:, ::2], np.arange(12).reshape(3, 4)):
        out = kernel_array(odd, dtype=np.float64)
        assert out.flags.c_contiguous and out.flags.writeable and out.dtype == np.float64
        np.testing.assert_array_equal(out, odd)
    assert frozen.flags.writeable is False and not np.shares_memory(kernel_array(frozen), frozen)
