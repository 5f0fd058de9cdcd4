"""IFC import: a :class:`~uav_struct_env.site.Site` from an IFC file (and :func:`write_ifc`, back).

ifcopenshell (the optional extra ``ifc``: ``pip install 'uav-struct-env[ifc]'``) is imported
inside the functions, so the rest of the package works without it. The export
(:func:`write_ifc`, ``Site.to_ifc``) is :mod:`uav_struct_env.site.ifc_export`, which reads the
plain data only and so sits below the :class:`~uav_struct_env.site.Site`; this module builds
sites and sits above it.

Import (:func:`load_ifc`, :func:`ifc_stages`, :func:`ifc_report`)
-----------------------------------------------------------------
Geometry comes from ifcopenshell's geometry iterator in world coordinates, which are metres
whatever the file's length unit (openings are already cut). The project frame is that IFC world
frame unless ``transform`` (a 4x4 ``project_from_ifc``, rigid, keeping z up) is given; IfcSite
placement, TrueNorth and IfcMapConversion are read and recorded in ``site.source``, never
applied. Imported: IfcSlab, IfcColumn, IfcBeam, IfcWall (and their subtypes). Not imported (the
report counts them by class): footings (below ground), members (stringers, mullions), stairs,
railings, doors, windows, coverings, furniture and every other non-structural product;
IfcOpeningElements become slab openings. Real files are messy; the rules, in order (each is a
function of the same name: :func:`_no_body_geometry`, ... :func:`_columns_beams_walls`):

0. **A ``*`` where a value belongs**: ``*`` marks an attribute a subtype derives; Renga also
   writes it for unset optional attributes (names, profile names), where ``$`` belongs, and the
   geometry kernel then refuses the element. Such a ``*`` is read as unset
   (:func:`_unset_star_arguments`; counted in the report's ``repaired``).
1. **No body geometry**: an element the iterator cannot tessellate is dropped; an aggregate
   whose parts carry the geometry (a Revit multi-layer floor exported as IfcSlab parts) is
   reported as such, its parts imported in its place.
2. **Coincident duplicates**: an element whose kind, 3D bounding box (within
   :data:`DUPLICATE_TOL`) and plan footprint match an earlier one is dropped.
3. **Finish floors**: a slab thinner than :data:`MIN_SLAB_THICKNESS` is dropped (said to be a
   finish floor when it lies on a kept slab).
4. **Not a floor**: a slab whose PredefinedType is not FLOOR, BASESLAB, ROOF, NOTDEFINED or unset
   (a LANDING, ...) is kept for rendering but bears no landmarks (``structural=False``).
5. **Sloped slabs**: a slab is flat-topped when its upward-facing horizontal triangles at its top
   elevation make at least :data:`FLAT_FRACTION` of its upward-facing plan area; otherwise it is
   kept for rendering (footprint outline, ``structural=False``) and bears no landmarks.
   **Ground-bearing slabs** (:func:`_at_terrain`): a slab whose top lies at most
   :data:`GROUND_TOL` above the terrain (z = 0 of the project frame, where the env lays its
   ground) is kept for rendering and bears no landmarks: a camera sees only the ground there.
6. **Precast pieces**: flat slabs of one storey whose tops lie within :data:`SAME_LEVEL_TOL` and
   whose top faces touch or are at most :data:`PRECAST_JOINT` apart become ONE slab: outline the
   union (joints closed), guid the pieces' GlobalIds joined by ``+``, mesh their triangles
   together. Pieces farther apart (a party-wall gap) stay separate slabs of the same floor.
7. **Slab outline**: the union (shapely) of the top-face triangles, simplified at
   :data:`OUTLINE_TOL`. Its interior rings are openings; so are **notches drawn into the
   outline**: a pocket whose mouth is collinear with the outline edge on both sides (a slot cut
   into a straight edge) and whose area is at most :data:`NOTCH_FRACTION` of the filled outline.
   The outline is then filled (its corners are the floor's corners; a point in the notch is not
   covered). A big or L-shaped re-entrant region stays part of the outline. An opening is
   ``Hole(source="void")`` named and identified after the IfcOpeningElement voiding the slab
   there, else ``source="outline"`` with guid ``"<slab guid>/opening <k>"``.
8. **Columns**: axis = centroid of the top face, outline = plan footprint. An IfcColumn shorter
   than :data:`MIN_COLUMN_HEIGHT` or squatter than its plan is wide (a plate, a railing post:
   Tekla exports them as IfcColumn) is rendered as a member and bears no landmark
   (:func:`_not_a_column`). **Beams, walls**:
   outline = the union of the plan projections of their triangles (its largest part, or the
   convex hull when the union falls apart into comparable parts). All keep their triangles as
   ``mesh``.

**Damage** is never imported as a different building: a file larger than
:func:`~uav_struct_env.site.ifc_file.max_file_bytes`, cut short (no ``END-ISO-10303-21;``) or with
a point or direction that is not finite or absurdly far (:mod:`uav_struct_env.site.ifc_file`) is
refused with the reason; an element whose geometry is degenerate (an outline without area at
the tolerance, non-finite tessellation) is dropped and reported, never failing the file, and an
opening too small to outline is dropped while its slab is kept. An element with a real plan
outline, however small, keeps it: a plan union is closed (slivers between triangles filled) before
it is simplified, and where that closing fails (it returns less area than it was given, as GEOS's
buffer can on parts touching at a vertex) the union is simplified unclosed (:func:`_clean`).

Storeys come from IfcBuildingStorey, in elevation order (its placement's z in metres); an element
belongs to the storey that contains it (through aggregates), else the highest storey at or below
its bottom. Names of one kind are made unique by appending ``[<guid prefix>]`` (8 characters, more
where 8 do not tell them apart). The floor of a
storey is its flat structural slabs. Stages, in build order, for each storey with a floor:
``"<storey>/slab"`` = every kept element of lower storeys plus the floors up to this one;
``"<storey>/columns"`` (only when the storey contains columns) = plus those columns. Imported
stages have no short aliases.

A building without a floor (a steel frame; slabs only at the terrain) gets **columns-only
stages** instead (:func:`_column_stages`): ``"<storey>/columns"`` = every kept element of lower
storeys plus the storey's columns, for each storey where at least four column tops stand exposed
above the terrain; the default is the last, where the columns end. A file with neither is
refused in one line that counts the slabs by the rule that kept them from being a floor
(``sloped or stepped``, ``ground-bearing at the terrain``, ...). Landmark ids follow from the
element order (columns, slabs, beams, walls; by storey, then file order), so they are stable
across loads of the same file.

The parse is cached in-process per (file, mtime, size, transform), so loading another stage of
the same file does not tessellate again, and on disk (:mod:`uav_struct_env.site.ifc_cache`) per
(the file's SHA-256, the importer's version, transform), so the next process to load the same
building (a study worker, an env copy, the next command) reads the parse back in about 0.1 s CPU
instead of parsing it again (``UAV_STRUCT_IFC_CACHE`` moves the cache or, ``off``, disables it).
A refused file is not cached. What was kept and dropped is an :class:`ImportReport` in
``site.source["report"]``, logged at INFO.

**Speed.** A first parse takes 0.1-5 s CPU for the corpus's files but the two Tekla exports (21 and
49 s for 3.4 and 3.6 MB, one core of a quiet machine, 2026-11-28; ``benchmarks/ifc_import.py
--breakdown`` splits a parse): 16 and 43 s of it is ifcopenshell's OpenCASCADE kernel, most of it
the boolean cuts of steel members (the steel frame's 644 cut beams take 34 s). The plan footprints
of beams and walls are unioned in GEOS's floating-point overlay, four times faster than on the 1 um
grid (:func:`_plan_union`; their outlines move by less than :data:`OUTLINE_TOL`, and no landmark and
no kept or dropped element changes on the corpus); slabs, columns and slivers stay on the grid. The
iterator runs on one thread: two threads gave the same tessellation of the carwash for 27 s CPU
against 17 s on one (a machine under load). Its other options change either nothing or the output; a
faster kernel (``cgal-simple``) drops elements; tessellating the beams without their cuts (9 s for
the steel frame's whole kernel) would render other beams: so none of these is done
(docs/benchmarks.md has the figures).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.detect.weights import file_sha256
from uav_struct_env.errors import ConfigError, IfcImportError, SiteGeometryError
from uav_struct_env.site import ifc_cache
from uav_struct_env.site.elements import Beam, Column, Element, Hole, Slab, Stage, Storey, TriangleMesh, Wall
from uav_struct_env.site.ifc_export import require_ifcopenshell, write_building
from uav_struct_env.site.ifc_file import check_complete, check_coordinates, check_size, star_arguments
from uav_struct_env.site.landmarks import exposed_landmarks
from uav_struct_env.site.model import Site
from uav_struct_env.site.polygons import canonical_outline

__all__ = [
    "DUPLICATE_TOL",
    "FLAT_FRACTION",
    "GROUND_TOL",
    "IMPORTED_CLASSES",
    "MIN_COLUMN_HEIGHT",
    "MIN_SLAB_THICKNESS",
    "NOTCH_FRACTION",
    "OUTLINE_TOL",
    "PRECAST_JOINT",
    "SAME_LEVEL_TOL",
    "ImportReport",
    "ifc_report",
    "ifc_stages",
    "load_ifc",
    "write_ifc",
]

log = logging.getLogger(__name__)

#: IFC classes imported (with their subtypes), by element kind.
IMPORTED_CLASSES = {"IfcColumn": "column", "IfcSlab": "slab", "IfcBeam": "beam", "IfcWall": "wall"}
#: Slab PredefinedTypes that make a landmark-bearing floor (None: not set).
FLOOR_TYPES = frozenset({"FLOOR", "BASESLAB", "ROOF", "NOTDEFINED", None})
#: Slabs thinner than this are finish layers, m.
MIN_SLAB_THICKNESS = 0.05
#: Bounding boxes within this are coincident (duplicates), m.
DUPLICATE_TOL = 0.005
#: Slab tops within this are at the same level (precast pieces, one floor), m.
SAME_LEVEL_TOL = 0.02
#: Pieces at the same level at most this far apart are one floor slab (a precast joint), m.
PRECAST_JOINT = 0.05
#: Outline simplification: vertices within this of the line through their neighbours go, m.
OUTLINE_TOL = 0.001
#: A notch larger than this fraction of the filled outline is part of the outline.
NOTCH_FRACTION = 0.2
#: A slab is flat-topped when its top face makes at least this fraction of its upward area.
FLAT_FRACTION = 0.9
#: An IfcColumn shorter than this (or squatter than its plan is wide) is a plate or post, m.
MIN_COLUMN_HEIGHT = 1.5
#: A slab whose top lies at most this high above the terrain (z = 0 of the project frame, where the
#: env lays its ground) is ground-bearing: its corners are not seen as structure, m.
GROUND_TOL = 0.3

# Not imported, by class (subtypes included), with the reason the report gives.
_NOT_IMPORTED = (
    ("IfcFooting", "foundation below ground: not rendered"),
    ("IfcMember", "member (stringer, mullion, brace): not imported"),
    ("IfcStair", "stair: not imported"),
    ("IfcStairFlight", "stair: not imported"),
    ("IfcRoof", "roof aggregate: its slabs are imported"),
    ("IfcOpeningElement", "opening: becomes a slab opening"),
    ("IfcSpatialStructureElement", "spatial structure"),
    ("IfcSpace", "space"),
    ("IfcAnnotation", "annotation"),
    ("IfcGrid", "grid"),
)
# The duplicate search's cells (m, wider than DUPLICATE_TOL) and the offsets of a cell's neighbours.
_DUPLICATE_CELL = 1.0
#: A stage needs at least this many landmarks of a set for a camera to get a pose from it.
_MIN_LANDMARKS = 4
_NEIGHBOURS = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
# The kinds whose plan footprints are unioned in floating point (:func:`_plan_union`): they bear no
# landmark, and a beam's outline moves a column top's cover test only within OUTLINE_TOL of its edge.
# Not columns: a plate's width, which the report quotes to the cm, could round the other way.
_FAST_UNION_KINDS = frozenset({"beam", "wall"})
# A union thinner on average than this (2 area / perimeter, m) is a sliver: made on the 1 um grid.
_FAST_MIN_WIDTH = 0.01
# A closing (:func:`_clean`) that loses more than this area (m2: OUTLINE_TOL squared, below the
# outline's resolution) has failed; the union is used unclosed.
_CLOSING_LOSS = OUTLINE_TOL**2
_KIND_ORDER = {"column": 0, "slab": 1, "beam": 2, "wall": 3}
_ELEMENT_CLASS = {"column": Column, "slab": Slab, "beam": Beam, "wall": Wall}

# A report row: (guid, ifc class, name, role or reason).
_Row = tuple[str, str, str, str]
# A tessellated product: vertices (V, 3) and triangles (T, 3).
_Shape = tuple[NDArray[np.float64], NDArray[np.int64]]
# Each element's plan outline (None: it has none), by guid.
_Footprints = dict[str, NDArray[np.float64] | None]


# ----------------------------------------------------------------------------- the report
@dataclass(frozen=True)
class ImportReport:
    """What an import kept and dropped, and why.

    Attributes:
        path: the IFC file.
        kept: ``(guid, ifc class, name, role)`` of every imported IFC element.
        dropped: ``(guid, ifc class, name, reason)`` of every imported-class element left out.
        skipped: ``(ifc class, count, reason)`` of the classes not imported at all.
        repaired: ``(ifc class, count, what)`` of the instances read other than as written
            (a ``*`` where the schema wants a value or ``$``: read as unset).
    """

    path: str
    kept: tuple[tuple[str, str, str, str], ...]
    dropped: tuple[tuple[str, str, str, str], ...]
    skipped: tuple[tuple[str, int, str], ...]
    repaired: tuple[tuple[str, int, str], ...] = ()

    def __repr__(self) -> str:
        return (f"ImportReport({self.path!r}: kept {len(self.kept)}, dropped {len(self.dropped)}, "
                f"{len(self.skipped)} classes not imported; .summary() lists every element)")

    def summary(self) -> str:
        """The report as readable text: counts, then one line per kept and dropped element."""
        lines = [f"IFC import of {self.path}: kept {len(self.kept)}, dropped {len(self.dropped)}, "
                 f"not imported {sum(n for _, n, _ in self.skipped)} of {len(self.skipped)} classes"]
        lines += [f"  kept    {c:<20} {g}  {n!r}: {r}" for g, c, n, r in self.kept]
        lines += [f"  dropped {c:<20} {g}  {n!r}: {r}" for g, c, n, r in self.dropped]
        lines += [f"  skipped {c:<20} x{n}: {r}" for c, n, r in self.skipped]
        lines += [f"  read    {c:<20} x{n}: {r}" for c, n, r in self.repaired]
        return "\n".join(lines)


# ----------------------------------------------------------------------------- plan geometry
def _tri_polygons(tri2d: NDArray[np.float64]) -> Any:
    """The plan triangles (T, 3, 2) that have an area, as an array of shapely polygons."""
    import shapely

    a = tri2d[:, 1] - tri2d[:, 0]
    b = tri2d[:, 2] - tri2d[:, 0]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    tri2d = tri2d[area > 1e-9]
    return shapely.polygons(np.concatenate([tri2d, tri2d[:, :1]], axis=1))


def _clean(geom: Any, close: float = 1e-4) -> Any:
    """Union slivers closed (morphological closing by ``close`` m), simplified at OUTLINE_TOL.

    A closing only adds area (it fills slivers and notches narrower than ``2 * close``), so a
    closing that returns less area than it was given has failed, not cleaned: GEOS's mitre buffer
    can turn a valid union into an EMPTY polygon where parts touch at a vertex with another vertex
    microns away (two 65 x 130 mm steel plates of a Tekla export were dropped as "no plan
    footprint" that way). Where the loss exceeds :data:`_CLOSING_LOSS` the union is simplified as it
    is, unclosed: it is the element's exact plan (valid, snapped to the 1 um grid), left with the
    slivers the closing would have filled (narrower than ``2 * close``), and a small part keeps its
    real footprint. Scaling the closing to the element's size instead would change every small
    element's outline; this test changes none whose closing works: across the corpus's 16 files
    (6,138 closings) the working ones lose at most 0.03 mm2 of an element's plan (float noise
    along a plate's fillet) and no imported building but the one with the two failed closings
    changes (which lost all their area). An outline degenerate in itself (no area at all, or a
    1 mm dummy that the simplification at OUTLINE_TOL reduces below a footprint's 1 mm2) still
    comes out empty and its element is dropped by the callers, with its reason.
    """
    import shapely

    closed = geom.buffer(close, join_style="mitre", mitre_limit=10.0).buffer(
        -close, join_style="mitre", mitre_limit=10.0)
    if geom.area - closed.area > _CLOSING_LOSS:
        log.debug("closing by %g m lost %.3g of %.3g m2 (a failed buffer): the union is kept unclosed",
                  close, geom.area - closed.area, geom.area)
        closed = geom
    geom = shapely.simplify(closed, OUTLINE_TOL, preserve_topology=True)
    return shapely.make_valid(geom) if not geom.is_valid else geom


def _plan_union(tri2d: NDArray[np.float64], close: float = 1e-4, fast: bool = False) -> Any:
    """The cleaned union of plan triangles (T, 3, 2) (Polygon or MultiPolygon, maybe empty).

    Snapped to a 1 um grid (GEOS's snap-rounding overlay). ``fast``: GEOS's floating-point
    overlay, four times faster, whose outline after the simplification at OUTLINE_TOL can differ
    by up to OUTLINE_TOL; used for the footprints of beams and walls (:func:`_parse`),
    and not where that overlay fails or its union is thinner on average than
    :data:`_FAST_MIN_WIDTH` (a sliver, whose outline the grid decides as it always has).
    """
    import shapely

    polys = _tri_polygons(tri2d)
    if len(polys) == 0:
        return shapely.Polygon()
    union = None
    if fast:
        try:
            union = shapely.union_all(polys)
        except shapely.errors.GEOSException:
            union = None
        if union is not None and 2.0 * union.area < _FAST_MIN_WIDTH * union.length:
            union = None
    if union is None:
        union = shapely.union_all(polys, grid_size=1e-6)
    return _clean(union, close)


def _parts(geom: Any, min_area: float = 1e-4) -> list[Any]:
    import shapely

    return [p for p in shapely.get_parts(geom) if p.geom_type == "Polygon" and p.area >= min_area]


def _footprint(tri: NDArray[np.float64], fast: bool = False) -> NDArray[np.float64] | None:
    """Plan outline of triangles (T, 3, 3): the union's largest part, or its convex hull.

    ``fast``: the union in floating point (:func:`_plan_union`).
    """
    union = _plan_union(tri[:, :, :2], fast=fast)
    parts = sorted(_parts(union, 1e-6), key=lambda p: -p.area)
    if not parts:
        return None
    if parts[0].area >= 0.99 * union.area:
        return np.asarray(parts[0].exterior.coords)[:-1]
    return np.asarray(union.convex_hull.exterior.coords)[:-1]


def _safe_footprint(tri: NDArray[np.float64], fast: bool = False) -> NDArray[np.float64] | None:
    """:func:`_footprint`, None where the plan geometry is degenerate (the element is then dropped)."""
    try:
        return _footprint(tri, fast)
    except ValueError:  # SiteGeometryError included
        return None


def _degenerate(guid: str, ifc_class: str, name: str, exc: Exception) -> _Row:
    """The report row of an element dropped because its geometry cannot make an element."""
    return (guid, ifc_class, name, f"degenerate geometry, dropped: {exc}")


def _ring(points: Any) -> NDArray[np.float64]:
    return np.asarray(points, dtype=np.float64).reshape(-1, 2)


def _fill_notches(outer: NDArray[np.float64]) -> tuple[NDArray[np.float64], list[NDArray[np.float64]]]:
    """The outline with its notches filled, and the notches (see the module docstring, rule 7)."""
    import shapely

    ring = canonical_outline(outer, "slab outline", tol=OUTLINE_TOL)
    notches: list[NDArray[np.float64]] = []
    while len(ring) >= 6:
        n, area = len(ring), shapely.Polygon(ring).area
        best: tuple[float, int, int] | None = None
        for i in range(n):
            a0, a1 = ring[i - 1], ring[i]
            d = a1 - a0
            d = d / np.hypot(*d)
            rel = ring - a1
            off = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0])  # distance to the edge's line
            along = rel @ d
            for m in range(2, n - 2):
                j, k = (i + m) % n, (i + m + 1) % n
                if off[j] > OUTLINE_TOL or off[k] > OUTLINE_TOL or along[j] <= OUTLINE_TOL:
                    continue
                if along[k] <= along[j]:
                    continue
                chain = ring[[(i + t) % n for t in range(m + 1)]]
                pocket = shapely.Polygon(chain)
                filled = np.delete(ring, [(i + t) % n for t in range(1, m)], axis=0)
                fpoly = shapely.Polygon(filled)
                if not (pocket.is_valid and fpoly.is_valid) or pocket.area <= 1e-6:
                    continue
                if abs(fpoly.area - area - pocket.area) > 1e-6 * max(1.0, fpoly.area):
                    continue  # not a pocket cut into the slab
                if pocket.area > NOTCH_FRACTION * fpoly.area:
                    continue
                if best is None or pocket.area < best[0]:
                    best = (pocket.area, i, m)
        if best is None:
            break
        _, i, m = best
        notches.append(ring[[(i + t) % n for t in range(m + 1)]])
        ring = canonical_outline(np.delete(ring, [(i + t) % n for t in range(1, m)], axis=0),
                                 "slab outline", tol=OUTLINE_TOL)
    return ring, notches


# ----------------------------------------------------------------------------- parsing
@dataclass
class _Raw:
    """One tessellated IFC element before the rules."""

    order: int
    guid: str
    ifc_class: str
    name: str
    kind: str
    storey: int
    predefined: str | None
    tri: NDArray[np.float64]  # (T, 3, 3) project frame
    voids: tuple[tuple[str, str, Any], ...] = ()  # (guid, name, plan polygon) of its openings

    @property
    def zmin(self) -> float:
        return float(self.tri[:, :, 2].min())

    @property
    def zmax(self) -> float:
        return float(self.tri[:, :, 2].max())

    def bbox(self) -> NDArray[np.float64]:
        v = self.tri.reshape(-1, 3)
        return np.concatenate([v.min(axis=0), v.max(axis=0)])


@dataclass
class _Top:
    """A slab's flat top: elevation and plan polygon; or why it has none."""

    z: float
    polygon: Any  # shapely geometry, empty when not flat
    flat: bool


def _slab_top(raw: _Raw) -> _Top:
    import shapely

    tri = raw.tri
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-12
    nz = np.zeros(len(tri))
    nz[ok] = n[ok, 2] / length[ok]
    plan_area = 0.5 * length * np.abs(nz)
    up = nz > 0.05
    z = raw.zmax
    top = (nz > 0.9999) & np.all(np.abs(tri[:, :, 2] - z) <= DUPLICATE_TOL, axis=1)
    if plan_area[top].sum() < FLAT_FRACTION * max(plan_area[up].sum(), 1e-12):
        return _Top(z, shapely.Polygon(), False)
    return _Top(z, _plan_union(tri[top][:, :, :2]), True)


def _check_transform(transform: ArrayLike | None) -> NDArray[np.float64]:
    if transform is None:
        return np.eye(4)
    try:
        t = np.array(transform, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"transform must be a 4x4 project_from_ifc array, got {transform!r}") from None
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise ValueError(f"transform must be a finite 4x4 project_from_ifc array, got shape {t.shape}")
    r = t[:3, :3]
    if (not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0
            or not np.allclose(t[3], [0, 0, 0, 1]) or abs(r[2, 2] - 1.0) > 1e-6):
        raise ValueError(
            "transform must be rigid (a rotation about z and a translation: slab tops stay "
            f"horizontal, metres stay metres), got\n{t}"
        )
    return t


def _open(path: Path) -> tuple[Any, bytes]:
    """The parsed file and its bytes, after the guards on size and completeness."""
    ios = require_ifcopenshell()
    if not path.exists():
        raise FileNotFoundError(f"IFC file not found: {str(path)!r}")
    if not path.is_file():
        raise IfcImportError(f"{str(path)!r} is not a file (an IFC file was expected)")
    with open(path, "rb") as fh:
        head = fh.read(64).lstrip()
    if not head.startswith(b"ISO-10303-21"):
        raise IfcImportError(
            f"{str(path)!r} is not an IFC file: an IFC-SPF file starts with 'ISO-10303-21;', "
            f"this one with {head[:24]!r} (ifcXML and ifcZIP are not supported)"
        )
    check_size(path)
    text = path.read_bytes()
    check_complete(path, text)
    try:
        return ios.open(str(path)), text
    except Exception as exc:  # ifcopenshell raises its own, untyped errors
        raise IfcImportError(f"{str(path)!r} is not a readable IFC file: {exc}") from exc


def _unset_star_arguments(f: Any, text: bytes) -> tuple[tuple[str, int, str], ...]:
    """Read a ``*`` written where the schema wants a value or ``$`` as unset, in the parsed file ``f``.

    Renga writes ``*`` (a derived attribute) for unset optional attributes; the geometry kernel
    then refuses the element. Returns ``(ifc class, count, what)`` for the report.
    """
    import ifcopenshell.ifcopenshell_wrapper as wrapper

    schema = wrapper.schema_by_name(f.schema)
    counts: Counter[str] = Counter()
    for entity_id, _, positions in star_arguments(text):
        inst = f.by_id(entity_id)
        derived = schema.declaration_by_name(inst.is_a()).as_entity().derived()
        for k in positions:
            if k < len(derived) and not derived[k]:
                inst.unset_attribute_value(k)
                counts[inst.is_a()] += 1
    what = "'*' (derived) where the schema wants a value or '$': read as unset"
    return tuple((c, n, what) for c, n in sorted(counts.items()))


def _matrix_m(placement: Any, scale: float) -> NDArray[np.float64]:
    import ifcopenshell.util.placement

    m = np.array(ifcopenshell.util.placement.get_local_placement(placement), dtype=np.float64)
    m[:3, 3] *= scale
    return m


def _georeference(f: Any, scale: float) -> dict[str, Any]:
    """IfcSite placement, TrueNorth and IfcMapConversion, as plain data (recorded, not applied).

    ``true_north``: the model context's TrueNorth direction in the IFC plan and its angle from +y,
    counter-clockwise, degrees. ``map_conversion`` (IFC4 and later): IfcMapConversion's fields
    and the target CRS name. ``site_placement``: the IfcSite's 4x4 world placement in metres.
    """
    out: dict[str, Any] = {"site_placement": None, "true_north": None, "map_conversion": None,
                           "site_reference": None}
    sites = f.by_type("IfcSite")
    if sites:
        s = sites[0]
        if s.ObjectPlacement is not None:
            out["site_placement"] = _matrix_m(s.ObjectPlacement, scale).tolist()
        out["site_reference"] = {"latitude": s.RefLatitude and tuple(s.RefLatitude),
                                 "longitude": s.RefLongitude and tuple(s.RefLongitude),
                                 "elevation_m": None if s.RefElevation is None else s.RefElevation * scale}
    for ctx in f.by_type("IfcGeometricRepresentationContext", include_subtypes=False):
        if ctx.ContextType == "Model" and ctx.TrueNorth is not None:
            x, y = (list(ctx.TrueNorth.DirectionRatios) + [0.0, 0.0])[:2]
            out["true_north"] = {"direction": (float(x), float(y)),
                                 "angle_from_y_deg": math.degrees(math.atan2(-x, y))}
    if f.schema != "IFC2X3":
        for mc in f.by_type("IfcMapConversion"):
            crs = mc.TargetCRS
            out["map_conversion"] = {
                "eastings": mc.Eastings, "northings": mc.Northings, "orthogonal_height": mc.OrthogonalHeight,
                "x_axis_abscissa": mc.XAxisAbscissa, "x_axis_ordinate": mc.XAxisOrdinate,
                "scale": mc.Scale, "target_crs": None if crs is None else crs.Name,
            }
    return out


# ----------------------------------------------------------------------------- the file
def _imported_by_kind(f: Any, products: list[Any], path: Path) -> dict[str, list[Any]]:
    """The products of each imported class by element kind; an error when there is no slab and no column."""
    by_kind = {kind: f.by_type(cls) for cls, kind in IMPORTED_CLASSES.items()}
    if not by_kind["slab"] and not by_kind["column"]:
        counts = Counter(p.is_a() for p in products)
        found = ", ".join(f"{c} x{n}" for c, n in counts.most_common()) or "no products at all"
        raise IfcImportError(
            f"{str(path)!r} has no IfcSlab and no IfcColumn, so no structural landmarks: it contains "
            f"{found}"
        )
    return by_kind


@dataclass(frozen=True)
class _Storeys:
    """The storeys bottom up, and each IfcBuildingStorey's place among them (by entity id)."""

    storeys: tuple[Storey, ...]
    index: dict[int, int]

    def of(self, e: Any, zmin: float) -> int:
        """The storey that contains ``e`` (through aggregates), else the highest at or below ``zmin``."""
        import ifcopenshell.util.element as ue

        c = ue.get_container(e, ifc_class="IfcBuildingStorey")
        if c is not None and c.id() in self.index:
            return self.index[c.id()]
        below = [k for k, s in enumerate(self.storeys) if s.elevation <= zmin + 0.1]
        return below[-1] if below else 0

    def name(self, k: int) -> str:
        """The name of storey ``k``."""
        return self.storeys[k].name


def _storeys(f: Any, scale: float, transform: NDArray[np.float64]) -> _Storeys:
    """IfcBuildingStorey in elevation order (its placement's z in the project frame), names unique.

    A file without storeys gets one, ``"Building"`` at elevation 0.
    """
    entities = []
    for s in f.by_type("IfcBuildingStorey"):
        if s.ObjectPlacement is not None:
            z = float(_matrix_m(s.ObjectPlacement, scale)[2, 3])
        else:
            z = float(s.Elevation or 0.0) * scale
        entities.append((z + transform[2, 3], s.id(), s))
    entities.sort(key=lambda t: (t[0], t[1]))
    names = [s.Name or f"Storey {k}" for k, (_, _, s) in enumerate(entities)]
    seen: Counter[str] = Counter()
    for k, n in enumerate(names):
        seen[n] += 1
        if seen[n] > 1:
            names[k] = f"{n} ({seen[n]})"
    storeys = [Storey(n, z) for n, (z, _, _) in zip(names, entities, strict=True)]
    index = {sid: k for k, (_, sid, _) in enumerate(entities)}
    return _Storeys(tuple(storeys) or (Storey("Building", 0.0),), index)


def _tessellate(ios_geom: Any, settings: Any, f: Any, include: list[Any]) -> dict[int, _Shape]:
    """Vertices (V, 3) and triangles (T, 3) of the ``include`` products, by entity id, world metres."""
    shapes: dict[int, _Shape] = {}
    if include:
        it = ios_geom.iterator(settings, f, 1, include=include)
        if it.initialize():
            while True:
                sh = it.get()
                g = sh.geometry
                shapes[sh.id] = (np.asarray(g.verts, dtype=np.float64).reshape(-1, 3),
                                 np.asarray(g.faces, dtype=np.int64).reshape(-1, 3))
                if not it.next():
                    break
    return shapes


def _to_project(verts: NDArray[np.float64], transform: NDArray[np.float64]) -> NDArray[np.float64]:
    """Vertices (..., 3) from the IFC world frame into the project frame."""
    return verts @ transform[:3, :3].T + transform[:3, 3]


def _voids(ios_geom: Any, settings: Any, slab: Any, transform: NDArray[np.float64]) -> tuple:
    """``(guid, name, plan convex hull)`` of the IfcOpeningElements voiding ``slab`` (with geometry)."""
    import shapely

    voids = []
    for rel in getattr(slab, "HasOpenings", ()) or ():
        op = rel.RelatedOpeningElement
        try:
            osh = ios_geom.create_shape(settings, op)
        except Exception:  # an opening without geometry: not matchable
            continue
        ov = _to_project(np.asarray(osh.geometry.verts, dtype=np.float64).reshape(-1, 3), transform)
        if len(ov) >= 3:
            hull = shapely.MultiPoint(ov[:, :2]).convex_hull
            voids.append((op.GlobalId, op.Name or "opening", hull))
    return tuple(voids)


def _raw(ios_geom: Any, settings: Any, order: int, e: Any, shape: _Shape, transform: NDArray[np.float64],
         storeys: _Storeys) -> _Raw:
    """The tessellated product ``e`` (``order``-th in file order) in the project frame."""
    import ifcopenshell.util.element as ue

    v, fc = shape
    tri = _to_project(v, transform)[fc]
    kind = IMPORTED_CLASSES[next(c for c in IMPORTED_CLASSES if e.is_a(c))]
    predefined = ue.get_predefined_type(e) if kind == "slab" else None
    voids = _voids(ios_geom, settings, e, transform) if kind == "slab" else ()
    storey = storeys.of(e, float(tri[:, :, 2].min()))
    return _Raw(order, e.GlobalId, e.is_a(), e.Name or e.is_a(), kind, storey, predefined, tri, voids)


def _mesh_of(tris: list[NDArray[np.float64]]) -> TriangleMesh:
    t = np.concatenate(tris)
    return TriangleMesh(t.reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3))


# ----------------------------------------------------------------------------- the rules
def _no_body_geometry(
    include: list[Any], shapes: dict[int, _Shape]
) -> tuple[list[tuple[int, Any]], list[_Row]]:
    """Rule 1: the products the iterator tessellated, with their file order; the others dropped."""
    tessellated: list[tuple[int, Any]] = []
    dropped: list[_Row] = []
    for order, e in enumerate(include):
        if e.id() not in shapes or len(shapes[e.id()][1]) == 0:
            dropped.append((e.GlobalId, e.is_a(), e.Name or e.is_a(), _no_body_reason(e)))
        elif not np.all(np.isfinite(shapes[e.id()][0])):
            dropped.append((e.GlobalId, e.is_a(), e.Name or e.is_a(), "non-finite body geometry"))
        else:
            tessellated.append((order, e))
    return tessellated, dropped


def _no_body_reason(e: Any) -> str:
    """Why ``e`` has no tessellation: an aggregate whose parts carry the geometry, or no body at all."""
    parts = [p for rel in getattr(e, "IsDecomposedBy", ()) or () for p in rel.RelatedObjects]
    if parts:
        classes = ", ".join(f"{n} {c}" for c, n in sorted(Counter(p.is_a() for p in parts).items()))
        return f"aggregate without a body of its own: its parts ({classes}) are imported in its place"
    return "no body geometry"


def _coincident(u: _Raw, r: _Raw, boxes: dict[str, NDArray[np.float64]], footprints: _Footprints) -> bool:
    """Whether ``r`` repeats ``u``: same kind, bounding box within DUPLICATE_TOL, same footprint."""
    import shapely

    if u.kind != r.kind or np.max(np.abs(boxes[u.guid] - boxes[r.guid])) > DUPLICATE_TOL:
        return False
    fa, fb = footprints[u.guid], footprints[r.guid]
    if fa is None or fb is None:
        return False
    pa, pb = shapely.Polygon(fa), shapely.Polygon(fb)
    return pa.symmetric_difference(pb).area <= 0.01 * max(pa.area, 1e-9)


def _coincident_duplicates(
    raws: list[_Raw], footprints: _Footprints
) -> tuple[list[_Raw], list[_Row]]:
    """Rule 2: the elements that repeat no earlier one; the coincident duplicates dropped.

    The earlier elements are binned by their bounding box's lower corner in cells of
    ``_DUPLICATE_CELL``: a twin's corner lies within DUPLICATE_TOL, so in the same or a
    neighbouring cell, and only those are compared (the first twin in file order wins).
    """
    boxes = {r.guid: r.bbox() for r in raws}
    cells: dict[tuple[int, ...], list[int]] = {}
    unique: list[_Raw] = []
    dropped: list[_Row] = []
    for r in raws:
        cell = np.floor(boxes[r.guid][:3] / _DUPLICATE_CELL).astype(np.int64)
        near = sorted(k for d in _NEIGHBOURS for k in cells.get(tuple(cell + d), ()))
        twin = next((unique[k] for k in near if _coincident(unique[k], r, boxes, footprints)), None)
        if twin is not None:
            why = f"coincident duplicate of {twin.guid} ({twin.name!r})"
            dropped.append((r.guid, r.ifc_class, r.name, why))
        else:
            cells.setdefault(tuple(cell), []).append(len(unique))
            unique.append(r)
    return unique, dropped


def _finish_floor(r: _Raw, thick: list[_Raw], footprints: _Footprints) -> str | None:
    """Rule 3: why slab ``r`` is dropped as thinner than MIN_SLAB_THICKNESS, or None if it is not."""
    import shapely

    t = r.zmax - r.zmin
    if t < MIN_SLAB_THICKNESS:
        fp = footprints[r.guid]
        under = [s for s in thick if abs(s.zmax - r.zmin) <= SAME_LEVEL_TOL and fp is not None
                 and footprints[s.guid] is not None
                 and shapely.Polygon(footprints[s.guid]).intersects(shapely.Polygon(fp))]
        return (f"finish floor {1000 * t:.0f} mm thick lying on slab {under[0].guid} ({under[0].name!r})"
                if under else f"{1000 * t:.0f} mm thick, thinner than {1000 * MIN_SLAB_THICKNESS:.0f} mm: "
                "not a structural floor")
    return None


def _not_a_floor(r: _Raw) -> str | None:
    """Rule 4: why slab ``r`` bears no landmarks for its PredefinedType, or None if it is a floor."""
    if r.predefined not in FLOOR_TYPES:
        return f"slab of type {r.predefined}: rendered, bears no landmarks"
    return None


def _sloped_slab(top: _Top) -> str | None:
    """Rule 5: why a slab with this top bears no landmarks (not flat-topped), or None."""
    if not top.flat:
        return "sloped or stepped top (no flat top face): rendered, no landmarks"
    return None


def _at_terrain(top: _Top) -> str | None:
    """Rule 5b: why a slab with this top bears no landmarks (ground-bearing, at terrain level), or None."""
    if top.z <= GROUND_TOL:
        return (f"ground-bearing slab, top at z = {top.z:.2f} m, within {GROUND_TOL} m of the terrain: "
                "rendered, no landmarks (a camera sees only the ground there)")
    return None


def _floor_pieces(
    slabs: list[_Raw], tops: dict[str, _Top], footprints: _Footprints
) -> tuple[list[_Raw], list[tuple[_Raw, str]], list[_Row]]:
    """Rules 3-5 over the slabs, in order.

    Returns the floor pieces, the slabs rendered without landmarks (with why) and the dropped rows.
    """
    thick = [r for r in slabs if r.zmax - r.zmin >= MIN_SLAB_THICKNESS]
    pieces: list[_Raw] = []
    rendered: list[tuple[_Raw, str]] = []
    dropped: list[_Row] = []
    for r in slabs:
        finish = _finish_floor(r, thick, footprints)
        if finish is not None:
            dropped.append((r.guid, r.ifc_class, r.name, finish))
            continue
        why = _not_a_floor(r) or _sloped_slab(tops[r.guid]) or _at_terrain(tops[r.guid])
        if why is not None:
            rendered.append((r, why))
        else:
            pieces.append(r)
    return pieces, rendered, dropped


def _root(parent: list[int], a: int) -> int:
    """The root of ``a`` in the union-find forest ``parent`` (path halving)."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


def _floor_groups(pieces: list[_Raw], tops: dict[str, _Top]) -> list[list[_Raw]]:
    """Pieces of one storey's floor grouped into slabs (rule 6).

    Connected components of "same level and at most PRECAST_JOINT apart", in file order.
    """
    parent = list(range(len(pieces)))
    for a in range(len(pieces)):
        for b in range(a + 1, len(pieces)):
            ta, tb = tops[pieces[a].guid], tops[pieces[b].guid]
            if abs(ta.z - tb.z) <= SAME_LEVEL_TOL and ta.polygon.distance(tb.polygon) <= PRECAST_JOINT:
                parent[_root(parent, b)] = _root(parent, a)
    roots: dict[int, list[_Raw]] = {}
    for a, r in enumerate(pieces):
        roots.setdefault(_root(parent, a), []).append(r)
    return sorted(roots.values(), key=lambda g: g[0].order)


def _precast_pieces(pieces: list[_Raw], tops: dict[str, _Top]) -> list[list[_Raw]]:
    """Rule 6: the floor pieces grouped into slabs, storey by storey."""
    groups: list[list[_Raw]] = []
    for storey in sorted({r.storey for r in pieces}):
        groups += _floor_groups([r for r in pieces if r.storey == storey], tops)
    return groups


def _slab_openings(part: Any, notches: list[NDArray[np.float64]], voids: list[tuple[str, str, Any]],
                   guid: str, name: str, failed: list[_Row]) -> tuple[Hole, ...]:
    """Rule 7's openings of one slab: interior rings and notches, after the void there if any.

    An opening too small to have an outline at OUTLINE_TOL is dropped, its row appended to ``failed``.
    """
    import shapely

    rings = [_ring(h.coords)[:-1] for h in part.interiors] + list(notches)
    outlines = []
    for ring in rings:
        try:
            outlines.append(canonical_outline(ring, "slab opening", tol=OUTLINE_TOL))
        except SiteGeometryError as exc:
            lo = ring.min(axis=0)
            failed.append((f"{guid}/opening at ({lo[0]:.2f}, {lo[1]:.2f})", "IfcOpeningElement", name,
                           f"degenerate opening, dropped (the slab is kept): {exc}"))
    outlines.sort(key=lambda h: (h[0, 1], h[0, 0]))
    holes = []
    for j, h in enumerate(outlines):
        at = shapely.Polygon(h).representative_point()
        match = [v for v in voids if v[2].buffer(0.01).contains(at)]
        if match:
            holes.append(Hole(match[0][1], h, guid=match[0][0], source="void"))
        else:
            holes.append(Hole(f"{name} opening {j}", h, guid=f"{guid}/opening {j}", source="outline"))
    return tuple(holes)


def _slab_outline(group: list[_Raw], tops: dict[str, _Top]) -> tuple[list[tuple[tuple, Slab]], list[_Row]]:
    """Rule 7: the slab(s) of one group of floor pieces, one per part of their tops' union, keyed.

    A part whose outline or openings are degenerate is dropped (its row in the second list).
    """
    import shapely

    first = group[0]
    if len(group) > 1:
        union = shapely.union_all([tops[r.guid].polygon for r in group])
        poly = _clean(union, PRECAST_JOINT / 2 + 1e-4)
    else:
        poly = tops[first.guid].polygon
    parts = sorted(_parts(poly), key=lambda p: (p.bounds[1], p.bounds[0]))
    guid = "+".join(r.guid for r in group)
    name = " + ".join(r.name for r in group)
    z_top = max(tops[r.guid].z for r in group)
    z_bottom = min(r.zmin for r in group)
    mesh = _mesh_of([r.tri for r in group])
    voids = [v for r in group for v in r.voids]
    out: list[tuple[tuple, Slab]] = []
    failed: list[_Row] = []
    for k, part in enumerate(parts):
        pguid = guid if len(parts) == 1 else f"{guid}#{k}"
        pname = name if len(parts) == 1 else f"{name} part {k}"
        try:
            outer, notches = _fill_notches(_ring(part.exterior.coords)[:-1])
            holes = _slab_openings(part, notches, voids, pguid, pname, failed)
            slab = Slab(guid=pguid, name=pname, storey=first.storey, outline=outer, z_bottom=z_bottom,
                        z_top=z_top, mesh=mesh, holes=holes)
        except ValueError as exc:  # SiteGeometryError included
            failed.append(_degenerate(pguid, first.ifc_class, pname, exc))
            continue
        out.append(((1, first.storey, first.order, k), slab))
    return out, failed


def _floors(
    groups: list[list[_Raw]], tops: dict[str, _Top], storeys: _Storeys
) -> tuple[list[tuple[tuple, Element]], dict[int, list[str]], list[_Row], list[_Row]]:
    """Rules 6-7 applied: the floor slabs (keyed), each storey's floor guids, the kept and dropped rows."""
    elements: list[tuple[tuple, Element]] = []
    floors: dict[int, list[str]] = {}
    kept: list[_Row] = []
    dropped: list[_Row] = []
    for group in groups:
        first = group[0]
        slabs, failed = _slab_outline(group, tops)
        dropped += failed
        if not slabs:
            continue
        for key, slab in slabs:
            elements.append((key, slab))
            floors.setdefault(first.storey, []).append(slab.guid)
        role = (f"floor of {storeys.name(first.storey)}" + (f", one slab with {len(group) - 1} more "
                f"piece(s) at most {100 * PRECAST_JOINT:.0f} cm apart" if len(group) > 1 else ""))
        kept += [(r.guid, r.ifc_class, r.name, role) for r in group]
    return elements, floors, kept, dropped


def _rendered_slabs(
    rendered: list[tuple[_Raw, str]], footprints: _Footprints
) -> tuple[list[tuple[tuple, Element]], list[_Row], list[_Row]]:
    """Rules 4-5's slabs, kept for rendering (footprint outline, ``structural=False``); kept, dropped."""
    elements: list[tuple[tuple, Element]] = []
    kept: list[_Row] = []
    dropped: list[_Row] = []
    for r, why in rendered:
        fp = footprints[r.guid]
        if fp is None:
            dropped.append((r.guid, r.ifc_class, r.name, "no plan footprint"))
            continue
        try:
            slab = Slab(guid=r.guid, name=r.name, storey=r.storey, outline=fp, z_bottom=r.zmin,
                        z_top=r.zmax, mesh=_mesh_of([r.tri]), structural=False)
        except ValueError as exc:  # SiteGeometryError included
            dropped.append(_degenerate(r.guid, r.ifc_class, r.name, exc))
            continue
        elements.append(((1, r.storey, r.order, 0), slab))
        kept.append((r.guid, r.ifc_class, r.name, why))
    return elements, kept, dropped


def _columns_beams_walls(
    unique: list[_Raw], footprints: _Footprints, storeys: _Storeys
) -> tuple[list[tuple[tuple, Element]], list[_Row], list[_Row]]:
    """Rule 8: columns (axis at the top face's centroid), beams and walls, keyed; kept, dropped."""
    import shapely

    elements: list[tuple[tuple, Element]] = []
    kept: list[_Row] = []
    dropped: list[_Row] = []
    columns = 0
    for r in unique:
        if r.kind == "slab":
            continue
        fp = footprints[r.guid]
        if fp is None or r.zmax - r.zmin <= 1e-6:
            dropped.append((r.guid, r.ifc_class, r.name, "no plan footprint or no height"))
            continue
        squat = _not_a_column(r, fp) if r.kind == "column" else None
        kind = "beam" if squat else r.kind
        extra: dict[str, Any] = {}
        if kind == "column":
            top = _slab_top(r)
            c = (top.polygon if top.flat and not top.polygon.is_empty else shapely.Polygon(fp)).centroid
            extra = {"axis": (c.x, c.y), "index": columns}
        try:
            element = _ELEMENT_CLASS[kind](guid=r.guid, name=r.name, storey=r.storey, outline=fp,
                                           z_bottom=r.zmin, z_top=r.zmax, mesh=_mesh_of([r.tri]), **extra)
        except ValueError as exc:  # SiteGeometryError included
            dropped.append(_degenerate(r.guid, r.ifc_class, r.name, exc))
            continue
        columns += kind == "column"
        elements.append(((_KIND_ORDER[kind], r.storey, r.order, 0), element))
        kept.append((r.guid, r.ifc_class, r.name, squat or f"{kind} of {storeys.name(r.storey)}"))
    return elements, kept, dropped


def _not_a_column(r: _Raw, footprint: NDArray[np.float64]) -> str | None:
    """Rule 8b: why an IfcColumn is no column (a plate, a railing post), or None if it is one.

    Such an element (Tekla exports plates and railing posts as IfcColumn) is shorter than
    :data:`MIN_COLUMN_HEIGHT` or squatter than its plan is wide; it is rendered as a member
    (a beam) and bears no column-top landmark.
    """
    height = r.zmax - r.zmin
    extent = float(np.max(footprint.max(axis=0) - footprint.min(axis=0)))
    if height < MIN_COLUMN_HEIGHT or height < extent:
        return (f"IfcColumn {height:.2f} m tall and {extent:.2f} m wide (a plate or post, not a column "
                f"at least {MIN_COLUMN_HEIGHT} m tall and taller than wide): rendered as a member, "
                "no column-top landmark")
    return None


# ----------------------------------------------------------------------------- the site
def _in_order(keyed: list[tuple[tuple, Element]]) -> tuple[Element, ...]:
    """The elements in element order (kind, storey, file order), names unique within a kind.

    A name used twice in a kind gets its guid's prefix: the first 8 characters, or as many as
    tell that name's elements apart (exports copy elements level by level and their GlobalIds
    can share 14 characters).
    """
    ordered = [e for _, e in sorted(keyed, key=lambda t: t[0])]
    groups: dict[tuple[str, str], list[str]] = {}
    for e in ordered:
        groups.setdefault((e.kind, e.name), []).append(e.guid)
    width = {key: _distinct_prefix(guids) for key, guids in groups.items() if len(guids) > 1}
    return tuple(e if (e.kind, e.name) not in width
                 else dataclasses.replace(e, name=f"{e.name} [{e.guid[:width[(e.kind, e.name)]]}]")
                 for e in ordered)


def _distinct_prefix(guids: list[str], shortest: int = 8) -> int:
    """The fewest leading characters (at least ``shortest``) that tell ``guids`` apart."""
    width = shortest
    while len({g[:width] for g in guids}) < len(guids) and width < max(map(len, guids)):
        width += 1
    return width


def _stages(
    elements: tuple[Element, ...], floors: dict[int, list[str]], storeys: _Storeys
) -> tuple[Stage, ...]:
    """``"<storey>/slab"`` and ``"<storey>/columns"`` for each storey with a floor, in build order.

    A building without a floor gets :func:`_column_stages` instead.
    """
    stages: list[Stage] = []
    for s in sorted(floors):
        below = {e.guid for e in elements if e.storey < s}
        slab_guids = {g for t in sorted(floors) if t <= s for g in floors[t]}
        built = frozenset(below | slab_guids)
        stages.append(Stage(f"{storeys.name(s)}/slab", built, tuple(floors[s])))
        cols = {e.guid for e in elements if isinstance(e, Column) and e.storey == s}
        if cols:
            stages.append(Stage(f"{storeys.name(s)}/columns", built | cols, tuple(floors[s])))
    return tuple(stages) if stages else _column_stages(elements, storeys)


def _column_stages(elements: tuple[Element, ...], storeys: _Storeys) -> tuple[Stage, ...]:
    """Columns-only stages of a building without a floor (a frame, or slabs only at the terrain).

    ``"<storey>/columns"`` = every kept element of lower storeys plus the storey's columns (not its
    beams: the column tops are the landmarks), for each storey where at least four column tops
    stand exposed above the terrain (:data:`GROUND_TOL`): fewer cannot give a camera a pose.
    """
    stages: list[Stage] = []
    for s in sorted({e.storey for e in elements if isinstance(e, Column)}):
        built = frozenset(e.guid for e in elements
                          if e.storey < s or (isinstance(e, Column) and e.storey == s))
        standing = tuple(e for e in elements if e.guid in built)
        tops = [p for p in exposed_landmarks("column_tops", standing, (), ()) if p[4][2] > GROUND_TOL]
        if len(tops) >= _MIN_LANDMARKS:
            stages.append(Stage(f"{storeys.name(s)}/columns", built, ()))
    return tuple(stages)


# Short labels of the rules' reasons, for the one-line refusal (first match wins).
_REASON_LABELS = (
    ("ground-bearing", "ground-bearing at the terrain"), ("sloped", "sloped or stepped"),
    ("finish floor", "finish floors"), ("thinner than", "thinner than a structural floor"),
    ("aggregate", "aggregates of parts"), ("duplicate", "coincident duplicates"),
    ("no body", "without body geometry"), ("degenerate", "degenerate"),
)


def _reason_label(why: str) -> str:
    """A rule's reason as a short label (``"sloped or stepped"``) to count in the refusal."""
    return next((label for key, label in _REASON_LABELS if key in why), why.split(":")[0])


def _no_floor(path: Path, by_kind: dict[str, list[Any]], dropped: list[_Row],
              rendered: list[tuple[_Raw, str]], elements: tuple[Element, ...]) -> IfcImportError:
    """The error for a file without a stage a camera can use: one line, the reasons counted."""
    reasons = Counter(_reason_label(why) for _, cls, _, why in dropped if cls.startswith("IfcSlab"))
    reasons.update(_reason_label(why) for _, why in rendered)
    slabs = "; ".join(f"{n} {why}" for why, n in reasons.most_common()) or "none imported"
    columns = sum(isinstance(e, Column) for e in elements)
    return IfcImportError(
        f"{str(path)!r} has no stage a camera can use: no flat-topped structural floor above the "
        f"terrain, and no storey with {_MIN_LANDMARKS} column tops exposed above the terrain "
        f"({len(by_kind['slab'])} IfcSlab: {slabs}; {len(by_kind['column'])} IfcColumn, {columns} kept); "
        "ifc_report() is not available for it, set logging to DEBUG for every element"
    )


def _not_imported(products: list[Any], include: list[Any]) -> tuple[tuple[str, int, str], ...]:
    """``(ifc class, count, reason)`` of the products not imported, by class."""
    imported_ids = {e.id() for e in include}
    counts: Counter[tuple[str, str]] = Counter()
    for p in products:
        if p.id() in imported_ids:
            continue
        reason = next((why for cls, why in _NOT_IMPORTED if p.is_a(cls)), "non-structural: not imported")
        counts[(p.is_a(), reason)] += 1
    return tuple(sorted(((c, n, why) for (c, why), n in counts.items()), key=lambda t: t[0]))


@dataclass(frozen=True)
class _Parsed:
    elements: tuple[Element, ...]
    storeys: tuple[Storey, ...]
    stages: tuple[Stage, ...]
    report: ImportReport
    source: dict[str, Any]


def _parse(path: Path, transform: NDArray[np.float64]) -> _Parsed:
    """The elements, storeys and stages of the IFC file ``path``: the rules of the module docstring."""
    ios = require_ifcopenshell()
    f, text = _open(path)
    scale = float(ios.util.unit.calculate_unit_scale(f))
    check_coordinates(path, text, scale)
    repaired = _unset_star_arguments(f, text)
    products = f.by_type("IfcProduct")
    by_kind = _imported_by_kind(f, products, path)
    storeys = _storeys(f, scale, transform)
    settings = ios.geom.settings()
    settings.set("use-world-coords", True)
    include = [e for kind in ("column", "slab", "beam", "wall") for e in by_kind[kind]]
    shapes = _tessellate(ios.geom, settings, f, include)
    tessellated, no_body = _no_body_geometry(include, shapes)
    raws = [_raw(ios.geom, settings, k, e, shapes[e.id()], transform, storeys) for k, e in tessellated]
    footprints = {r.guid: _safe_footprint(r.tri, fast=r.kind in _FAST_UNION_KINDS) for r in raws}
    unique, duplicates = _coincident_duplicates(raws, footprints)
    slabs = [r for r in unique if r.kind == "slab"]
    tops = {r.guid: _slab_top(r) for r in slabs}
    pieces, rendered, finish = _floor_pieces(slabs, tops, footprints)
    floor_slabs, floors, floors_kept, floors_dropped = _floors(_precast_pieces(pieces, tops), tops, storeys)
    shown, shown_kept, no_footprint = _rendered_slabs(rendered, footprints)
    others, others_kept, others_dropped = _columns_beams_walls(unique, footprints, storeys)
    dropped = no_body + duplicates + finish + floors_dropped + no_footprint + others_dropped
    elements = _in_order(floor_slabs + shown + others)
    stages = _stages(elements, floors, storeys)
    report = ImportReport(str(path), tuple(floors_kept + shown_kept + others_kept), tuple(dropped),
                          _not_imported(products, include), repaired)
    if not stages:
        log.debug("%s", report.summary())
        raise _no_floor(path, by_kind, dropped, rendered, elements)
    source = {
        "format": "ifc", "path": str(path), "schema": f.schema,
        "units": {"length_unit_in_m": scale},
        "transform": transform.tolist(), **_georeference(f, scale), "report": report,
    }
    return _Parsed(elements, storeys.storeys, stages, report, source)


@functools.lru_cache(maxsize=8)
def _parse_cached(path: str, mtime_ns: int, size: int, transform: bytes) -> _Parsed:
    """The parse of ``path``: from the disk cache (:mod:`.ifc_cache`), else parsed and stored there.

    The size guard comes first (a stat; the key hashes the whole file).
    """
    check_size(Path(path))
    entry = ifc_cache.cache_path(file_sha256(path), transform)
    with ifc_cache.entry_lock(entry):  # another process parsing the same file: wait for its entry
        parsed = ifc_cache.read_entry(entry)
        if isinstance(parsed, _Parsed):
            report = dataclasses.replace(parsed.report, path=path)  # the same content, maybe elsewhere
            parsed = dataclasses.replace(parsed, report=report, source={**parsed.source, "path": path,
                                                                        "report": report})
            log.info("%s (from the parse cache %s)", report.summary(), entry)
            return parsed
        parsed = _parse(Path(path), np.frombuffer(transform, dtype=np.float64).reshape(4, 4).copy())
        ifc_cache.write_entry(entry, parsed)
    log.info("%s", parsed.report.summary())
    return parsed


def _parsed(path: str | os.PathLike, transform: ArrayLike | None) -> _Parsed:
    require_ifcopenshell()
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    p = Path(path).expanduser()
    t = _check_transform(transform)
    if not p.exists():
        raise FileNotFoundError(f"IFC file not found: {str(p)!r}")
    st = p.resolve().stat()
    return _parse_cached(str(p.resolve()), st.st_mtime_ns, st.st_size, t.tobytes())


# ----------------------------------------------------------------------------- public API
def ifc_stages(path: str | os.PathLike, *, transform: ArrayLike | None = None) -> list[str]:
    """The construction stages ``path`` supports, in build order (``"<storey>/slab"``, ...).

    Raises:
        FileNotFoundError: if the file does not exist.
        IfcImportError: if it is not IFC, has no slab or column, or no stage a camera can use
            (no flat structural floor above the terrain and no four exposed column tops).
        ImportError: if ifcopenshell is not installed (names the ``ifc`` extra).
    """
    return [st.name for st in _parsed(path, transform).stages]


def ifc_report(path: str | os.PathLike, *, transform: ArrayLike | None = None) -> ImportReport:
    """What importing ``path`` keeps and drops, and why (also ``site.source["report"]``)."""
    return _parsed(path, transform).report


def load_ifc(
    path: str | os.PathLike, stage: str | None = None, *, transform: ArrayLike | None = None
) -> Site:
    """The :class:`~uav_struct_env.site.Site` of an IFC file at ``stage``.

    Args:
        path: an IFC-SPF file (``.ifc``; IFC2X3, IFC4, IFC4X3).
        stage: one of :func:`ifc_stages` (``"Level 2/slab"``); None: the last (highest) stage.
        transform: 4x4 ``project_from_ifc`` applied to every vertex: a rotation about z and a
            translation, metres. None: the IFC world frame in metres, whatever the file unit.

    Returns:
        The site, no markers (``make_site`` adds them), named after the file's stem, with
        ``source`` = provenance: path, schema, units, transform, site placement, true north, map
        conversion and the :class:`ImportReport` (see the module docstring for the rules).

    Raises:
        FileNotFoundError: if the file does not exist.
        IfcImportError: if it is not IFC, has no slab or column, or no stage a camera can use
            (no flat structural floor above the terrain and no four exposed column tops).
        ConfigError: for an unknown stage (the message lists the valid ones).
        ValueError: for a transform that is not 4x4 rigid keeping z up.
        ImportError: if ifcopenshell is not installed (names the ``ifc`` extra).
    """
    parsed = _parsed(path, transform)
    names = [n for st in parsed.stages for n in st.names]
    if stage is None:
        stage = parsed.stages[-1].name
    if stage not in names:
        raise ConfigError(f"stage must be one of the stages of {str(path)!r}: {names}, got {stage!r}")
    xmin = min(e.bounds[0] for e in parsed.elements)
    ymin = min(e.bounds[1] for e in parsed.elements)
    xmax = max(e.bounds[2] for e in parsed.elements)
    ymax = max(e.bounds[3] for e in parsed.elements)
    reach = max(abs(xmin), abs(xmax), abs(ymin), abs(ymax))
    ground = max(160.0, 4.0 * math.hypot(xmax - xmin, ymax - ymin), 2.0 * reach + 20.0)
    return Site(
        elements=parsed.elements, storeys=parsed.storeys, stages=parsed.stages, stage=stage,
        markers=(), ground_size=float(math.ceil(ground)), name=Path(path).stem, building=None,
        source=dict(parsed.source),
    )


def write_ifc(site: Site, path: str | os.PathLike) -> Path:
    """Write ``site``'s building (every element, all stages) as IFC4 in metres; returns the path.

    See :mod:`uav_struct_env.site.ifc_export`. Markers are not written.

    Raises:
        TypeError: if ``site`` is not a Site.
        ImportError: if ifcopenshell is not installed (names the ``ifc`` extra).
    """
    if not isinstance(site, Site):
        raise TypeError(f"site must be a uav_struct_env.site.Site, got {type(site).__name__}")
    return write_building(site.name, site.storeys, site.elements, path)
