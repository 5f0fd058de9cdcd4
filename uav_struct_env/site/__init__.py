"""The building model (BIM) as plain data: no pybullet, no gymnasium."""

from uav_struct_env.site.model import (
    LANDMARK_SETS,
    STAGES,
    STRUCTURAL_SETS,
    ArucoMarker,
    Building,
    Column,
    ColumnGrid,
    LandmarkSet,
    Opening,
    Site,
    Slab,
)
from uav_struct_env.site.presets import (
    make_site,
    markers_around,
    paper_building,
    paper_site,
    random_site,
)

__all__ = [
    "LANDMARK_SETS",
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
