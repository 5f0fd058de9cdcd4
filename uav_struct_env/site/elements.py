"""The typed building elements a :class:`~uav_struct_env.site.Site` is made of.

Every structural element is a solid between ``z_bottom`` and ``z_top`` whose plan footprint is
``outline`` (a polygon in :mod:`uav_struct_env.site.polygons`' convention). That prism is its
geometry unless ``mesh`` gives the element's own triangles (an imported IFC element: sloped,
curved or otherwise not a vertical prism); ``outline``, ``z_bottom`` and ``z_top`` are then its
plan footprint and height range. Slabs carry their openings (:class:`Hole`); columns their axis,
whose top end is the ``column_tops`` landmark.

Elements are produced by the parametric grid (:mod:`uav_struct_env.site.parametric`) or the IFC
importer (:mod:`uav_struct_env.site.ifc`); everything downstream (meshes, obstacles, view
targets, landmarks) reads only these classes. ``guid`` is the element's stable identity (the IFC
GlobalId, or a name the parametric producer derives from the grid position), from which landmark
ids are allocated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.polygons import (
    canonical_outline,
    is_axis_aligned_rectangle,
    points_in_polygon,
    polygon_bounds,
)

__all__ = [
    "ELEMENT_TYPES",
    "MAX_COORDINATE",
    "Beam",
    "Column",
    "Element",
    "Hole",
    "Slab",
    "Stage",
    "Storey",
    "TriangleMesh",
    "Wall",
    "check_coordinate",
    "check_length",
    "check_points",
    "element_boxes",
]


#: Bound on every plan coordinate and elevation of a site, m: a building site fits in a few km.
MAX_COORDINATE = 10_000.0


def check_coordinate(where: str, value: object, bound: float | None = MAX_COORDINATE) -> float:
    """A coordinate or elevation in metres, finite and within ``bound`` of the origin.

    Parametric buildings and site files are held to :data:`MAX_COORDINATE`; elements as such
    (an imported IFC file keeps its own world frame) only to being finite (``bound=None``).

    Raises:
        SiteGeometryError: naming ``where`` (a non-number too: site data comes from files).
    """
    lo, hi = (None, None) if bound is None else (-bound, bound)
    return check_number(f"{where} (m)", value, lo, hi, error=SiteGeometryError, type_error=SiteGeometryError)


def check_length(where: str, value: object, hi: float, *, lo: float = 0.0, lo_open: bool = True,
                 type_error: type[Exception] = TypeError) -> float:
    """A length in metres in ``(lo, hi]`` (``[lo, hi]`` without ``lo_open``).

    Raises:
        SiteGeometryError: out of range, NaN or infinite, naming ``where``.
        ``type_error``: not a number.
    """
    return check_number(f"{where} (m)", value, lo, hi, lo_open=lo_open, error=SiteGeometryError,
                        type_error=type_error)


def check_points(
    where: str, value: object, dim: int, bound: float | None = MAX_COORDINATE
) -> tuple[float, ...]:
    """A point of ``dim`` coordinates (a JSON list or tuple), each by :func:`check_coordinate`."""
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != dim:
        raise SiteGeometryError(f"{where} must be {dim} numbers, got {value!r}")
    return tuple(check_coordinate(f"{where}[{k}]", v, bound) for k, v in enumerate(value))


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """Triangles in the project frame: ``vertices`` (V, 3) metres, ``faces`` (F, 3) indices."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise SiteGeometryError(f"mesh vertices must be a finite (V, 3) array, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
            raise SiteGeometryError(
                f"mesh faces must be a non-empty (F, 3) array of vertex indices < {len(v)}, "
                f"got shape {f.shape}"
            )
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)


@dataclass(frozen=True, eq=False)
class Hole:
    """An opening through a slab (a stair opening, a shaft), as a plan outline.

    ``source`` says where it came from: ``"parametric"``, ``"void"`` (an IFC opening element) or
    ``"outline"`` (a notch drawn into the slab's outline, which the importer turned into a hole).
    """

    name: str
    outline: NDArray[np.float64]
    guid: str = ""
    source: str = "parametric"

    def __post_init__(self) -> None:
        object.__setattr__(self, "outline", canonical_outline(self.outline, f"opening {self.name!r} outline"))
        object.__setattr__(self, "guid", self.guid or self.name)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)``."""
        return polygon_bounds(self.outline)

    @property
    def center(self) -> tuple[float, float]:
        """Centre of the bounding box."""
        xmin, ymin, xmax, ymax = self.bounds
        return (xmin + xmax) / 2, (ymin + ymax) / 2

    @property
    def size(self) -> tuple[float, float]:
        """Bounding-box size ``(along x, along y)``."""
        xmin, ymin, xmax, ymax = self.bounds
        return xmax - xmin, ymax - ymin


@dataclass(frozen=True, eq=False, kw_only=True)
class Element:
    """A solid building element (see the module docstring)."""

    kind: ClassVar[str] = "element"

    guid: str
    name: str
    storey: int
    outline: NDArray[np.float64]
    z_bottom: float
    z_top: float
    mesh: TriangleMesh | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        where = f"{self.kind} {self.name!r}"
        if not isinstance(self.guid, str) or not self.guid:
            raise SiteGeometryError(f"{where} needs a non-empty guid string, got {self.guid!r}")
        check_number(f"{where} storey", self.storey, 0, integer=True, error=SiteGeometryError,
                     type_error=SiteGeometryError)
        object.__setattr__(self, "outline", canonical_outline(self.outline, f"{where} outline"))
        z0 = check_coordinate(f"{where} z_bottom", self.z_bottom, None)
        z1 = check_coordinate(f"{where} z_top", self.z_top, None)
        if not z1 > z0:
            raise SiteGeometryError(f"{where} z_top = {z1} m must exceed z_bottom = {z0} m")
        object.__setattr__(self, "z_bottom", z0)
        object.__setattr__(self, "z_top", z1)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """Plan bounding box ``(xmin, ymin, xmax, ymax)``."""
        return polygon_bounds(self.outline)

    @property
    def is_box(self) -> bool:
        """Whether the element is exactly an axis-aligned box (a rectangular prism, no own mesh)."""
        return self.mesh is None and is_axis_aligned_rectangle(self.outline)

    def covers(self, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether each plan point (N, 2) lies inside the footprint (and outside any opening)."""
        return points_in_polygon(xy, self.outline)


@dataclass(frozen=True, eq=False, kw_only=True)
class Column(Element):
    """A column; ``axis`` is its plan centre line, whose top end is the ``column_tops`` landmark.

    ``index`` is the producer's own numbering (row-major over the grid for parametric sites).
    """

    kind: ClassVar[str] = "column"

    axis: tuple[float, float]
    index: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "axis", check_points(f"column {self.name!r} axis", self.axis, 2, None))

    @property
    def x(self) -> float:
        """Axis x, m."""
        return self.axis[0]

    @property
    def y(self) -> float:
        """Axis y, m."""
        return self.axis[1]

    @property
    def section(self) -> tuple[float, float]:
        """Bounding-box section ``(along x, along y)``, m."""
        xmin, ymin, xmax, ymax = self.bounds
        return xmax - xmin, ymax - ymin

    @property
    def top_center(self) -> tuple[float, float, float]:
        """Centre of the top face (the ``column_tops`` landmark)."""
        return self.axis[0], self.axis[1], self.z_top


@dataclass(frozen=True, eq=False, kw_only=True)
class Slab(Element):
    """A floor (or roof) slab with its openings; ``structural=False`` marks finish layers."""

    kind: ClassVar[str] = "slab"

    holes: tuple[Hole, ...] = ()
    structural: bool = True

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "holes", tuple(self.holes))
        for hole in self.holes:
            if not np.all(points_in_polygon(hole.outline.mean(axis=0)[None], self.outline)):
                raise SiteGeometryError(f"opening {hole.name!r} lies outside slab {self.name!r}")

    @property
    def openings(self) -> tuple[Hole, ...]:
        """The slab's openings (same as ``holes``)."""
        return self.holes

    @property
    def thickness(self) -> float:
        """``z_top - z_bottom``, m."""
        return self.z_top - self.z_bottom

    def covers(self, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Inside the outline and outside every opening."""
        inside = points_in_polygon(xy, self.outline)
        for hole in self.holes:
            inside &= ~points_in_polygon(xy, hole.outline)
        return inside


@dataclass(frozen=True, eq=False, kw_only=True)
class Beam(Element):
    """A beam (its plan footprint extruded over its depth)."""

    kind: ClassVar[str] = "beam"


@dataclass(frozen=True, eq=False, kw_only=True)
class Wall(Element):
    """A wall (its plan footprint extruded over its height)."""

    kind: ClassVar[str] = "wall"


#: Element classes by kind, in the order meshes are built (columns first, as in the first wave).
ELEMENT_TYPES: dict[str, type[Element]] = {c.kind: c for c in (Column, Slab, Beam, Wall)}


@dataclass(frozen=True)
class Storey:
    """A building storey: its name (``"Level 1"``) and floor elevation (m)."""

    name: str
    elevation: float


@dataclass(frozen=True, eq=False)
class Stage:
    """A construction stage as data.

    Attributes:
        name: ``"<storey name>/slab"`` or ``"<storey name>/columns"``.
        built: guids of every element standing at this stage.
        floor: guids of the topmost built structural floor's slabs (their outline and opening
            corners are the stage's ``slab_corners`` and ``opening_corners``).
        aliases: other names accepted for this stage (``"slab"`` / ``"columns"`` for the first
            floor of a parametric building, the paper's two stages).
    """

    name: str
    built: frozenset[str]
    floor: tuple[str, ...]
    aliases: tuple[str, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        """The name and its aliases."""
        return (self.name, *self.aliases)


def element_boxes(element: Element) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The element as axis-aligned boxes ``lo`` (B, 3), ``hi`` (B, 3), e.g. for collision tests.

    The plan is cut along every x and y of the outline's (and openings') corners; a cell is kept
    when its centre is covered. Exact for rectilinear outlines (a UAV may pass through a stair
    opening); for slanted edges the cells whose centres are covered stand in for the shape.
    """
    holes = element.holes if isinstance(element, Slab) else ()
    pts = np.concatenate([element.outline, *[h.outline for h in holes]])
    xs, ys = np.unique(pts[:, 0]), np.unique(pts[:, 1])
    cx, cy = np.meshgrid((xs[:-1] + xs[1:]) / 2, (ys[:-1] + ys[1:]) / 2, indexing="ij")
    keep = element.covers(np.column_stack([cx.ravel(), cy.ravel()])).reshape(cx.shape)
    ix, iy = np.nonzero(keep)
    lo = np.column_stack([xs[ix], ys[iy], np.full(len(ix), element.z_bottom)])
    hi = np.column_stack([xs[ix + 1], ys[iy + 1], np.full(len(ix), element.z_top)])
    return lo, hi
