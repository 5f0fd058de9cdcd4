"""DJI gimbal angles -> project-frame pose, checked against a render.

The camera's true azimuth to the building comes from pyproj's geodesic (independent of the ENU
and grid-convergence maths under test); the pose built from it must render the building at the
image centre, and the building's east side on the image's right.
"""

import math

import numpy as np
import pytest

from localization.geometry.transforms import project
from uav_struct_env.photos import Georeference, prior_from_metadata
from uav_struct_env.photos.attitude import dji_angles_from_enu_from_cam, enu_from_cam_from_dji
from uav_struct_env.photos.metadata import PhotoMetadata
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site

CAMERA = Camera(width=320, height=180, fx=277.125, fy=277.125, cx=159.5, cy=89.5)


def test_known_dji_attitudes_in_enu():
    # yaw 90 (east), level: the optical axis (camera z) points east, image right (camera x) south
    R = enu_from_cam_from_dji(90.0, 0.0, 0.0)
    np.testing.assert_allclose(R[:, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)
    # pitch -90: straight down, image top (-camera y) towards the heading (north at yaw 0)
    R = enu_from_cam_from_dji(0.0, -90.0, 0.0)
    np.testing.assert_allclose(R[:, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(-R[:, 1], [0, 1, 0], atol=1e-12)
    # roll +10 (right side down): image right (camera x) tilts below the horizon
    assert enu_from_cam_from_dji(0.0, 0.0, 10.0)[2, 0] == pytest.approx(-math.sin(math.radians(10)))


def test_angles_round_trip(rng):
    for yaw, pitch, roll in rng.uniform([-179, -89, -30], [179, 89, 30], (50, 3)):
        back = dji_angles_from_enu_from_cam(enu_from_cam_from_dji(yaw, pitch, roll))
        np.testing.assert_allclose(back, (yaw, pitch, roll), atol=1e-9)


def test_a_dji_attitude_aimed_by_geodesic_azimuth_renders_the_building_centred(tmp_path):
    import pyproj

    site = paper_site("slab")
    g = Georeference((691000.0, 5334000.0, 500.0), 0.3, crs="EPSG:32632")
    target = site.center
    cam = target + np.array([9.0, -24.0, 13.0])
    (lat, lon, alt), (tlat, tlon, _) = g.wgs84_from_project([cam, target])
    azimuth = pyproj.Geod(ellps="WGS84").inv(lon, lat, tlon, tlat)[0]  # true azimuth, from north clockwise
    pitch = -math.degrees(math.atan2(cam[2] - target[2], math.hypot(*(cam[:2] - target[:2]))))
    meta = PhotoMetadata(tmp_path / "p.jpg", (320, 180), latitude_deg=lat, longitude_deg=lon,
                         dji={"AbsoluteAltitude": alt, "GimbalYawDegree": azimuth,
                              "GimbalPitchDegree": pitch, "GimbalRollDegree": 0.0})
    pose = prior_from_metadata(meta, g)
    np.testing.assert_allclose(pose.position, cam, atol=1e-6)
    uv, _ = project(CAMERA.K, pose.cam_from_world, [target])
    np.testing.assert_allclose(uv[0], [159.5, 89.5], atol=0.5)  # geodesic vs grid: < 0.1 deg here
    world = SiteWorld(site, renderer="tiny", rng=np.random.default_rng(0))
    try:
        result = world.render(pose.cam_from_world, CAMERA, segmentation=True)
        slab = world.body_ids[f"slab {site.slabs[0].name}"]
        assert result.segmentation[89, 159] == slab
        west, east = min(site.columns, key=lambda c: c.axis[0]), max(site.columns, key=lambda c: c.axis[0])
        (uw, _), (ue, _) = project(CAMERA.K, pose.cam_from_world,
                                   [[*west.axis, west.z_top], [*east.axis, east.z_top]])[0]
        assert ue > uw
    finally:
        world.close()
