"""The building model (BIM) as plain data: no pybullet, no gymnasium.

A :class:`Site` is a list of typed elements (:mod:`~uav_struct_env.site.elements`) with its
construction stages and markers; the parametric grid (:mod:`~uav_struct_env.site.parametric`)
and the IFC importer (:mod:`~uav_struct_env.site.ifc`, optional extra ``ifc``) produce them.

Imports point one way, from the plain data up (``tests/site/test_imports.py`` checks it):

* the plain data: ``polygons``, ``elements`` (the element types, stages, storeys), ``markers``;
* what the site derives from it: ``landmarks``, and ``ifc_export`` (the IFC writer);
* the site: ``model`` (:class:`Site`);
* the producers of sites: ``parametric`` (:func:`building_site`), ``ifc`` (:func:`load_ifc`),
  ``io`` (site files) and ``presets``; and what reads a site: ``mesh`` (with ``textures``),
  ``activity``, ``as_built``.
"""

from uav_struct_env.site.elements import Beam, Column, Element, Hole, Slab, Stage, Storey, TriangleMesh, Wall
from uav_struct_env.site.ifc import ImportReport, ifc_report, ifc_stages, load_ifc, write_ifc
from uav_struct_env.site.landmarks import LANDMARK_SETS, STRUCTURAL_SETS, LandmarkSet
from uav_struct_env.site.markers import ArucoMarker
from uav_struct_env.site.model import Site
from uav_struct_env.site.parametric import STAGES, Building, ColumnGrid, Opening, building_site
from uav_struct_env.site.presets import (
    make_site,
    markers_around,
    paper_building,
    paper_site,
    random_site,
)

__all__ = [
    "LANDMARK_SETS",
    "Beam",
    "Element",
    "Hole",
    "ImportReport",
    "Stage",
    "Storey",
    "TriangleMesh",
    "Wall",
    "building_site",
    "ifc_report",
    "ifc_stages",
    "load_ifc",
    "write_ifc",
    "STAGES",
    "STRUCTURAL_SETS",
    "ArucoMarker",
    "Building",
    "Column",
    "ColumnGrid",
    "LandmarkSet",
    "Opening",
    "Site",
    "Slab",
    "make_site",
    "markers_around",
    "paper_building",
    "paper_site",
    "random_site",
]
