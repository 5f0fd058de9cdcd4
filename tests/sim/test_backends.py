"""The two backends give the same geometry; marker textures are detectable in the right order."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from localization.geometry.transforms import look_at, project
from uav_struct_env.sim.camera import Camera


def test_backends_agree_on_geometry(paper_world, egl_ok):
    if not egl_ok:
        pytest.skip("EGL rendering is unavailable on this machine")
    camera = Camera().scaled(640, 360)
    tiny, egl = paper_world("columns", "tiny"), paper_world("columns", "egl")
    assert tiny.body_ids == egl.body_ids
    pose = look_at([-22.0, -16.0, 14.0], tiny.site.center)
    a = tiny.render(pose, camera, depth=True, segmentation=True)
    b = egl.render(pose, camera, depth=True, segmentation=True)
    assert (a.segmentation == b.segmentation).mean() > 0.995
    compared = 0
    for body in tiny.body_ids.values():
        ma, mb = a.segmentation == body, b.segmentation == body
        if ma.sum() < 200:
            continue
        ca, cb = (np.argwhere(m).mean(axis=0) for m in (ma, mb))
        assert np.abs(ca - cb).max() < 0.25, (body, ca - cb)
        compared += 1
    assert compared >= 20
    same = (a.segmentation == b.segmentation) & (a.segmentation >= 0)
    rel = np.abs(a.depth[same] - b.depth[same]) / a.depth[same]
    assert np.median(rel) < 1e-3 and np.percentile(rel, 99) < 1e-2
    for name in ("column_tops", "slab_corners", "aruco"):
        ta = tiny.landmark_truth(name, pose, camera, a)
        tb = egl.landmark_truth(name, pose, camera, b)
        np.testing.assert_array_equal(ta["visible"], tb["visible"])
        np.testing.assert_allclose(ta["uv"], tb["uv"])


def test_marker_detected_with_corners_in_opencv_order(backend, paper_world):
    world = paper_world("columns", backend)
    camera = Camera()
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50), cv2.aruco.DetectorParameters()
    )
    for marker in (world.site.markers[0], world.site.markers[5]):
        centre = np.array(marker.center)
        # Above the marker, slightly oblique, image "up" along a diagonal so no axis is special.
        pose = look_at(centre + [1.5, -2.0, 7.0], centre, up=(1.0, 1.0, 0.0))
        gray = cv2.cvtColor(world.render(pose, camera).rgb, cv2.COLOR_RGB2GRAY)
        corners, ids, _ = detector.detectMarkers(gray)
        assert ids is not None, f"marker {marker.id} not detected ({backend})"
        found = dict(zip(ids.ravel().tolist(), corners, strict=False))
        assert marker.id in found, (marker.id, ids.ravel())
        expected, _ = project(camera.K, pose, marker.corners_world)
        err = np.linalg.norm(found[marker.id].reshape(4, 2) - expected, axis=1)
        assert err.max() < 1.5, f"marker {marker.id} corners off by {err} px ({backend})"
