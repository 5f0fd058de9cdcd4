"""Landmarks derived from a site's elements, in one place, with ids allocated once per building.

Which landmarks a stage exposes to the air:

==================  ==========================================================================
set                 landmarks
==================  ==========================================================================
``slab_corners``    the corners of the outline of each slab of the stage's topmost built
                    structural floor (outline order: counter-clockwise from min y, then min x):
                    its vertices where it turns by at least :data:`MIN_CORNER_TURN_DEG`
``opening_corners`` the corners of every opening through those slabs, same order and rule
``column_tops``     the top centre of every built column that no built slab or beam covers
                    (an element over the column's axis whose underside is at most
                    :data:`COVER_GAP` m above the column top)
``aruco``           each marker's four corners, OpenCV order
``all``             the three structural sets together
==================  ==========================================================================

A vertex where an outline turns by less than :data:`MIN_CORNER_TURN_DEG` (a kink in one edge, a
vertex of the polygon an exporter made of a curved edge) is no corner: along the edge a detector
cannot place it (its along-edge precision is about ``1 / sin(turn)`` of its across-edge one, twice
at 30 deg), and a curve has no point to place. An oval slab therefore has no slab corners.

Ids: :class:`LandmarkRegistry` numbers every landmark any stage of the building can expose,
set by set (structural sets, then markers) and element by element in the site's element order,
from 0 up. So ids are unique at any building size, the same at every stage of a building and
the same for the same input; ``LandmarkSet.elements`` names the element (guid) each landmark
belongs to.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.elements import Column, Element, Slab, Stage
from uav_struct_env.site.markers import ArucoMarker

__all__ = [
    "COVER_GAP",
    "LANDMARK_SETS",
    "MIN_CORNER_TURN_DEG",
    "STRUCTURAL_SETS",
    "LandmarkRegistry",
    "LandmarkSet",
    "StagedSite",
    "check_landmarks",
    "corner_vertices",
    "exposed_landmarks",
]

STRUCTURAL_SETS = ("slab_corners", "opening_corners", "column_tops")
LANDMARK_SETS = (*STRUCTURAL_SETS, "aruco", "all")

#: A slab or beam whose underside is at most this far above a column top covers that top, m.
COVER_GAP = 0.5

#: Least turn of an outline at a vertex for the vertex to be a corner landmark, deg (the module docstring).
MIN_CORNER_TURN_DEG = 30.0


@dataclass(frozen=True, eq=False)
class LandmarkSet:
    """A named set of landmarks: ids (M,), positions (M, 3), labels and element guids (M,)."""

    name: str
    ids: NDArray[np.int64]
    xyz: NDArray[np.float64]
    labels: tuple[str, ...]
    elements: tuple[str, ...] = field(default=())

    def __len__(self) -> int:
        return len(self.ids)


# A landmark before it gets an id: (set, element guid, corner key, label, xyz).
_Point = tuple[str, str, str, str, tuple[float, float, float]]


def corner_vertices(outline: NDArray[np.float64]) -> list[int]:
    """Indices of a closed outline's (N, 2) vertices where it turns by >= :data:`MIN_CORNER_TURN_DEG`.

    Either way (a re-entrant corner too), in outline order.
    """
    p = np.asarray(outline, dtype=np.float64)
    before = p - np.roll(p, 1, axis=0)
    after = np.roll(p, -1, axis=0) - p
    cross = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0]
    turn = np.degrees(np.abs(np.arctan2(cross, (before * after).sum(axis=1))))
    return np.flatnonzero(turn >= MIN_CORNER_TURN_DEG - 1e-9).tolist()  # a turn of exactly 30 deg is one


def _slab_corners(slab: Slab) -> list[_Point]:
    return [
        ("slab_corners", slab.guid, f"corner {k}", f"{slab.name} corner {k}",
         (*slab.outline[k].tolist(), slab.z_top))
        for k in corner_vertices(slab.outline)
    ]


def _opening_corners(slab: Slab) -> list[_Point]:
    return [
        ("opening_corners", slab.guid, f"{hole.guid} corner {k}", f"{hole.name} corner {k}",
         (*hole.outline[k].tolist(), slab.z_top))
        for hole in slab.holes
        for k in corner_vertices(hole.outline)
    ]


def _column_top(column: Column) -> list[_Point]:
    return [("column_tops", column.guid, "top", f"{column.name} top", column.top_center)]


def _marker_corners(marker: ArucoMarker) -> list[_Point]:
    return [
        ("aruco", f"marker {marker.id}", f"corner {k}", f"marker {marker.id} corner {k}", tuple(xyz))
        for k, xyz in enumerate(marker.corners_world.tolist())
    ]


def _covered(column: Column, built: tuple[Element, ...]) -> bool:
    xy = np.array([column.axis])
    for e in built:
        if e.kind not in ("slab", "beam") or e is column:
            continue
        if e.z_top > column.z_top and e.z_bottom <= column.z_top + COVER_GAP and e.covers(xy)[0]:
            return True
    return False


def exposed_landmarks(
    name: str,
    built: tuple[Element, ...],
    floor: tuple[Slab, ...],
    markers: tuple[ArucoMarker, ...],
) -> list[_Point]:
    """The landmarks of set ``name`` (not ``all``) exposed with ``built`` elements standing."""
    if name == "slab_corners":
        return [p for slab in floor for p in _slab_corners(slab)]
    if name == "opening_corners":
        return [p for slab in floor for p in _opening_corners(slab)]
    if name == "column_tops":
        return [
            p for e in built if isinstance(e, Column) and not _covered(e, built) for p in _column_top(e)
        ]
    if name == "aruco":
        return [p for m in markers for p in _marker_corners(m)]
    raise ValueError(f"landmark set must be one of {LANDMARK_SETS}, got {name!r}")


class LandmarkRegistry:
    """Ids for every landmark any stage of a building can expose (see the module docstring)."""

    def __init__(self, elements: tuple[Element, ...], markers: tuple[ArucoMarker, ...]) -> None:
        slabs = [e for e in elements if isinstance(e, Slab) and e.structural]
        columns = [e for e in elements if isinstance(e, Column)]
        points = [p for s in slabs for p in _slab_corners(s)]
        points += [p for s in slabs for p in _opening_corners(s)]
        points += [p for c in columns for p in _column_top(c)]
        points += [p for m in markers for p in _marker_corners(m)]
        self._ids = {p[:3]: k for k, p in enumerate(points)}

    def __len__(self) -> int:
        return len(self._ids)

    def landmark_set(self, name: str, points: list[_Point]) -> LandmarkSet:
        """A :class:`LandmarkSet` of ``points`` with their allocated ids (read-only arrays)."""
        ids = np.array([self._ids[p[:3]] for p in points], dtype=np.int64)
        xyz = np.array([p[4] for p in points], dtype=np.float64).reshape(-1, 3)
        ids.setflags(write=False)
        xyz.setflags(write=False)
        return LandmarkSet(name, ids, xyz, tuple(p[3] for p in points), tuple(p[1] for p in points))


class StagedSite(Protocol):
    """What :func:`check_landmarks` reads of a :class:`~uav_struct_env.site.Site`.

    The landmarks sit below the site (the site derives its landmarks from here), so they name
    what they read of it rather than import it.
    """

    @property
    def name(self) -> str:
        """The site's name."""

    @property
    def stage(self) -> str:
        """The stage the site is at."""

    @property
    def stages(self) -> Sequence[Stage]:
        """The construction stages in build order."""

    def landmarks(self, name: str) -> LandmarkSet:
        """The landmark set ``name`` exposed at this stage."""

    def with_stage(self, stage: str) -> StagedSite:
        """The same site at another stage."""


def check_landmarks(site: StagedSite, name: str, minimum: int = 4) -> LandmarkSet:
    """The landmark set ``name`` exposed at the site's stage, if it has at least ``minimum``.

    A pose needs four correspondences: a stage that exposes fewer of the requested set (an
    imported building without columns asked for ``column_tops``) cannot localize with it.

    Raises:
        ValueError: for an unknown set name or ``minimum`` < 1.
        SiteGeometryError: naming the stage, the set and how many it exposes, with the sets this
            stage exposes enough of and the stages that expose enough of this set.
    """
    if name not in LANDMARK_SETS:
        raise ValueError(f"landmark set must be one of {LANDMARK_SETS}, got {name!r}")
    check_number("minimum", minimum, 1, integer=True, type_error=ValueError)
    found = site.landmarks(name)
    if len(found) >= minimum:
        return found
    sets = [n for n in LANDMARK_SETS if n != name and len(site.landmarks(n)) >= minimum]
    stages = [st.name for st in site.stages if len(site.with_stage(st.name).landmarks(name)) >= minimum]
    raise SiteGeometryError(
        f"stage {site.stage!r} of site {site.name!r} exposes {len(found)} {name} landmark(s), fewer "
        f"than the {minimum} a pose needs; sets with at least {minimum} at this stage: {sets or 'none'}; "
        f"stages with at least {minimum} {name}: {stages or 'none'}"
    )
