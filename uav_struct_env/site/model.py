"""The construction site as plain data: column grid, columns, slabs, openings, stages, markers.

Everything here is a frozen dataclass built from a few parameters (like dm_control's
``_make_model``); derived elements (columns, slabs, landmarks) are computed from them, so a site
cannot hold contradictory copies of the same geometry. Units are metres, the frame is the project
frame (right-handed, z up, origin at the first column grid line intersection at ground level).

Landmark ids are stable across stages and presets of the same grid:

==================  =========================================================
set                 id
==================  =========================================================
``slab_corners``    ``100 + k``, k = 0..3 counter-clockwise from (xmin, ymin)
``opening_corners`` ``200 + 4 * opening_index + k``, same corner order
``column_tops``     ``300 + column_index`` (row-major over the grid: ``i_y * n_x + i_x``)
``aruco``           ``1000 + 4 * marker_id + corner`` (OpenCV corner order)
==================  =========================================================
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.errors import SiteGeometryError

__all__ = [
    "ARUCO_DICTIONARY_SIZES",
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
]

STAGES = ("slab", "columns")
STRUCTURAL_SETS = ("slab_corners", "opening_corners", "column_tops")
LANDMARK_SETS = (*STRUCTURAL_SETS, "aruco", "all")
#: Number of markers in each supported OpenCV ArUco dictionary.
ARUCO_DICTIONARY_SIZES = {"DICT_4X4_50": 50, "DICT_4X4_100": 100, "DICT_5X5_50": 50}

_ID_BASE = {"slab_corners": 100, "opening_corners": 200, "column_tops": 300, "aruco": 1000}


def _positive(name: str, value: float) -> float:
    if not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value) or value <= 0:
        raise SiteGeometryError(f"{name} must be a positive finite length in metres, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class ColumnGrid:
    """Column grid lines: ``spans_x`` are the distances between consecutive lines along x.

    A grid with ``len(spans_x) == 2`` and ``len(spans_y) == 3`` has 3 x 4 columns.
    """

    spans_x: tuple[float, ...]
    spans_y: tuple[float, ...]

    def __post_init__(self) -> None:
        for axis in ("x", "y"):
            spans = getattr(self, f"spans_{axis}")
            if isinstance(spans, (int, float)) or len(spans) == 0:
                raise SiteGeometryError(
                    f"spans_{axis} must be a non-empty sequence of span lengths, got {spans!r}"
                )
            for k, s in enumerate(spans):
                _positive(f"spans_{axis}[{k}]", s)
            object.__setattr__(self, f"spans_{axis}", tuple(float(s) for s in spans))

    @property
    def xs(self) -> NDArray[np.float64]:
        """Grid line x coordinates, starting at 0."""
        return np.concatenate([[0.0], np.cumsum(self.spans_x)])

    @property
    def ys(self) -> NDArray[np.float64]:
        """Grid line y coordinates, starting at 0."""
        return np.concatenate([[0.0], np.cumsum(self.spans_y)])

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_x, n_y)`` number of grid lines (columns) along each axis."""
        return len(self.spans_x) + 1, len(self.spans_y) + 1


@dataclass(frozen=True)
class Opening:
    """A rectangular slab opening (e.g. the stair opening), axis-aligned, in plan."""

    name: str
    center: tuple[float, float]
    size: tuple[float, float]  # (along x, along y)

    def __post_init__(self) -> None:
        _positive(f"opening {self.name!r} size[0]", self.size[0])
        _positive(f"opening {self.name!r} size[1]", self.size[1])
        object.__setattr__(self, "center", (float(self.center[0]), float(self.center[1])))
        object.__setattr__(self, "size", (float(self.size[0]), float(self.size[1])))

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)``."""
        (cx, cy), (sx, sy) = self.center, self.size
        return cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2


@dataclass(frozen=True)
class Column:
    """One cast column: a box from ``z_bottom`` to ``z_top`` with a rectangular section."""

    index: int  # row-major grid index i_y * n_x + i_x
    storey: int  # 0 = ground storey
    x: float
    y: float
    section: tuple[float, float]
    z_bottom: float
    z_top: float

    @property
    def name(self) -> str:
        """A readable name such as ``C1-03``."""
        return f"C{self.storey}-{self.index:02d}"

    @property
    def top_center(self) -> tuple[float, float, float]:
        """Centre of the top face (the ``column_tops`` landmark)."""
        return self.x, self.y, self.z_top


@dataclass(frozen=True)
class Slab:
    """A floor slab: a rectangular outline with openings, top surface at ``z_top``."""

    level: int  # 1 = first floor (tops storey 0)
    bounds: tuple[float, float, float, float]  # (xmin, ymin, xmax, ymax)
    z_top: float
    thickness: float
    openings: tuple[Opening, ...] = ()

    @property
    def name(self) -> str:
        """A readable name such as ``S1``."""
        return f"S{self.level}"


@dataclass(frozen=True)
class ArucoMarker:
    """A printed ArUco marker lying flat on the ground, facing up.

    The marker frame is OpenCV's: x right and y up on the printed face, z out of the face (world
    +z here). ``yaw`` turns it about the world z axis. ``side`` is the black square's side length;
    a white quiet zone of ``quiet_zone`` times the side surrounds it.
    """

    id: int
    side: float
    center: tuple[float, float, float]
    yaw: float = 0.0
    dictionary: str = "DICT_4X4_50"
    quiet_zone: float = 0.25

    def __post_init__(self) -> None:
        _positive(f"marker {self.id} side", self.side)
        if self.dictionary not in ARUCO_DICTIONARY_SIZES:
            raise SiteGeometryError(
                f"marker {self.id} dictionary must be one of {sorted(ARUCO_DICTIONARY_SIZES)}, "
                f"got {self.dictionary!r}"
            )
        n = ARUCO_DICTIONARY_SIZES[self.dictionary]
        if not isinstance(self.id, (int, np.integer)) or not 0 <= self.id < n:
            raise SiteGeometryError(
                f"marker id must be an int in [0, {n}) for {self.dictionary}, got {self.id!r}"
            )
        if self.quiet_zone < 0:
            raise SiteGeometryError(f"marker {self.id} quiet_zone must be >= 0, got {self.quiet_zone!r}")
        object.__setattr__(self, "center", tuple(float(c) for c in self.center))

    @property
    def world_from_marker(self) -> NDArray[np.float64]:
        """4x4 pose of the marker frame in the project frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        out = np.eye(4)
        out[:2, :2] = [[c, -s], [s, c]]
        out[:3, 3] = self.center
        return out

    @property
    def corners_marker(self) -> NDArray[np.float64]:
        """(4, 3) corners in the marker frame, OpenCV order (TL, TR, BR, BL as printed)."""
        h = self.side / 2
        return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])

    @property
    def corners_world(self) -> NDArray[np.float64]:
        """(4, 3) corners in the project frame, OpenCV order."""
        T = self.world_from_marker
        return self.corners_marker @ T[:3, :3].T + T[:3, 3]

    @property
    def footprint_half_extent(self) -> float:
        """Half side of the printed sheet including its quiet zone."""
        return self.side * (0.5 + self.quiet_zone)


@dataclass(frozen=True, eq=False)
class LandmarkSet:
    """A named set of landmarks: stable ids (M,), positions (M, 3) and readable labels."""

    name: str
    ids: NDArray[np.int64]
    xyz: NDArray[np.float64]
    labels: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class Building:
    """A reinforced-concrete frame: grid, storeys, column section, slab and its openings.

    ``storey_heights[k]`` is the floor-to-floor height of storey ``k``; the slab topping storey
    ``k`` has its top surface at ``sum(storey_heights[:k + 1])``. Columns of storey ``k`` rise from
    the floor below to the underside of the next slab (``slab_thickness`` below the next floor).
    """

    grid: ColumnGrid
    storey_heights: tuple[float, ...] = (3.5, 3.5)
    column_section: tuple[float, float] = (0.35, 0.35)
    slab_thickness: float = 0.25
    slab_overhang: float = 0.3
    openings: tuple[Opening, ...] = ()

    def __post_init__(self) -> None:
        if len(self.storey_heights) < 2:
            raise SiteGeometryError(
                "storey_heights needs at least two storeys (ground and first floor), "
                f"got {self.storey_heights!r}"
            )
        t = _positive("slab_thickness", self.slab_thickness)
        for k, h in enumerate(self.storey_heights):
            if _positive(f"storey_heights[{k}]", h) <= t:
                raise SiteGeometryError(f"storey_heights[{k}] = {h} m must exceed slab_thickness = {t} m")
        sx = _positive("column_section[0]", self.column_section[0])
        sy = _positive("column_section[1]", self.column_section[1])
        for axis, spans, sec in (("x", self.grid.spans_x, sx), ("y", self.grid.spans_y, sy)):
            for k, span in enumerate(spans):
                if span <= sec:
                    raise SiteGeometryError(
                        f"columns overlap: spans_{axis}[{k}] = {span} m is not larger than the "
                        f"column section {sec} m"
                    )
        if not math.isfinite(self.slab_overhang) or self.slab_overhang < max(sx, sy) / 2:
            raise SiteGeometryError(
                f"slab_overhang = {self.slab_overhang} m must cover the columns' half section "
                f"{max(sx, sy) / 2} m"
            )
        xmin, ymin, xmax, ymax = self.slab_bounds
        for op in self.openings:
            oxmin, oymin, oxmax, oymax = op.bounds
            if oxmin <= xmin or oymin <= ymin or oxmax >= xmax or oymax >= ymax:
                raise SiteGeometryError(
                    f"opening {op.name!r} with bounds {op.bounds} lies outside the slab {self.slab_bounds}"
                )
            for x in self.grid.xs:
                for y in self.grid.ys:
                    if (
                        oxmin < x + sx / 2
                        and oxmax > x - sx / 2
                        and oymin < y + sy / 2
                        and oymax > y - sy / 2
                    ):
                        raise SiteGeometryError(
                            f"opening {op.name!r} with bounds {op.bounds} overlaps the column at ({x}, {y})"
                        )
        names = [op.name for op in self.openings]
        if len(set(names)) != len(names):
            raise SiteGeometryError(f"opening names must be unique, got {names}")

    @property
    def slab_bounds(self) -> tuple[float, float, float, float]:
        """Slab outline ``(xmin, ymin, xmax, ymax)``: the grid extended by the overhang."""
        o = self.slab_overhang
        return -o, -o, float(self.grid.xs[-1]) + o, float(self.grid.ys[-1]) + o

    @property
    def first_floor_z(self) -> float:
        """Top of the first-floor slab."""
        return float(self.storey_heights[0])

    def columns(self, storey: int) -> tuple[Column, ...]:
        """The columns of one storey, row-major over the grid."""
        z0 = float(sum(self.storey_heights[:storey]))
        z1 = z0 + self.storey_heights[storey] - self.slab_thickness
        nx, _ = self.grid.shape
        return tuple(
            Column(
                index=iy * nx + ix,
                storey=storey,
                x=float(x),
                y=float(y),
                section=self.column_section,
                z_bottom=z0,
                z_top=z1,
            )
            for iy, y in enumerate(self.grid.ys)
            for ix, x in enumerate(self.grid.xs)
        )


@dataclass(frozen=True)
class Site:
    """A construction site at one stage: the building, the stage's cast elements and the markers.

    Stages: ``"slab"`` — ground-storey columns and the first-floor slab are cast, upper columns
    not yet (slab and opening corners exposed); ``"columns"`` — the upper-storey columns are cast
    too and their tops are exposed.
    """

    building: Building
    stage: str = "columns"
    markers: tuple[ArucoMarker, ...] = ()
    ground_size: float = 160.0  # side of the square textured ground, m
    name: str = "custom"

    def __post_init__(self) -> None:
        if self.stage not in STAGES:
            raise SiteGeometryError(f"stage must be one of {STAGES}, got {self.stage!r}")
        _positive("ground_size", self.ground_size)
        object.__setattr__(self, "markers", tuple(self.markers))
        ids = [m.id for m in self.markers]
        dupes = sorted({i for i in ids if ids.count(i) > 1})
        if dupes:
            raise SiteGeometryError(f"duplicate marker ids {dupes}: every marker needs its own id")
        xmin, ymin, xmax, ymax = self.building.slab_bounds
        for m in self.markers:
            h = m.footprint_half_extent
            x, y, _ = m.center
            if x + h > xmin and x - h < xmax and y + h > ymin and y - h < ymax:
                raise SiteGeometryError(
                    f"marker {m.id} at ({x}, {y}) lies under the building footprint "
                    f"{self.building.slab_bounds}"
                )
            if max(abs(x), abs(y)) + h > self.ground_size / 2 + max(xmax, ymax):
                raise SiteGeometryError(f"marker {m.id} at ({x}, {y}) lies off the ground")
        for i, a in enumerate(self.markers):
            for b in self.markers[i + 1 :]:
                d = max(abs(a.center[0] - b.center[0]), abs(a.center[1] - b.center[1]))
                if d < a.footprint_half_extent + b.footprint_half_extent:
                    raise SiteGeometryError(f"markers {a.id} and {b.id} overlap")

    # ----------------------------------------------------------------------------- elements
    @cached_property
    def columns(self) -> tuple[Column, ...]:
        """All cast columns at this stage."""
        cols = self.building.columns(0)
        if self.stage == "columns":
            cols = cols + self.building.columns(1)
        return cols

    @cached_property
    def slabs(self) -> tuple[Slab, ...]:
        """All cast slabs at this stage (the first-floor slab)."""
        b = self.building
        return (
            Slab(
                level=1,
                bounds=b.slab_bounds,
                z_top=b.first_floor_z,
                thickness=b.slab_thickness,
                openings=b.openings,
            ),
        )

    @property
    def exposed_columns(self) -> tuple[Column, ...]:
        """Columns whose top faces are exposed (no slab above them yet)."""
        if self.stage == "columns":
            return self.building.columns(1)
        return ()

    @property
    def center(self) -> NDArray[np.float64]:
        """Centre of the building footprint at mid-height of the exposed structure."""
        xmin, ymin, xmax, ymax = self.building.slab_bounds
        top = max([c.z_top for c in self.columns] + [self.building.first_floor_z])
        return np.array([(xmin + xmax) / 2, (ymin + ymax) / 2, top / 2])

    # ----------------------------------------------------------------------------- landmarks
    def landmarks(self, name: str) -> LandmarkSet:
        """The landmark set ``name`` (one of :data:`LANDMARK_SETS`) exposed at this stage.

        ``all`` is the structural sets together (not the markers). A set with nothing exposed at
        this stage (``column_tops`` at stage ``slab``) is empty.
        """
        if name == "all":
            parts = [self.landmarks(n) for n in STRUCTURAL_SETS]
            return LandmarkSet(
                "all",
                np.concatenate([p.ids for p in parts]).astype(np.int64),
                np.concatenate([p.xyz for p in parts]).reshape(-1, 3),
                tuple(lab for p in parts for lab in p.labels),
            )
        points: list[tuple[int, tuple[float, float, float], str]] = []
        if name == "slab_corners":
            for slab in self.slabs:
                for k, (x, y) in enumerate(_rect_corners(slab.bounds)):
                    points.append((_ID_BASE[name] + k, (x, y, slab.z_top), f"{slab.name} corner {k}"))
        elif name == "opening_corners":
            for slab in self.slabs:
                for j, op in enumerate(slab.openings):
                    for k, (x, y) in enumerate(_rect_corners(op.bounds)):
                        points.append(
                            (
                                _ID_BASE[name] + 4 * j + k,
                                (x, y, slab.z_top),
                                f"{op.name} corner {k}",
                            )
                        )
        elif name == "column_tops":
            for col in self.exposed_columns:
                points.append((_ID_BASE[name] + col.index, col.top_center, f"{col.name} top"))
        elif name == "aruco":
            for m in self.markers:
                for k, xyz in enumerate(m.corners_world):
                    points.append((_ID_BASE[name] + 4 * m.id + k, tuple(xyz), f"marker {m.id} corner {k}"))
        else:
            raise ValueError(f"landmark set must be one of {LANDMARK_SETS}, got {name!r}")
        return LandmarkSet(
            name,
            np.array([p[0] for p in points], dtype=np.int64),
            np.array([p[1] for p in points], dtype=np.float64).reshape(-1, 3),
            tuple(p[2] for p in points),
        )

    def with_stage(self, stage: str) -> Site:
        """The same site at another construction stage."""
        return Site(self.building, stage, self.markers, self.ground_size, self.name)


def _rect_corners(bounds: Sequence[float]) -> list[tuple[float, float]]:
    xmin, ymin, xmax, ymax = bounds
    return [(xmin, ymin), (xmax, ymin), (xmax, ymax), (xmin, ymax)]
