import numpy as np
import pytest

from localization.aruco import ArucoLocalizer, MarkerSpec, marker_corners
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import look_at, make_transform
from localization.metrics import pose_errors
from localization.testing.synthetic import paper_prior, render_aruco_image

# the paper site's eight markers: flat on the ground, facing up, 1 m
CENTRES = [(2, -3.3), (6, -3.3), (2, 14.3), (6, 14.3), (-3.3, 3), (-3.3, 8), (11.3, 3), (11.3, 8)]
MARKERS = [(i, 1.0, make_transform(np.eye(3), [x, y, 0.01])) for i, (x, y) in enumerate(CENTRES)]


def test_marker_corner_order_matches_opencv():
    c = marker_corners(2.0)
    np.testing.assert_allclose(c, [[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]])


@pytest.mark.parametrize("mode", ["average", "joint"])
def test_localize_synthetic_image(mode):
    loc = ArucoLocalizer(MARKERS, PAPER_K, mode=mode)
    for k, eye in enumerate([(4, -14, 12), (20, 5.5, 14), (-8, 16, 11)]):
        T = look_at(eye, (4, 5.5, 0))
        img = render_aruco_image(MARKERS, PAPER_K, T)
        est = loc.localize(img, paper_prior(T, k))
        assert est.success, est.failure_reason
        t, r = pose_errors(est.cam_from_world, T)
        limit = (0.1, 0.5) if mode == "joint" else (1.0, 3.0)
        assert t < limit[0] and r < limit[1], (t, r)
        assert est.n_inliers % 4 == 0 and est.n_inliers >= 4
        assert "detect" in est.timings and np.all(np.isfinite(est.covariance))


def test_single_marker_is_enough_and_rgb_accepted():
    loc = ArucoLocalizer(MARKERS[:1], PAPER_K, mode="joint")
    T = look_at((2, -10, 8), (2, -3.3, 0))
    img = render_aruco_image(MARKERS[:1], PAPER_K, T)
    est = loc.localize(np.dstack([img] * 3), paper_prior(T, 5))
    assert est.success and est.n_inliers == 4
    assert pose_errors(est.cam_from_world, T)[0] < 0.3


def test_no_marker_fails_with_prior_fallback():
    loc = ArucoLocalizer(MARKERS, PAPER_K)
    prior = look_at((4, -14, 12), (4, 5.5, 0))
    est = loc.localize(np.full((720, 1280), 120, np.uint8), prior)
    assert not est.success and "no known marker" in est.failure_reason
    np.testing.assert_array_equal(est.cam_from_world, prior)


def test_marker_objects_and_errors():
    class Obj:
        def __init__(self, i, s, T):
            self.id, self.side, self.world_from_marker = i, s, T

    loc = ArucoLocalizer([Obj(*m) for m in MARKERS], PAPER_K)
    assert loc.corners_world.shape == (32, 3)
    assert isinstance(loc.markers[0], MarkerSpec)
    with pytest.raises(ValueError, match="mode"):
        ArucoLocalizer(MARKERS, PAPER_K, mode="median")
    with pytest.raises(ValueError, match="unique"):
        ArucoLocalizer(MARKERS[:1] * 2, PAPER_K)
    with pytest.raises(ValueError, match=r"markers\[0\] side"):
        ArucoLocalizer([(0, -1.0, np.eye(4))], PAPER_K)
    with pytest.raises(TypeError, match="image must be uint8"):
        loc.localize(np.zeros((10, 10)), np.eye(4))
    with pytest.raises(ValueError, match="corners must have shape"):
        loc.localize_corners([1], np.zeros((1, 3, 2)), None)
