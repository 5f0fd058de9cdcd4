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

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.elements import Column, Element, Hole, Slab, Stage, Storey
from uav_struct_env.site.polygons import rectangle

__all__ = ["STAGES", "Building", "ColumnGrid", "Opening", "building_site"]

#: The paper's two stages (aliases of the first floor's stages of a parametric building).
STAGES = ("slab", "columns")

#: Upper bound on columns, floors and openings of a parametric building (memory and time).
MAX_COLUMNS = 10_000


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
        nx, ny = self.shape
        if nx * ny > MAX_COLUMNS:
            raise SiteGeometryError(f"a grid of {nx} x {ny} columns exceeds the {MAX_COLUMNS} supported")

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
        if len(self.storey_heights) < 1:
            raise SiteGeometryError(f"storey_heights needs at least one storey, got {self.storey_heights!r}")
        if len(self.storey_heights) * self.grid.shape[0] * self.grid.shape[1] > MAX_COLUMNS:
            raise SiteGeometryError(
                f"{len(self.storey_heights)} storeys of {self.grid.shape[0]} x {self.grid.shape[1]} "
                f"columns exceed the {MAX_COLUMNS} supported"
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
):
    """The :class:`~uav_struct_env.site.Site` of a parametric ``building`` at ``stage``."""
    from uav_struct_env.site.model import Site

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
