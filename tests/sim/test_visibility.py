"""landmark_visibility on synthetic depth maps: no pybullet involved."""

from __future__ import annotations

import numpy as np
import pytest

from localization.geometry.transforms import look_at, project
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.visibility import depth_tolerance, landmark_visibility
from uav_struct_env.site import paper_site

CAMERA = Camera().scaled(320, 180)
POSE = look_at([0.0, -30.0, 10.0], [0.0, 0.0, 2.0])


def _depth_of(points, fill):
    """A depth image that is ``fill`` everywhere except the landmark pixels, at landmark depth."""
    uv, z = project(CAMERA.K, POSE, points)
    depth = np.full((CAMERA.height, CAMERA.width), fill, np.float32)
    for (u, v), d in zip(np.rint(uv).astype(int), z, strict=False):
        if 0 <= u < CAMERA.width and 0 <= v < CAMERA.height:
            depth[v, u] = d
    return depth, uv, z


def test_point_on_rendered_surface_is_visible(rng):
    pts = rng.uniform([-5, -3, 0], [5, 3, 5], (20, 3))
    depth, uv, _ = _depth_of(pts, fill=1.0)  # everything else is right in front of the camera
    truth = landmark_visibility(pts, POSE, CAMERA, depth, ids=np.arange(20) + 300)
    assert truth["in_frame"].all() and truth["visible"].all()
    np.testing.assert_array_equal(truth["ids"], np.arange(20) + 300)
    np.testing.assert_allclose(truth["uv"], uv)
    assert truth["xyz"].shape == (20, 3) and truth["uv"].dtype == np.float64


def test_surface_in_front_occludes_and_tolerance_grows_with_distance():
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 20.0, 2.0]])  # about 32 m and 50 m away
    _, z = project(CAMERA.K, POSE, pts)
    tol = depth_tolerance(z, CAMERA)
    assert tol[1] > tol[0] > 0.03
    for k in range(2):
        near_miss = np.full((CAMERA.height, CAMERA.width), z[k] - 0.5 * tol[k], np.float32)
        occluded = np.full((CAMERA.height, CAMERA.width), z[k] - 2.0 * tol[k], np.float32)
        assert landmark_visibility(pts[k:k + 1], POSE, CAMERA, near_miss)["visible"][0]
        assert not landmark_visibility(pts[k:k + 1], POSE, CAMERA, occluded)["visible"][0]


def test_convex_edge_any_neighbour_behind_counts():
    pt = np.array([[0.0, 0.0, 2.0]])
    uv, z = project(CAMERA.K, POSE, pt)
    depth = np.full((CAMERA.height, CAMERA.width), z[0] - 1.0, np.float32)  # occluder ...
    u, v = np.rint(uv[0]).astype(int)
    depth[v + 1, u + 1] = z[0] + 5.0  # ... except one diagonal neighbour sees past the edge
    assert landmark_visibility(pt, POSE, CAMERA, depth)["visible"][0]
    assert not landmark_visibility(pt, POSE, CAMERA, depth, radius=0)["visible"][0]


def test_out_of_frame_and_behind_camera():
    pts = np.array([[200.0, 0.0, 2.0], [0.0, -60.0, 2.0], [0.0, -30.0, 10.0]])
    depth = np.full((CAMERA.height, CAMERA.width), 1e3, np.float32)
    truth = landmark_visibility(pts, POSE, CAMERA, depth)
    assert not truth["in_frame"].any() and not truth["visible"].any()
    assert np.isfinite(truth["uv"][0]).all()  # in front, outside the image: uv still reported
    assert np.isnan(truth["uv"][1:]).all()  # behind / at the camera centre


def test_image_border_is_half_a_pixel_out():
    W, H = CAMERA.width, CAMERA.height
    rays = np.array(
        [[-0.49, 10.0, 1.0], [W - 0.51, 10.0, 1.0], [-0.51, 10.0, 1.0], [W - 0.49, 10.0, 1.0]]
    )
    cam_pts = (np.linalg.solve(CAMERA.K, rays.T) * 20.0).T
    world = (np.linalg.inv(POSE) @ np.c_[cam_pts, np.ones(4)].T).T[:, :3]
    depth = np.full((H, W), 1e3, np.float32)
    truth = landmark_visibility(world, POSE, CAMERA, depth)
    np.testing.assert_array_equal(truth["in_frame"], [True, True, False, False])


def test_accepts_landmark_sets():
    tops = paper_site("columns").landmarks("column_tops")
    depth = np.full((CAMERA.height, CAMERA.width), 1e3, np.float32)
    truth = landmark_visibility(tops, POSE, CAMERA, depth)
    np.testing.assert_array_equal(truth["ids"], tops.ids)
    assert truth["ids"].dtype == np.int64 and truth["visible"].dtype == bool


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"depth": np.zeros((10, 10))}, ValueError, r"depth must have the camera.s shape \(H, W\)"),
        ({"depth": None}, TypeError, "depth must be"),
        ({"cam_from_world": np.eye(3)}, ValueError, "cam_from_world"),
        ({"landmarks": np.zeros((3, 2))}, ValueError, "landmarks must have shape"),
        ({"camera": "cam"}, TypeError, "camera must be"),
        ({"ids": np.arange(2)}, ValueError, "ids must be"),
        ({"radius": -1}, ValueError, "radius"),
    ],
)
def test_bad_inputs_raise(kwargs, error, match):
    args = {
        "landmarks": np.zeros((3, 3)),
        "cam_from_world": POSE,
        "camera": CAMERA,
        "depth": np.ones((CAMERA.height, CAMERA.width)),
    }
    args.update({k: v for k, v in kwargs.items() if k in args})
    extra = {k: v for k, v in kwargs.items() if k not in args}
    with pytest.raises(error, match=match):
        landmark_visibility(
            args["landmarks"], args["cam_from_world"], args["camera"], args["depth"], **extra
        )
