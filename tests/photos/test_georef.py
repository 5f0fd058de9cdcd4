import math

import numpy as np
import pytest

from uav_struct_env.photos import Georeference, PhotoError, read_ifc_georeference
from uav_struct_env.photos.georef import read_control_points, utm_crs


def test_ifc_map_conversion_is_read_with_its_crs(georef_ifc):
    g = read_ifc_georeference(georef_ifc)
    assert g.crs == "EPSG:32632" and g.source == "IfcMapConversion"
    assert g.origin_m == (691000.0, 5334000.0, 500.0)
    assert g.rotation_rad == pytest.approx(0.3)
    assert g.scale == (1.0, 1.0, 1.0)


def test_an_ifc_without_georeferencing_gives_none(plain_ifc):
    assert read_ifc_georeference(plain_ifc) is None


def test_project_origin_maps_to_the_stated_eastings_northings():
    g = Georeference((691000.0, 5334000.0, 500.0), 0.3, crs="EPSG:32632")
    expected = [[691000, 5334000, 500], [691000 + math.cos(0.3), 5334000 + math.sin(0.3), 500]]
    np.testing.assert_allclose(g.map_from_project([[0, 0, 0], [1, 0, 0]]), expected)


@pytest.mark.parametrize("scale", [1.0, 0.001])
def test_wgs84_round_trip_below_a_millimetre(rng, scale):
    # scale 0.001: the map conversion of a millimetre file read as project metres x 1000 (a test of the
    # formula; read_ifc_georeference folds the units into the scale)
    g = Georeference((691000.0, 5334000.0, 500.0), 0.3, scale=(scale,) * 3, crs="EPSG:32632")
    xyz = rng.uniform(-300, 300, (200, 3))
    back = g.project_from_wgs84(g.wgs84_from_project(xyz))
    assert np.abs(back - xyz).max() * scale < 1e-3


def test_the_enu_rotation_holds_the_grid_convergence():
    # on the central meridian (9 deg E for zone 32) grid and true north agree: only the project's rotation
    g = Georeference((500000.0, 5334000.0, 0.0), 0.3, crs="EPSG:32632")
    lat, lon, _ = g.wgs84_from_project([[0, 0, 0]])[0]
    assert lon == pytest.approx(9.0, abs=1e-6)
    R = g.project_from_enu(lat, lon)
    assert math.atan2(R[1, 0], R[0, 0]) == pytest.approx(-0.3, abs=1e-6)
    # 2.57 deg east of it at 48.1 deg N the convergence is ~ (lon - 9) sin(lat) = 1.91 deg
    g2 = Georeference((691000.0, 5334000.0, 0.0), 0.0, crs="EPSG:32632")
    lat2, lon2, _ = g2.wgs84_from_project([[0, 0, 0]])[0]
    R2 = g2.project_from_enu(lat2, lon2)
    expected = math.radians((lon2 - 9.0) * math.sin(math.radians(lat2)))
    assert math.atan2(R2[1, 0], R2[0, 0]) == pytest.approx(expected, abs=2e-4)


def test_user_string_and_its_refusals():
    g = Georeference.from_string("691000,5334000,500,17.1887,32632")
    assert g.crs == "EPSG:32632" and g.rotation_rad == pytest.approx(math.radians(17.1887))
    with pytest.raises(PhotoError, match=r"E,N,H,rotation_deg,EPSG \(5 fields\), got '1,2,3'"):
        Georeference.from_string("1,2,3")
    with pytest.raises(PhotoError, match="not a projected CRS"):
        Georeference.from_string("1,2,3,0,4326")
    with pytest.raises(PhotoError, match="not a coordinate reference system"):
        Georeference.from_string("1,2,3,0,99999999")


def test_control_points_recover_the_map_conversion(rng, tmp_path):
    truth = Georeference((691000.0, 5334000.0, 500.0), 0.3, crs="EPSG:32632")
    xyz = rng.uniform(-50, 50, (5, 3))
    lla = truth.wgs84_from_project(xyz)
    path = tmp_path / "cp.csv"
    path.write_text("x,y,z,lat,lon,alt\n" + "\n".join(",".join(f"{v:.10f}" for v in row)
                                                     for row in np.hstack([xyz, lla])))
    fit = Georeference.from_control_points(*read_control_points(path))
    assert fit.crs == utm_crs(*lla[0, :2]) == "EPSG:32632"
    assert fit.residual_m < 1e-3
    probe = rng.uniform(-100, 100, (20, 3))
    assert np.abs(fit.project_from_wgs84(truth.wgs84_from_project(probe)) - probe).max() < 1e-3


def test_control_points_refused_when_too_few_or_collinear(tmp_path):
    with pytest.raises(PhotoError, match="need >= 3"):
        Georeference.from_control_points([[0, 0, 0], [1, 0, 0]], [[48, 11, 0], [48, 11.0001, 0]])
    xyz = [[0, 0, 0], [1, 0, 0], [2, 0, 0]]
    lla = [[48, 11, 0], [48, 11.00001, 0], [48, 11.00002, 0]]
    with pytest.raises(PhotoError, match="collinear"):
        Georeference.from_control_points(xyz, lla)
    bad = tmp_path / "cp.csv"
    bad.write_text("1,2,3,4,5\n")
    with pytest.raises(PhotoError, match=r"line 1: expected x,y,z,lat,lon,alt"):
        read_control_points(bad)


def test_map_conversion_fields_survive_the_importer(georef_ifc, map_conversion):
    from uav_struct_env.site import load_ifc

    source = load_ifc(georef_ifc, "Level 1/slab").source["map_conversion"]
    assert source["target_crs"] == map_conversion["crs"] and source["eastings"] == map_conversion["eastings"]
