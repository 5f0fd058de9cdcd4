"""The parametric reinforced-concrete frame: a column grid, storeys, slabs and their openings.

A :class:`Building` is a few parameters (like dm_control's ``_make_model``); :func:`building_site`
turns it into the typed elements of a :class:`~uav_struct_env.site.Site`, one of the two
producers of sites (the other is the IFC importer). Units are metres, the frame is the project
frame (origin at the first column grid line intersection at ground level).

Storeys are named ``"Ground"``, ``"Level 1"``, ... ``"Level n"``: storey ``k`` has the
floor-to-floor height ``storey_heights[k]``, and the slab on top of it is the floor of
``"Level k+1"`` (the last one is the roof). Stages, in build order: ``"Level k/slab"`` (every
column below level k and the slabs up to it) and ``"Level k/columns"`` (plus the columns
standing on level k, below the roof). The first floor's two stages are the paper's, and keep
their short names ``"slab"`` and ``"columns"`` as aliases.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.elements import (
    Column,
    Element,
    Hole,
    Slab,
    Stage,
    Storey,
    check_length,
    check_points,
)
from uav_struct_env.site.model import Site
from uav_struct_env.site.polygons import rectangle

__all__ = ["STAGES", "Building", "ColumnGrid", "Opening", "building_site"]

#: The paper's two stages (aliases of the first floor's stages of a parametric building).
STAGES = ("slab", "columns")

#: Upper bound on columns, floors and openings of a parametric building (memory and time).
MAX_COLUMNS = 10_000
#: Upper bound on slab openings (each is checked against every column and every other opening).
MAX_OPENINGS = 200
#: Physical bounds, m: a span between grid lines, the building's plan extent along each axis, a
#: storey height, the column section, the slab thickness and its overhang past the grid.
MAX_SPAN = 200.0
MAX_EXTENT = 2_000.0
MAX_STOREY_HEIGHT = 50.0
MAX_SECTION = 10.0
MAX_SLAB_THICKNESS = 5.0
MAX_OVERHANG = 50.0


def _sequence(where: str, value: object, n: int | None = None, *, limit: int | None = None) -> tuple:
    """``value`` as a tuple: a list or tuple of exactly ``n`` entries (else non-empty, at most ``limit``)."""
    what = f"{n} numbers" if n is not None else "a non-empty list"
    if isinstance(value, (str, bytes)) or not isinstance(value, (tuple, list)):
        raise SiteGeometryError(f"{where} must be {what}, got {value!r}"[:300])
    if (n is not None and len(value) != n) or (n is None and len(value) == 0):
        raise SiteGeometryError(f"{where} must be {what}, got {len(value)} entries: {value!r}"[:300])
    if limit is not None and len(value) > limit:
        raise SiteGeometryError(f"{where} has {len(value)} entries, more than the {limit} supported")
    return tuple(value)


@dataclass(frozen=True)
class ColumnGrid:
    """Column grid lines: ``spans_x`` are the distances between consecutive lines along x.

    A grid with ``len(spans_x) == 2`` and ``len(spans_y) == 3`` has 3 x 4 columns.
    """

    spans_x: tuple[float, ...]
    spans_y: tuple[float, ...]

    def __post_init__(self) -> None:
        spans_x = _sequence("spans_x", self.spans_x)
        spans_y = _sequence("spans_y", self.spans_y)
        nx, ny = len(spans_x) + 1, len(spans_y) + 1
        if nx * ny > MAX_COLUMNS:  # before looking at the values: refused in microseconds
            raise SiteGeometryError(f"a grid of {nx} x {ny} columns exceeds the {MAX_COLUMNS} supported")
        for axis, spans in (("x", spans_x), ("y", spans_y)):
            spans = tuple(check_length(f"spans_{axis}[{k}]", s, MAX_SPAN) for k, s in enumerate(spans))
            if sum(spans) > MAX_EXTENT:
                raise SiteGeometryError(
                    f"spans_{axis} add up to {sum(spans)} m, more than the {MAX_EXTENT} m supported"
                )
            object.__setattr__(self, f"spans_{axis}", spans)

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
    """A rectangular slab opening (e.g. the stair opening), axis-aligned, in plan.

    It goes through every floor slab of the building (a stair or shaft).
    """

    name: str
    center: tuple[float, float]
    size: tuple[float, float]  # (along x, along y)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SiteGeometryError(f"opening name must be a non-empty string, got {self.name!r}")
        where = f"opening {self.name!r}"
        object.__setattr__(self, "center", check_points(f"{where} center", self.center, 2))
        size = _sequence(f"{where} size", self.size, 2)
        object.__setattr__(self, "size", tuple(check_length(f"{where} size[{k}]", v, MAX_EXTENT)
                                               for k, v in enumerate(size)))

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)``."""
        (cx, cy), (sx, sy) = self.center, self.size
        return cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2


@dataclass(frozen=True)
class Building:
    """A reinforced-concrete frame: grid, storeys, column section, slabs and their openings.

    ``storey_heights[k]`` is the floor-to-floor height of storey ``k``; the slab topping storey
    ``k`` has its top surface at ``sum(storey_heights[:k + 1])``. Columns of storey ``k`` rise from
    the floor below to the underside of the slab above (``slab_thickness`` below the next floor).
    """

    grid: ColumnGrid
    storey_heights: tuple[float, ...] = (3.5, 3.5)
    column_section: tuple[float, float] = (0.35, 0.35)
    slab_thickness: float = 0.25
    slab_overhang: float = 0.3
    openings: tuple[Opening, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.grid, ColumnGrid):
            raise SiteGeometryError(f"grid must be a ColumnGrid, got {self.grid!r}")
        heights = _sequence("storey_heights", self.storey_heights)
        if len(heights) * self.grid.shape[0] * self.grid.shape[1] > MAX_COLUMNS:
            raise SiteGeometryError(
                f"{len(heights)} storeys of {self.grid.shape[0]} x {self.grid.shape[1]} "
                f"columns exceed the {MAX_COLUMNS} supported"
            )
        openings = () if self.openings == () else _sequence("openings", self.openings, limit=MAX_OPENINGS)
        for k, op in enumerate(openings):
            if not isinstance(op, Opening):
                raise SiteGeometryError(f"openings[{k}] must be an Opening, got {op!r}")
        object.__setattr__(self, "openings", openings)
        t = check_length("slab_thickness", self.slab_thickness, MAX_SLAB_THICKNESS)
        heights = tuple(check_length(f"storey_heights[{k}]", h, MAX_STOREY_HEIGHT)
                        for k, h in enumerate(heights))
        for k, h in enumerate(heights):
            if h <= t:
                raise SiteGeometryError(f"storey_heights[{k}] = {h} m must exceed slab_thickness = {t} m")
        object.__setattr__(self, "storey_heights", heights)
        section = _sequence("column_section", self.column_section, 2)
        sx, sy = (check_length(f"column_section[{k}]", v, MAX_SECTION) for k, v in enumerate(section))
        object.__setattr__(self, "column_section", (sx, sy))
        object.__setattr__(self, "slab_thickness", t)
        for axis, spans, sec in (("x", self.grid.spans_x, sx), ("y", self.grid.spans_y, sy)):
            for k, span in enumerate(spans):
                if span <= sec:
                    raise SiteGeometryError(
                        f"columns overlap: spans_{axis}[{k}] = {span} m is not larger than the "
                        f"column section {sec} m"
                    )
        overhang = check_length("slab_overhang", self.slab_overhang, MAX_OVERHANG, lo_open=False)
        object.__setattr__(self, "slab_overhang", overhang)
        if overhang < max(sx, sy) / 2:
            raise SiteGeometryError(
                f"slab_overhang = {self.slab_overhang} m must cover the columns' half section "
                f"{max(sx, sy) / 2} m"
            )
        self._check_openings()

    def _check_openings(self) -> None:
        """Openings inside the slab, clear of every column and of each other, with unique names."""
        sx, sy = self.column_section
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
        for i, a in enumerate(self.openings):
            for b in self.openings[i + 1 :]:
                (a0, a1, a2, a3), (b0, b1, b2, b3) = a.bounds, b.bounds
                if a0 < b2 and b0 < a2 and a1 < b3 and b1 < a3:
                    raise SiteGeometryError(f"openings {a.name!r} and {b.name!r} overlap")
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
        sx, sy = self.column_section
        out = []
        for iy, y in enumerate(self.grid.ys):
            for ix, x in enumerate(self.grid.xs):
                index = iy * nx + ix
                name = f"C{storey}-{index:02d}"
                x, y = float(x), float(y)
                out.append(Column(
                    guid=name, name=name, storey=storey, index=index, axis=(x, y),
                    outline=rectangle(x - sx / 2, y - sy / 2, x + sx / 2, y + sy / 2),
                    z_bottom=z0, z_top=z1,
                ))
        return tuple(out)

    def slab(self, level: int) -> Slab:
        """The slab on top of storey ``level - 1`` (the floor of ``"Level <level>"``)."""
        name = f"S{level}"
        z_top = float(sum(self.storey_heights[:level]))
        return Slab(
            guid=name, name=name, storey=level, outline=rectangle(*self.slab_bounds),
            z_bottom=z_top - self.slab_thickness, z_top=z_top,
            holes=tuple(Hole(op.name, rectangle(*op.bounds), guid=f"{name}/{op.name}")
                        for op in self.openings),
        )

    def storeys(self) -> tuple[Storey, ...]:
        """``Ground``, ``Level 1`` ... ``Level n`` with their floor elevations."""
        z = np.concatenate([[0.0], np.cumsum(self.storey_heights)])
        return tuple(Storey("Ground" if k == 0 else f"Level {k}", float(z[k])) for k in range(len(z)))

    def elements(self) -> tuple[Element, ...]:
        """Every column (storey by storey, row-major), then every slab (level by level)."""
        n = len(self.storey_heights)
        columns = [c for k in range(n) for c in self.columns(k)]
        return (*columns, *[self.slab(level) for level in range(1, n + 1)])

    def stages(self) -> tuple[Stage, ...]:
        """The construction stages in build order (see the module docstring)."""
        n = len(self.storey_heights)
        columns = [tuple(c.guid for c in self.columns(k)) for k in range(n)]
        stages = []
        for level in range(1, n + 1):
            built = {g for k in range(level) for g in columns[k]} | {f"S{j}" for j in range(1, level + 1)}
            floor = (f"S{level}",)
            stages.append(Stage(f"Level {level}/slab", frozenset(built), floor,
                                ("slab",) if level == 1 else ()))
            if level < n:
                stages.append(Stage(f"Level {level}/columns", frozenset(built | set(columns[level])), floor,
                                    ("columns",) if level == 1 else ()))
        return tuple(stages)


def building_site(
    building: Building,
    stage: str = "columns",
    markers: Sequence = (),
    ground_size: float = 160.0,
    name: str = "custom",
) -> Site:
    """The :class:`~uav_struct_env.site.Site` of a parametric ``building`` at ``stage``."""
    if not isinstance(building, Building):
        raise TypeError(f"building must be a uav_struct_env.site.Building, got {type(building).__name__}")
    return Site(
        elements=building.elements(),
        storeys=building.storeys(),
        stages=building.stages(),
        stage=stage,
        markers=tuple(markers),
        ground_size=ground_size,
        name=name,
        building=building,
    )
