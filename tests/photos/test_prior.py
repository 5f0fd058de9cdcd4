import math

import numpy as np
import pytest

from uav_struct_env.photos import Georeference, PhotoError, prior_from_metadata
from uav_struct_env.photos.metadata import PhotoMetadata
from uav_struct_env.photos.prior import (
    CONSUMER_M,
    RTK_FIXED_M,
    RTK_FLOAT_M,
    RTK_FLOOR_M,
    prior_from_string,
    prior_sigmas,
)

G = Georeference((691000.0, 5334000.0, 500.0), 0.3, crs="EPSG:32632")
GIMBAL = {"GimbalYawDegree": 10.0, "GimbalPitchDegree": -30.0, "GimbalRollDegree": 0.0}


def _meta(tmp_path, **kw):
    lat, lon, _ = G.wgs84_from_project([[5.0, -20.0, 0.0]])[0]
    base = {"latitude_deg": lat, "longitude_deg": lon, "dji": {"AbsoluteAltitude": 515.0, **GIMBAL}}
    return PhotoMetadata(tmp_path / "p.jpg", (640, 360), **{**base, **kw})


def test_the_prior_sits_where_the_metadata_says(tmp_path):
    prior = prior_from_metadata(_meta(tmp_path), G)
    np.testing.assert_allclose(prior.position, [5.0, -20.0, 15.0], atol=1e-6)
    assert prior.sigmas.position_m == (CONSUMER_M[0], CONSUMER_M[0], CONSUMER_M[1])
    assert "consumer GNSS" in prior.source


def test_takeoff_height_plus_relative_altitude(tmp_path):
    meta = _meta(tmp_path, dji={"AbsoluteAltitude": 999.0, "RelativeAltitude": 12.5, **GIMBAL})
    prior = prior_from_metadata(meta, G, takeoff_z=0.75)
    assert prior.position[2] == pytest.approx(13.25)
    assert prior.sigmas.position_m[2] == 1.0


def test_rtk_fixed_takes_the_stds_or_the_defaults(tmp_path):
    meta = _meta(tmp_path, dji={"RtkFlag": 50, "RtkStdLon": 0.031, "RtkStdLat": 0.034, "RtkStdHgt": 0.05})
    sigmas, case = prior_sigmas(meta)
    assert sigmas.position_m == (0.034, 0.034, 0.05) and case == "RTK fixed (RtkStd)"
    tiny = _meta(tmp_path, dji={"RtkFlag": 50, "RtkStdLon": 0.001, "RtkStdLat": 0.001, "RtkStdHgt": 0.001})
    assert prior_sigmas(tiny)[0].position_m == (RTK_FLOOR_M,) * 3
    sigmas, case = prior_sigmas(_meta(tmp_path, dji={"RtkFlag": 50}))
    assert sigmas.position_m == (RTK_FIXED_M[0], RTK_FIXED_M[0], RTK_FIXED_M[1])
    assert sigmas.rotation_rad[2] == pytest.approx(math.radians(5.0))


@pytest.mark.parametrize("flag, case", [(34, "RTK float"), (32, "RTK float"), (49, "RTK float"),
                                        (16, "consumer GNSS"), (0, "consumer GNSS")])
def test_rtk_flags_below_fixed_as_dji_documents_them(tmp_path, flag, case):
    # DJI: 0 no position, 16 single point, 32-49 float, 50 fixed
    sigmas, got = prior_sigmas(_meta(tmp_path, dji={"RtkFlag": flag}))
    assert got == case
    assert sigmas.position_m[0] == (RTK_FLOAT_M[0] if case == "RTK float" else CONSUMER_M[0])


def test_a_photo_without_a_prior_is_refused_naming_what_is_missing(tmp_path):
    meta = PhotoMetadata(tmp_path / "p.jpg", (640, 360), dji={"GimbalYawDegree": 1.0})
    missing = r"lacks a GPS position .*; an altitude .*; the gimbal attitude .*--prior"
    with pytest.raises(PhotoError, match=missing):
        prior_from_metadata(meta, G)


def test_user_prior_uses_the_project_convention():
    prior = prior_from_string("1,2,20,90,30,0")
    np.testing.assert_allclose(prior.position, [1, 2, 20])
    axis = np.linalg.inv(prior.cam_from_world)[:3, 2]  # optical axis: +y, 30 deg down
    np.testing.assert_allclose(axis, [0, math.cos(math.radians(30)), -math.sin(math.radians(30))], atol=1e-12)
    with pytest.raises(PhotoError, match=r"x,y,z,yaw,pitch,roll \(6 numbers"):
        prior_from_string("1,2,3")
