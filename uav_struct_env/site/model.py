"""The construction site as plain data: typed elements, stages, markers and the landmarks they expose.

A :class:`Site` is a list of typed building elements (:mod:`uav_struct_env.site.elements`:
columns, slabs with their openings, beams, walls), the storeys and construction stages as data,
the ArUco markers on the ground, and the stage the site is at. Two producers make sites: the
parametric grid (:func:`~uav_struct_env.site.parametric.building_site`, the paper's building and
random layouts) and the IFC importer (:func:`~uav_struct_env.site.ifc.load_ifc`). Everything
downstream reads the elements only: meshes, collision obstacles, view targets, visibility.

Landmarks are derived from the elements in one place (:mod:`uav_struct_env.site.landmarks`,
which also documents the id allocation). Units are metres, the frame is the project frame
(right-handed, z up).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.elements import Column, Element, Slab, Stage, Storey, check_length
from uav_struct_env.site.ifc_export import write_building
from uav_struct_env.site.landmarks import STRUCTURAL_SETS, LandmarkRegistry, LandmarkSet, exposed_landmarks
from uav_struct_env.site.markers import ArucoMarker

__all__ = ["MAX_GROUND_SIZE", "Site"]

#: Bound on the side of the square textured ground, m.
MAX_GROUND_SIZE = 20_000.0


@dataclass(frozen=True, eq=False)
class Site:
    """A construction site at one stage: the building's elements, its stages and the markers.

    Attributes:
        elements: every element of the building as designed, at all stages.
        storeys: the storeys, bottom up.
        stages: the construction stages in build order (:class:`~uav_struct_env.site.elements.Stage`).
        stage: the stage the site is at: a stage name or alias.
        markers: ArUco markers on the ground.
        ground_size: side of the square textured ground, m.
        name: a readable name (``"paper"``, ``"random"``, the IFC file's stem, ...).
        building: the parametric description the site was made from (a
            :class:`~uav_struct_env.site.parametric.Building`, which site files save), or None for
            an imported site. The site only keeps it: the producers of sites sit above the site.
        source: provenance (for an IFC site: the file, the import report, the transforms).
    """

    elements: tuple[Element, ...]
    storeys: tuple[Storey, ...]
    stages: tuple[Stage, ...]
    stage: str = "columns"
    markers: tuple[ArucoMarker, ...] = ()
    ground_size: float = 160.0
    name: str = "custom"
    building: Hashable | None = None
    source: Mapping[str, Any] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "elements", tuple(self.elements))
        object.__setattr__(self, "stages", tuple(self.stages))
        object.__setattr__(self, "storeys", tuple(self.storeys))
        object.__setattr__(self, "markers", tuple(self.markers))
        self._check_elements_and_stages()
        check_length("ground_size", self.ground_size, MAX_GROUND_SIZE, type_error=SiteGeometryError)
        if not isinstance(self.name, str):
            raise SiteGeometryError(f"site name must be a string, got {self.name!r}")
        self._check_markers()

    def _check_elements_and_stages(self) -> None:
        """Elements of their type with unique guids; unique stage names naming only known elements."""
        if not self.elements:
            raise SiteGeometryError("a site needs at least one building element, got none")
        for e in self.elements:
            if not isinstance(e, Element):
                raise TypeError(f"site elements must be Element objects, got {type(e).__name__}")
        guids = [e.guid for e in self.elements]
        dupes = sorted({g for g in guids if guids.count(g) > 1}) if len(set(guids)) != len(guids) else []
        if dupes:
            raise SiteGeometryError(f"duplicate element guids {dupes[:5]}: every element needs its own")
        if not self.stages:
            raise SiteGeometryError("a site needs at least one construction stage, got none")
        names = self.stage_names
        if len(set(names)) != len(names):
            raise SiteGeometryError(f"stage names must be unique, got {names}")
        if self.stage not in names:
            raise SiteGeometryError(f"stage must be one of {names}, got {self.stage!r}")
        known = set(guids)
        for st in self.stages:
            missing = sorted((st.built | set(st.floor)) - known)
            if missing:
                raise SiteGeometryError(f"stage {st.name!r} names unknown elements {missing[:5]}")

    def _check_markers(self) -> None:
        """Markers with unique ids, on the ground, clear of the building's footprint and of each other."""
        ids = [m.id for m in self.markers]
        dupes = sorted({i for i in ids if ids.count(i) > 1})
        if dupes:
            raise SiteGeometryError(f"duplicate marker ids {dupes}: every marker needs its own id")
        xmin, ymin, xmax, ymax = self.footprint_bounds
        for m in self.markers:
            h = m.footprint_half_extent
            x, y, _ = m.center
            if x + h > xmin and x - h < xmax and y + h > ymin and y - h < ymax:
                raise SiteGeometryError(
                    f"marker {m.id} at ({x}, {y}) lies under the building footprint "
                    f"{self.footprint_bounds}"
                )
            if max(abs(x), abs(y)) + h > self.ground_size / 2 + max(xmax, ymax):
                raise SiteGeometryError(f"marker {m.id} at ({x}, {y}) lies off the ground")
        for i, a in enumerate(self.markers):
            for b in self.markers[i + 1 :]:
                d = max(abs(a.center[0] - b.center[0]), abs(a.center[1] - b.center[1]))
                if d < a.footprint_half_extent + b.footprint_half_extent:
                    raise SiteGeometryError(f"markers {a.id} and {b.id} overlap")

    # ----------------------------------------------------------------------------- identity
    def _key(self) -> tuple:
        if self.building is not None:
            body: tuple = (self.building,)
        else:
            body = tuple(_element_signature(e) for e in self.elements)
        return (body, self.stage, self.markers, self.ground_size, self.name)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Site):
            return NotImplemented
        return self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    # ----------------------------------------------------------------------------- stages
    @property
    def stage_names(self) -> tuple[str, ...]:
        """Every accepted stage name: each stage's name, then its aliases, in build order."""
        return tuple(n for st in self.stages for n in st.names)

    @cached_property
    def current_stage(self) -> Stage:
        """The :class:`Stage` the site is at."""
        return next(st for st in self.stages if self.stage in st.names)

    def with_stage(self, stage: str) -> Site:
        """The same site at another construction stage."""
        return dataclasses.replace(self, stage=stage)

    def with_columns_exposed(self) -> Site:
        """The site at its floor's ``columns`` stage, if the floor has one (else itself).

        The paper's viewpoints are the same at both stages of a floor: they are chosen so that
        the landmarks of both are in view.
        """
        floor = self.current_stage.floor
        later = [st for st in self.stages if st.floor == floor and st.built >= self.current_stage.built]
        return self.with_stage(later[-1].name) if later[-1] is not self.current_stage else self

    def floor_stage(self, role: str) -> str | None:
        """The stage of this site's floor in ``role``, or None if the floor has no such stage.

        ``role`` ``"slab"``: the floor just built (the floor's first stage); ``"columns"``: with
        the columns standing on it (its last stage, if that adds columns). The paper's two
        stages are the first floor's roles; the study evaluates each method in its role. A
        columns-only stage (a frame without a floor, :mod:`uav_struct_env.site.ifc`) is its own
        ``"columns"`` role and has no ``"slab"`` one.
        """
        if role not in ("slab", "columns"):
            raise ValueError(f"role must be 'slab' or 'columns', got {role!r}")
        if not self.current_stage.floor:
            return self.current_stage.name if role == "columns" else None
        same = [st for st in self.stages if st.floor == self.current_stage.floor]
        first, last = same[0], same[-1]
        if role == "slab":
            return first.name
        return last.name if last is not first else None

    # ----------------------------------------------------------------------------- elements
    @cached_property
    def built(self) -> tuple[Element, ...]:
        """The elements standing at this stage, in element order."""
        built = self.current_stage.built
        return tuple(e for e in self.elements if e.guid in built)

    @property
    def columns(self) -> tuple[Column, ...]:
        """All built columns at this stage."""
        return tuple(e for e in self.built if isinstance(e, Column))

    @property
    def slabs(self) -> tuple[Slab, ...]:
        """All built slabs at this stage."""
        return tuple(e for e in self.built if isinstance(e, Slab))

    @cached_property
    def floor(self) -> tuple[Slab, ...]:
        """The slabs of the topmost built structural floor."""
        by_guid = {e.guid: e for e in self.elements}
        return tuple(by_guid[g] for g in self.current_stage.floor)

    @property
    def exposed_columns(self) -> tuple[Column, ...]:
        """Built columns whose top faces are exposed (nothing built covers them)."""
        tops = set(self.landmarks("column_tops").elements)
        return tuple(c for c in self.columns if c.guid in tops)

    @cached_property
    def footprint_bounds(self) -> tuple[float, float, float, float]:
        """Plan bounding box ``(xmin, ymin, xmax, ymax)`` of the whole building (every stage)."""
        b = np.array([e.bounds for e in self.elements])
        return float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())

    @property
    def center(self) -> NDArray[np.float64]:
        """Centre of the building footprint at mid-height of the structure built at this stage."""
        xmin, ymin, xmax, ymax = self.footprint_bounds
        top = max(e.z_top for e in self.built)
        return np.array([(xmin + xmax) / 2, (ymin + ymax) / 2, top / 2])

    def to_ifc(self, path: str | os.PathLike) -> Path:
        """Write the building as IFC4 (:mod:`uav_struct_env.site.ifc_export`; extra ``ifc``)."""
        return write_building(self.name, self.storeys, self.elements, path)

    # ----------------------------------------------------------------------------- landmarks
    @cached_property
    def registry(self) -> LandmarkRegistry:
        """Landmark ids for the whole building (:mod:`uav_struct_env.site.landmarks`)."""
        return LandmarkRegistry(self.elements, self.markers)

    @cached_property
    def _landmark_cache(self) -> dict[str, LandmarkSet]:
        return {}

    def landmarks(self, name: str) -> LandmarkSet:
        """The landmark set ``name`` exposed at this stage (``name``: one of ``LANDMARK_SETS``).

        ``all`` is the structural sets together (not the markers). A set with nothing exposed at
        this stage (``column_tops`` at stage ``slab``) is empty.
        """
        cache = self._landmark_cache
        if name not in cache:
            if name == "all":
                points = [p for n in STRUCTURAL_SETS
                          for p in exposed_landmarks(n, self.built, self.floor, self.markers)]
            else:
                points = exposed_landmarks(name, self.built, self.floor, self.markers)
            cache[name] = self.registry.landmark_set(name, points)
        return cache[name]


def _element_signature(e: Element) -> tuple:
    holes = tuple((h.guid, h.outline.tobytes()) for h in getattr(e, "holes", ()))
    mesh = None if e.mesh is None else (e.mesh.vertices.tobytes(), e.mesh.faces.tobytes())
    return (e.kind, e.guid, e.name, e.storey, e.outline.tobytes(), e.z_bottom, e.z_top, holes, mesh)
