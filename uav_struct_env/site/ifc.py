"""IFC import and export: a :class:`~uav_struct_env.site.Site` from an IFC file, and back.

The only module that imports ifcopenshell (the optional extra ``ifc``:
``pip install 'uav-struct-env[ifc]'``); it is imported inside the functions, so the rest of the
package works without it.

Import (:func:`load_ifc`, :func:`ifc_stages`, :func:`ifc_report`)
-----------------------------------------------------------------
Geometry comes from ifcopenshell's geometry iterator in world coordinates, which are metres
whatever the file's length unit (openings are already cut). The project frame is that IFC world
frame unless ``transform`` (a 4x4 ``project_from_ifc``, rigid, keeping z up) is given; IfcSite
placement, TrueNorth and IfcMapConversion are read and recorded in ``site.source``, never
applied. Imported: IfcSlab, IfcColumn, IfcBeam, IfcWall (and their subtypes). Not imported (the
report counts them by class): footings (below ground), members (stringers, mullions), stairs,
railings, doors, windows, coverings, furniture and every other non-structural product;
IfcOpeningElements become slab openings. Real files are messy; the rules, in order:

1. **No body geometry**: an element the iterator cannot tessellate is dropped.
2. **Coincident duplicates**: an element whose kind, 3D bounding box (within
   :data:`DUPLICATE_TOL`) and plan footprint match an earlier one is dropped.
3. **Finish floors**: a slab thinner than :data:`MIN_SLAB_THICKNESS` is dropped (said to be a
   finish floor when it lies on a kept slab).
4. **Not a floor**: a slab whose PredefinedType is not FLOOR, BASESLAB, ROOF, NOTDEFINED or unset
   (a LANDING, ...) is kept for rendering but bears no landmarks (``structural=False``).
5. **Sloped slabs**: a slab is flat-topped when its upward-facing horizontal triangles at its top
   elevation make at least :data:`FLAT_FRACTION` of its upward-facing plan area; otherwise it is
   kept for rendering (footprint outline, ``structural=False``) and bears no landmarks.
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
8. **Columns**: axis = centroid of the top face, outline = plan footprint. **Beams, walls**:
   outline = the union of the plan projections of their triangles (its largest part, or the
   convex hull when the union falls apart into comparable parts). All keep their triangles as
   ``mesh``.

Storeys come from IfcBuildingStorey, in elevation order (its placement's z in metres); an element
belongs to the storey that contains it (through aggregates), else the highest storey at or below
its bottom. Names of one kind are made unique by appending ``[<guid prefix>]``. The floor of a
storey is its flat structural slabs. Stages, in build order, for each storey with a floor:
``"<storey>/slab"`` = every kept element of lower storeys plus the floors up to this one;
``"<storey>/columns"`` (only when the storey contains columns) = plus those columns. Imported
stages have no short aliases. Landmark ids follow from the element order (columns, slabs, beams,
walls; by storey, then file order), so they are stable across loads of the same file.

The parse is cached in-process per (file, mtime, size, transform): loading another stage of the
same file does not tessellate again. What was kept and dropped is an :class:`ImportReport` in
``site.source["report"]``, logged at INFO.

Export (:func:`write_ifc`, ``Site.to_ifc``)
-------------------------------------------
IFC4 through ``ifcopenshell.api``, in metres: project, site, building, one IfcBuildingStorey per
storey (name, elevation), each element contained in its storey, placed at its bottom. An element
without a mesh is an extruded IfcArbitraryClosedProfileDef of its outline; a slab's openings are
IfcOpeningElement voids extruded through it. An element with its own mesh (an imported one) is an
IfcTriangulatedFaceSet (its openings are already cut). GlobalIds are derived from the site name
and element guid (the same site writes the same ids); the element guid goes into ``Tag``.
Markers are not written (they are not building elements).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import os
import uuid
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uav_struct_env.errors import ConfigError, IfcImportError
from uav_struct_env.site.elements import Beam, Column, Element, Hole, Slab, Stage, Storey, TriangleMesh, Wall
from uav_struct_env.site.polygons import canonical_outline

if TYPE_CHECKING:
    from uav_struct_env.site.model import Site

__all__ = [
    "DUPLICATE_TOL",
    "FLAT_FRACTION",
    "IMPORTED_CLASSES",
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

INSTALL_HINT = "pip install 'uav-struct-env[ifc]'"

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
_KIND_ORDER = {"column": 0, "slab": 1, "beam": 2, "wall": 3}
_ELEMENT_CLASS = {"column": Column, "slab": Slab, "beam": Beam, "wall": Wall}


def _ifcopenshell() -> Any:
    """The ifcopenshell module (with geom and util), or an ImportError naming the extra."""
    try:
        import ifcopenshell
        import ifcopenshell.geom
        import ifcopenshell.util.element
        import ifcopenshell.util.placement
        import ifcopenshell.util.unit
    except ImportError as exc:
        raise ImportError(
            f"IFC import/export needs ifcopenshell, which is not installed ({exc}); "
            f"install the 'ifc' extra: {INSTALL_HINT}"
        ) from exc
    return ifcopenshell


# ----------------------------------------------------------------------------- the report
@dataclass(frozen=True)
class ImportReport:
    """What an import kept and dropped, and why.

    Attributes:
        path: the IFC file.
        kept: ``(guid, ifc class, name, role)`` of every imported IFC element.
        dropped: ``(guid, ifc class, name, reason)`` of every imported-class element left out.
        skipped: ``(ifc class, count, reason)`` of the classes not imported at all.
    """

    path: str
    kept: tuple[tuple[str, str, str, str], ...]
    dropped: tuple[tuple[str, str, str, str], ...]
    skipped: tuple[tuple[str, int, str], ...]

    def summary(self) -> str:
        """The report as readable text: counts, then one line per kept and dropped element."""
        lines = [f"IFC import of {self.path}: kept {len(self.kept)}, dropped {len(self.dropped)}, "
                 f"not imported {sum(n for _, n, _ in self.skipped)} of {len(self.skipped)} classes"]
        lines += [f"  kept    {c:<20} {g}  {n!r}: {r}" for g, c, n, r in self.kept]
        lines += [f"  dropped {c:<20} {g}  {n!r}: {r}" for g, c, n, r in self.dropped]
        lines += [f"  skipped {c:<20} x{n}: {r}" for c, n, r in self.skipped]
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
    """Union slivers closed (morphological closing by ``close`` m), simplified at OUTLINE_TOL."""
    import shapely

    geom = geom.buffer(close, join_style="mitre", mitre_limit=10.0).buffer(
        -close, join_style="mitre", mitre_limit=10.0)
    geom = shapely.simplify(geom, OUTLINE_TOL, preserve_topology=True)
    return shapely.make_valid(geom) if not geom.is_valid else geom


def _plan_union(tri2d: NDArray[np.float64], close: float = 1e-4) -> Any:
    """The cleaned union of plan triangles (T, 3, 2) (Polygon or MultiPolygon, maybe empty)."""
    import shapely

    polys = _tri_polygons(tri2d)
    if len(polys) == 0:
        return shapely.Polygon()
    return _clean(shapely.union_all(polys, grid_size=1e-6), close)


def _parts(geom: Any, min_area: float = 1e-4) -> list[Any]:
    import shapely

    return [p for p in shapely.get_parts(geom) if p.geom_type == "Polygon" and p.area >= min_area]


def _footprint(tri: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """Plan outline of triangles (T, 3, 3): the union's largest part, or its convex hull."""
    union = _plan_union(tri[:, :, :2])
    parts = sorted(_parts(union, 1e-6), key=lambda p: -p.area)
    if not parts:
        return None
    if parts[0].area >= 0.99 * union.area:
        return np.asarray(parts[0].exterior.coords)[:-1]
    return np.asarray(union.convex_hull.exterior.coords)[:-1]


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


def _open(path: Path) -> Any:
    ios = _ifcopenshell()
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
    try:
        return ios.open(str(path))
    except Exception as exc:  # ifcopenshell raises its own, untyped errors
        raise IfcImportError(f"{str(path)!r} is not a readable IFC file: {exc}") from exc


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


def _floor_groups(pieces: list[_Raw], tops: dict[str, _Top]) -> list[list[_Raw]]:
    """Pieces of one storey's floor grouped into slabs (rule 6).

    Connected components of "same level and at most PRECAST_JOINT apart", in file order.
    """
    parent = list(range(len(pieces)))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a in range(len(pieces)):
        for b in range(a + 1, len(pieces)):
            ta, tb = tops[pieces[a].guid], tops[pieces[b].guid]
            if abs(ta.z - tb.z) <= SAME_LEVEL_TOL and ta.polygon.distance(tb.polygon) <= PRECAST_JOINT:
                parent[find(b)] = find(a)
    roots: dict[int, list[_Raw]] = {}
    for a, r in enumerate(pieces):
        roots.setdefault(find(a), []).append(r)
    return sorted(roots.values(), key=lambda g: g[0].order)


@dataclass(frozen=True)
class _Parsed:
    elements: tuple[Element, ...]
    storeys: tuple[Storey, ...]
    stages: tuple[Stage, ...]
    report: ImportReport
    source: dict[str, Any]


def _parse(path: Path, transform: NDArray[np.float64]) -> _Parsed:
    ios = _ifcopenshell()
    import ifcopenshell.util.element as ue
    import shapely

    f = _open(path)
    scale = float(ios.util.unit.calculate_unit_scale(f))
    products = f.by_type("IfcProduct")
    counts = Counter(p.is_a() for p in products)
    by_kind = {kind: f.by_type(cls) for cls, kind in IMPORTED_CLASSES.items()}
    if not by_kind["slab"] and not by_kind["column"]:
        found = ", ".join(f"{c} x{n}" for c, n in counts.most_common()) or "no products at all"
        raise IfcImportError(
            f"{str(path)!r} has no IfcSlab and no IfcColumn, so no structural landmarks: it contains "
            f"{found}"
        )

    # Storeys, bottom up, their elevation in the project frame.
    storey_entities = []
    for s in f.by_type("IfcBuildingStorey"):
        if s.ObjectPlacement is not None:
            z = float(_matrix_m(s.ObjectPlacement, scale)[2, 3])
        else:
            z = float(s.Elevation or 0.0) * scale
        storey_entities.append((z + transform[2, 3], s.id(), s))
    storey_entities.sort(key=lambda t: (t[0], t[1]))
    names = [s.Name or f"Storey {k}" for k, (_, _, s) in enumerate(storey_entities)]
    seen: Counter[str] = Counter()
    for k, n in enumerate(names):
        seen[n] += 1
        if seen[n] > 1:
            names[k] = f"{n} ({seen[n]})"
    storeys = [Storey(n, z) for n, (z, _, _) in zip(names, storey_entities, strict=True)]
    storey_index = {sid: k for k, (_, sid, _) in enumerate(storey_entities)}
    if not storeys:
        storeys = [Storey("Building", 0.0)]

    # Tessellate the imported classes in world coordinates (metres).
    ios_geom = ios.geom
    settings = ios_geom.settings()
    settings.set("use-world-coords", True)
    include = [e for kind in ("column", "slab", "beam", "wall") for e in by_kind[kind]]
    shapes: dict[int, tuple[NDArray[np.float64], NDArray[np.int64]]] = {}
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
    rot, shift = transform[:3, :3], transform[:3, 3]

    def world(verts: NDArray[np.float64]) -> NDArray[np.float64]:
        return verts @ rot.T + shift

    def storey_of(e: Any, zmin: float) -> int:
        c = ue.get_container(e, ifc_class="IfcBuildingStorey")
        if c is not None and c.id() in storey_index:
            return storey_index[c.id()]
        below = [k for k, s in enumerate(storeys) if s.elevation <= zmin + 0.1]
        return below[-1] if below else 0

    kept: list[tuple[str, str, str, str]] = []
    dropped: list[tuple[str, str, str, str]] = []
    raws: list[_Raw] = []
    for order, e in enumerate(include):
        name = e.Name or e.is_a()
        if e.id() not in shapes or len(shapes[e.id()][1]) == 0:
            dropped.append((e.GlobalId, e.is_a(), name, "no body geometry"))
            continue
        v, fc = shapes[e.id()]
        tri = world(v)[fc]
        kind = IMPORTED_CLASSES[next(c for c in IMPORTED_CLASSES if e.is_a(c))]
        predefined = ue.get_predefined_type(e) if kind == "slab" else None
        voids = []
        if kind == "slab":
            for rel in getattr(e, "HasOpenings", ()) or ():
                op = rel.RelatedOpeningElement
                try:
                    osh = ios_geom.create_shape(settings, op)
                except Exception:  # an opening without geometry: not matchable
                    continue
                ov = world(np.asarray(osh.geometry.verts, dtype=np.float64).reshape(-1, 3))
                if len(ov) >= 3:
                    hull = shapely.MultiPoint(ov[:, :2]).convex_hull
                    voids.append((op.GlobalId, op.Name or "opening", hull))
        raws.append(_Raw(order, e.GlobalId, e.is_a(), name, kind, storey_of(e, float(tri[:, :, 2].min())),
                         predefined, tri, tuple(voids)))

    # Rule 2: coincident duplicates (same kind, bounding box and footprint).
    footprints: dict[str, NDArray[np.float64] | None] = {r.guid: _footprint(r.tri) for r in raws}
    unique: list[_Raw] = []
    for r in raws:
        twin = None
        for u in unique:
            if u.kind != r.kind or np.max(np.abs(u.bbox() - r.bbox())) > DUPLICATE_TOL:
                continue
            fa, fb = footprints[u.guid], footprints[r.guid]
            if fa is None or fb is None:
                continue
            pa, pb = shapely.Polygon(fa), shapely.Polygon(fb)
            if pa.symmetric_difference(pb).area <= 0.01 * max(pa.area, 1e-9):
                twin = u
                break
        if twin is not None:
            why = f"coincident duplicate of {twin.guid} ({twin.name!r})"
            dropped.append((r.guid, r.ifc_class, r.name, why))
        else:
            unique.append(r)

    # Rules 3-5: slabs -> finish floors (dropped), non-floor and sloped slabs (kept, no landmarks).
    slabs = [r for r in unique if r.kind == "slab"]
    tops = {r.guid: _slab_top(r) for r in slabs}
    thick = [r for r in slabs if r.zmax - r.zmin >= MIN_SLAB_THICKNESS]
    floor_pieces: list[_Raw] = []
    rendered_slabs: list[tuple[_Raw, str]] = []
    for r in slabs:
        t = r.zmax - r.zmin
        if t < MIN_SLAB_THICKNESS:
            fp = footprints[r.guid]
            under = [s for s in thick if abs(s.zmax - r.zmin) <= SAME_LEVEL_TOL and fp is not None
                     and footprints[s.guid] is not None
                     and shapely.Polygon(footprints[s.guid]).intersects(shapely.Polygon(fp))]
            why = (f"finish floor {1000 * t:.0f} mm thick lying on slab {under[0].guid} ({under[0].name!r})"
                   if under else f"{1000 * t:.0f} mm thick, thinner than {1000 * MIN_SLAB_THICKNESS:.0f} mm: "
                   "not a structural floor")
            dropped.append((r.guid, r.ifc_class, r.name, why))
        elif r.predefined not in FLOOR_TYPES:
            rendered_slabs.append((r, f"slab of type {r.predefined}: rendered, bears no landmarks"))
        elif not tops[r.guid].flat:
            rendered_slabs.append((r, "sloped or stepped top (no flat top face): rendered, no landmarks"))
        else:
            floor_pieces.append(r)

    # Rule 6: group floor pieces per storey (same level, touching or a precast joint apart).
    groups: list[list[_Raw]] = []
    for storey in sorted({r.storey for r in floor_pieces}):
        groups += _floor_groups([r for r in floor_pieces if r.storey == storey], tops)

    elements: list[tuple[tuple, Element]] = []
    floors: dict[int, list[str]] = {}

    def mesh_of(tris: list[NDArray[np.float64]]) -> TriangleMesh:
        t = np.concatenate(tris)
        return TriangleMesh(t.reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3))

    for group in groups:
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
        mesh = mesh_of([r.tri for r in group])
        voids = [v for r in group for v in r.voids]
        for k, part in enumerate(parts):
            pguid = guid if len(parts) == 1 else f"{guid}#{k}"
            pname = name if len(parts) == 1 else f"{name} part {k}"
            outer, notches = _fill_notches(_ring(part.exterior.coords)[:-1])
            rings = [(_ring(h.coords)[:-1], True) for h in part.interiors] + [(n_, False) for n_ in notches]
            holes = []
            outlines = [canonical_outline(h, "slab opening", tol=OUTLINE_TOL) for h, _ in rings]
            outlines.sort(key=lambda h: (h[0, 1], h[0, 0]))
            for j, h in enumerate(outlines):
                at = shapely.Polygon(h).representative_point()
                match = [v for v in voids if v[2].buffer(0.01).contains(at)]
                if match:
                    holes.append(Hole(match[0][1], h, guid=match[0][0], source="void"))
                else:
                    holes.append(Hole(f"{pname} opening {j}", h, guid=f"{pguid}/opening {j}",
                                      source="outline"))
            elements.append(((1, first.storey, first.order, k), Slab(
                guid=pguid, name=pname, storey=first.storey, outline=outer, z_bottom=z_bottom,
                z_top=z_top, mesh=mesh, holes=tuple(holes))))
            floors.setdefault(first.storey, []).append(pguid)
        role = (f"floor of {storeys[first.storey].name}" + (f", one slab with {len(group) - 1} more "
                f"piece(s) at most {100 * PRECAST_JOINT:.0f} cm apart" if len(group) > 1 else ""))
        kept += [(r.guid, r.ifc_class, r.name, role) for r in group]
    for r, why in rendered_slabs:
        fp = footprints[r.guid]
        if fp is None:
            dropped.append((r.guid, r.ifc_class, r.name, "no plan footprint"))
            continue
        elements.append(((1, r.storey, r.order, 0), Slab(
            guid=r.guid, name=r.name, storey=r.storey, outline=fp, z_bottom=r.zmin, z_top=r.zmax,
            mesh=mesh_of([r.tri]), structural=False)))
        kept.append((r.guid, r.ifc_class, r.name, why))

    # Rule 8: columns, beams, walls.
    for r in unique:
        if r.kind == "slab":
            continue
        fp = footprints[r.guid]
        if fp is None or r.zmax - r.zmin <= 1e-6:
            dropped.append((r.guid, r.ifc_class, r.name, "no plan footprint or no height"))
            continue
        cls = _ELEMENT_CLASS[r.kind]
        extra: dict[str, Any] = {}
        if r.kind == "column":
            top = _slab_top(r)
            c = (top.polygon if top.flat and not top.polygon.is_empty else shapely.Polygon(fp)).centroid
            extra = {"axis": (c.x, c.y), "index": sum(1 for k, e in elements if e.kind == "column")}
        elements.append(((_KIND_ORDER[r.kind], r.storey, r.order, 0), cls(
            guid=r.guid, name=r.name, storey=r.storey, outline=fp, z_bottom=r.zmin, z_top=r.zmax,
            mesh=mesh_of([r.tri]), **extra)))
        kept.append((r.guid, r.ifc_class, r.name, f"{r.kind} of {storeys[r.storey].name}"))

    elements.sort(key=lambda t: t[0])
    ordered = [e for _, e in elements]
    # Unique names per kind: a name used twice gets its guid prefix.
    name_counts = Counter((e.kind, e.name) for e in ordered)
    ordered = [e if name_counts[(e.kind, e.name)] == 1
               else dataclasses.replace(e, name=f"{e.name} [{e.guid[:8]}]") for e in ordered]

    # Stages.
    stages: list[Stage] = []
    for s in sorted(floors):
        below = {e.guid for e in ordered if e.storey < s}
        slab_guids = {g for t in sorted(floors) if t <= s for g in floors[t]}
        built = frozenset(below | slab_guids)
        stages.append(Stage(f"{storeys[s].name}/slab", built, tuple(floors[s])))
        cols = {e.guid for e in ordered if isinstance(e, Column) and e.storey == s}
        if cols:
            stages.append(Stage(f"{storeys[s].name}/columns", built | cols, tuple(floors[s])))
    if not stages:
        raise IfcImportError(
            f"{str(path)!r} has no flat-topped structural floor to build stages on: "
            f"{len(by_kind['slab'])} IfcSlab, {len(by_kind['column'])} IfcColumn; dropped or not "
            "landmark-bearing: " + "; ".join(f"{g} {n!r}: {why}" for g, _, n, why in dropped[:8])
            + "; " + "; ".join(f"{r.guid} {r.name!r}: {why}" for r, why in rendered_slabs[:8])
        )

    # What was not imported, by class.
    imported_ids = {e.id() for e in include}
    skipped_counts: Counter[tuple[str, str]] = Counter()
    for p in products:
        if p.id() in imported_ids:
            continue
        reason = next((why for cls, why in _NOT_IMPORTED if p.is_a(cls)), "non-structural: not imported")
        skipped_counts[(p.is_a(), reason)] += 1
    skipped = tuple(sorted(((c, n, why) for (c, why), n in skipped_counts.items()), key=lambda t: t[0]))
    report = ImportReport(str(path), tuple(kept), tuple(dropped), skipped)
    source = {
        "format": "ifc", "path": str(path), "schema": f.schema,
        "units": {"length_unit_in_m": scale},
        "transform": transform.tolist(), **_georeference(f, scale), "report": report,
    }
    return _Parsed(tuple(ordered), tuple(storeys), tuple(stages), report, source)


@functools.lru_cache(maxsize=8)
def _parse_cached(path: str, mtime_ns: int, size: int, transform: bytes) -> _Parsed:
    parsed = _parse(Path(path), np.frombuffer(transform, dtype=np.float64).reshape(4, 4).copy())
    log.info("%s", parsed.report.summary())
    return parsed


def _parsed(path: str | os.PathLike, transform: ArrayLike | None) -> _Parsed:
    _ifcopenshell()
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
        IfcImportError: if it is not IFC, has no slab or column, or no flat structural floor.
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
        IfcImportError: if it is not IFC, has no slab or column, or no flat structural floor.
        ConfigError: for an unknown stage (the message lists the valid ones).
        ValueError: for a transform that is not 4x4 rigid keeping z up.
        ImportError: if ifcopenshell is not installed (names the ``ifc`` extra).
    """
    from uav_struct_env.site.model import Site

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


# ----------------------------------------------------------------------------- export
_GUID_NAMESPACE = uuid.UUID("6f1b7a52-3c1e-4f0e-9a55-2b8c8a4d7e10")


def write_ifc(site: Site, path: str | os.PathLike) -> Path:
    """Write ``site``'s building (every element, all stages) as IFC4 in metres; returns the path.

    See the module docstring (Export). Markers are not written.

    Raises:
        TypeError: if ``site`` is not a Site.
        ImportError: if ifcopenshell is not installed (names the ``ifc`` extra).
    """
    from uav_struct_env.site.model import Site

    if not isinstance(site, Site):
        raise TypeError(f"site must be a uav_struct_env.site.Site, got {type(site).__name__}")
    ios = _ifcopenshell()
    import ifcopenshell.api
    import ifcopenshell.api.project
    import ifcopenshell.guid

    def api(usecase: str, *args: Any, **kwargs: Any) -> Any:
        module, name = usecase.split(".")
        return getattr(getattr(ifcopenshell.api, module), name)(*args, **kwargs)

    for module in ("aggregate", "context", "feature", "geometry", "root", "spatial", "unit"):
        __import__(f"ifcopenshell.api.{module}")
    f = ifcopenshell.api.project.create_file(version="IFC4")

    def gid(key: str) -> str:
        return ifcopenshell.guid.compress(uuid.uuid5(_GUID_NAMESPACE, f"{site.name}/{key}").hex)

    project = api("root.create_entity", f, ifc_class="IfcProject", name=site.name)
    project.GlobalId = gid("project")
    metre = api("unit.add_si_unit", f, unit_type="LENGTHUNIT")
    api("unit.assign_unit", f, units=[metre])
    model = api("context.add_context", f, context_type="Model")
    body = api("context.add_context", f, context_type="Model", context_identifier="Body",
               target_view="MODEL_VIEW", parent=model)
    ifc_site = api("root.create_entity", f, ifc_class="IfcSite", name=site.name)
    ifc_site.GlobalId = gid("site")
    building = api("root.create_entity", f, ifc_class="IfcBuilding", name=site.name)
    building.GlobalId = gid("building")
    api("aggregate.assign_object", f, products=[ifc_site], relating_object=project)
    api("aggregate.assign_object", f, products=[building], relating_object=ifc_site)
    for product in (ifc_site, building):
        api("geometry.edit_object_placement", f, product=product, matrix=np.eye(4))
    storeys = []
    for k, st in enumerate(site.storeys):
        s = api("root.create_entity", f, ifc_class="IfcBuildingStorey", name=st.name)
        s.GlobalId = gid(f"storey {k}")
        s.Elevation = float(st.elevation)
        api("aggregate.assign_object", f, products=[s], relating_object=building)
        api("geometry.edit_object_placement", f, product=s, matrix=_translation(0.0, 0.0, st.elevation))
        storeys.append(s)

    ifc_class = {"column": "IfcColumn", "slab": "IfcSlab", "beam": "IfcBeam", "wall": "IfcWall"}
    for e in site.elements:
        product = api("root.create_entity", f, ifc_class=ifc_class[e.kind], name=e.name,
                      predefined_type=("FLOOR" if getattr(e, "structural", True) else "NOTDEFINED")
                      if e.kind == "slab" else None)
        product.GlobalId = gid(e.guid)
        product.Tag = e.guid
        if storeys:
            api("spatial.assign_container", f, products=[product],
                relating_structure=storeys[min(e.storey, len(storeys) - 1)])
        api("geometry.edit_object_placement", f, product=product, matrix=_translation(0.0, 0.0, e.z_bottom))
        if e.mesh is not None:
            item = _face_set(f, e.mesh.vertices - [0.0, 0.0, e.z_bottom], e.mesh.faces)
            rep_type = "Tessellation"
        else:
            item = _extrusion(f, e.outline, 0.0, e.z_top - e.z_bottom)
            rep_type = "SweptSolid"
        rep = f.createIfcShapeRepresentation(body, "Body", rep_type, [item])
        api("geometry.assign_representation", f, product=product, representation=rep)
        if isinstance(e, Slab) and e.mesh is None:
            for hole in e.holes:
                op = api("root.create_entity", f, ifc_class="IfcOpeningElement", name=hole.name)
                op.GlobalId = gid(f"{e.guid}/{hole.guid}")
                op.Tag = hole.guid
                api("geometry.edit_object_placement", f, product=op,
                    matrix=_translation(0.0, 0.0, e.z_bottom - 0.1))
                rep = f.createIfcShapeRepresentation(
                    body, "Body", "SweptSolid", [_extrusion(f, hole.outline, 0.0, e.thickness + 0.2)])
                api("geometry.assign_representation", f, product=op, representation=rep)
                api("feature.add_feature", f, feature=op, element=product)
    out = Path(path)
    f.write(str(out))
    del ios
    return out


def _translation(x: float, y: float, z: float) -> NDArray[np.float64]:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _extrusion(f: Any, outline: NDArray[np.float64], z0: float, depth: float) -> Any:
    """An IfcExtrudedAreaSolid of a plan ``outline`` from ``z0`` up by ``depth`` (local frame)."""
    pts = [f.createIfcCartesianPoint((float(x), float(y))) for x, y in outline]
    profile = f.createIfcArbitraryClosedProfileDef("AREA", None, f.createIfcPolyline([*pts, pts[0]]))
    position = f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, float(z0))), None, None)
    up = f.createIfcDirection((0.0, 0.0, 1.0))
    return f.createIfcExtrudedAreaSolid(profile, position, up, float(depth))


def _face_set(f: Any, vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> Any:
    """An IfcTriangulatedFaceSet (IFC4) of a triangle mesh, vertices deduplicated."""
    v, inverse = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    fc = inverse.reshape(-1)[faces]
    fc = fc[(fc[:, 0] != fc[:, 1]) & (fc[:, 1] != fc[:, 2]) & (fc[:, 0] != fc[:, 2])]
    points = f.createIfcCartesianPointList3D([tuple(map(float, p)) for p in v])
    indices = [tuple(int(i) + 1 for i in t) for t in fc]  # 1-based
    return f.createIfcTriangulatedFaceSet(points, None, None, indices, None)
