"""An IFC building has no markers; the site made from it (what the env flies over) has eight."""

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ifcopenshell")

from uav_struct_env.site import make_site  # noqa: E402
from uav_struct_env.site.ifc import load_ifc  # noqa: E402

DUPLEX = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"


def test_load_ifc_has_no_markers_and_make_site_adds_the_eight_the_env_shows():
    building = load_ifc(DUPLEX)
    assert building.markers == () and len(building.landmarks("aruco").ids) == 0
    site = make_site(str(DUPLEX))
    assert len(site.markers) == 8 and {m.side for m in site.markers} == {1.0}
    corners = site.landmarks("aruco")
    assert len(corners.ids) == 32 and len(set(corners.elements)) == 8
    # on the ground, outside the building's footprint (two per side, 3 m out)
    assert np.allclose(corners.xyz[:, 2], 0.01)
    bounds = np.array([e.bounds for e in building.elements])
    lo, hi = bounds[:, :2].min(0), bounds[:, 2:4].max(0)
    inside = np.all((corners.xyz[:, :2] > lo) & (corners.xyz[:, :2] < hi), axis=1)
    assert not inside.any()
    # the structural landmarks are the building's either way
    assert np.array_equal(site.landmarks("slab_corners").xyz, building.landmarks("slab_corners").xyz)
