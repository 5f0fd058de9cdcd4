"""A calibrated, distorting camera localizes as well as a pinhole: detections undistorted at the entry.

Views through the Mavic 2 Pro preset's lens (12 % barrel at the corners) with 1 px detector noise:
given the coefficients, ``Localizer`` and ``ArucoLocalizer`` match the pinhole camera's errors;
without them they are measurably worse.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from localization import Localizer
from localization.aruco import ArucoLocalizer
from localization.geometry.distortion import check_distortion, distort_points, is_pinhole
from localization.geometry.transforms import camera_center, project
from localization.testing.synthetic import paper_prior, sample_viewpoints

#: The Mavic 2 Pro preset at 1280 x 720 (uav_struct_env.sim.lens.MAVIC2PRO).
K = np.array([[995.0, 0.0, 639.5], [0.0, 995.0, 359.5], [0.0, 0.0, 1.0]])
D = np.array([-0.269478, 0.115681, -8.75619e-5, -3.06177e-4, -0.0357628])


def _views(X: np.ndarray, center: np.ndarray, n: int = 16):
    """(true pose, pinhole uv, distorted uv) of ``n`` views; the same 1 px noise on both."""
    rng = np.random.default_rng(3)
    out = []
    for T in sample_viewpoints(rng, n, center):
        uv, z = project(K, T, X)
        seen = (z > 0) & np.all((uv > 5) & (uv < [1275, 715]), axis=1)
        noise = rng.normal(0.0, 1.0, (int(seen.sum()), 2))
        distorted = cv2.projectPoints(X[seen], cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, D)[0][:, 0]
        out.append((T, uv[seen] + noise, distorted + noise))
    return out


def _median_error(localizer: Localizer, views, which: int) -> float:
    errors = []
    for k, view in enumerate(views):
        T = view[0]
        est = localizer.localize(view[which], paper_prior(T, k))
        errors.append(np.linalg.norm(camera_center(est.cam_from_world) - camera_center(T))
                      if est.success else np.inf)
    return float(np.median(errors))


def test_localizer_with_the_coefficients_is_as_accurate_as_a_pinhole(building, center) -> None:
    _, X = building["column_tops"]
    views = _views(X, center)
    pinhole = _median_error(Localizer(X, K, image_size=(1280, 720)), views, 1)
    calibrated = _median_error(Localizer(X, K, image_size=(1280, 720), distortion=D), views, 2)
    ignored = _median_error(Localizer(X, K, image_size=(1280, 720)), views, 2)
    assert calibrated <= 1.15 * pinhole, (calibrated, pinhole)
    assert ignored >= 3.0 * calibrated, (ignored, calibrated)


def test_aruco_undistorts_the_detected_corners(building, center) -> None:
    from uav_struct_env.site import paper_site

    markers = paper_site(stage="slab", marker_size=1.0).markers
    rng = np.random.default_rng(5)
    with_d, without = ArucoLocalizer(markers, K, dist_coeffs=D), ArucoLocalizer(markers, K)
    err_d, err_none = [], []
    for k, T in enumerate(sample_viewpoints(rng, 16, center)):
        uv, z = project(K, T, with_d.corners_world)
        inside = np.all((uv > 5) & (uv < [1275, 715]), axis=1) & (z > 0)
        ok = inside.reshape(-1, 4).all(axis=1)
        if ok.sum() < 2:
            continue
        ids = np.array([m.id for m in with_d.markers])[ok]
        corners = distort_points(uv, K, D).reshape(-1, 4, 2)[ok] + rng.normal(0, 0.3, (ok.sum(), 4, 2))
        for loc, errs in ((with_d, err_d), (without, err_none)):
            est = loc.localize_corners(ids, corners, paper_prior(T, k))
            assert est.success
            errs.append(np.linalg.norm(camera_center(est.cam_from_world) - camera_center(T)))
    assert len(err_d) >= 8
    assert np.median(err_none) >= 3.0 * np.median(err_d), (np.median(err_none), np.median(err_d))


def test_coefficients_are_checked() -> None:
    np.testing.assert_array_equal(check_distortion("d", None), np.zeros(5))
    np.testing.assert_array_equal(check_distortion("d", [0.1, 0.0, 0.0, 0.0]), [0.1, 0, 0, 0, 0])
    assert is_pinhole(None) and is_pinhole(np.zeros(5)) and not is_pinhole(D)
    with pytest.raises(ValueError, match=r"distortion must hold the 5 OpenCV coefficients .* got 2"):
        Localizer(np.eye(4, 3), K, distortion=(0.1, 0.2))
    with pytest.raises(ValueError, match="must be finite"):
        check_distortion("distortion", [np.nan, 0, 0, 0, 0])
    with pytest.raises(TypeError, match="must be numbers"):
        check_distortion("distortion", ["a"] * 5)
