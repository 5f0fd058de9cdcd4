"""Photo-test fixtures: the paper site written as a georeferenced IFC (IfcMapConversion, UTM 32N)."""

from __future__ import annotations

import math

import pytest

from uav_struct_env.site import paper_site
from uav_struct_env.site.ifc_export import write_building

#: The map conversion written into the test IFC: Munich, UTM zone 32N, x axis 17.19 deg from east.
MAP_CONVERSION = {"crs": "EPSG:32632", "eastings": 691000.0, "northings": 5334000.0,
                  "orthogonal_height": 500.0, "x_axis_abscissa": math.cos(0.3),
                  "x_axis_ordinate": math.sin(0.3)}


@pytest.fixture(scope="session")
def map_conversion() -> dict:
    """The fields of :data:`MAP_CONVERSION`."""
    return dict(MAP_CONVERSION)


@pytest.fixture(scope="session")
def georef_ifc(tmp_path_factory):
    """The paper site (all stages) as IFC4 with IfcMapConversion + IfcProjectedCRS."""
    site = paper_site("slab")
    path = tmp_path_factory.mktemp("ifc") / "paper_georef.ifc"
    return write_building(site.name, site.storeys, site.elements, path, map_conversion=MAP_CONVERSION)


@pytest.fixture(scope="session")
def plain_ifc(tmp_path_factory):
    """The same building without georeferencing."""
    site = paper_site("slab")
    path = tmp_path_factory.mktemp("ifc") / "paper_plain.ifc"
    return write_building(site.name, site.storeys, site.elements, path)
