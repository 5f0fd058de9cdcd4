"""Site activity as plain data: workers, equipment, stored materials, scaffolding and formwork.

An active construction site is not a bare building: people walk on the slab and around it,
machines stand beside it, materials are stacked on the slab and on the ground, scaffolding runs
along slab edges and formwork wraps columns. :class:`SiteActivity` lays all of that out for any
:class:`~uav_struct_env.site.Site` from its elements alone -- the topmost floor slabs' outlines and
openings, the built columns, the footprint and the markers -- never from coordinates of one
particular building. Everything is a set of oriented boxes (:class:`Box`), so the renderer and the
ray-cast visibility (:mod:`uav_struct_env.sim.raycast`) see exactly the same solids.

How much there is comes from an :class:`Activity` (presets ``"none"``, ``"light"``, ``"busy"``,
:func:`make_activity`). The layout is a pure function of ``(site, activity, seed)``: the same seed
gives the same layout and the same motion, in any process. Each category draws from its own child
of ``numpy.random.SeedSequence(seed)``, so nothing else's random stream is touched.

Placement rules (the numbers are module constants):

* workers (a 0.46 x 0.28 x 1.75 m box, hi-vis colours) walk at a seeded speed within
  ``Activity.walking_speed`` back and forth along a seeded polyline of waypoints: on a floor slab
  (0.4 m inside its edges and openings, clear of standing columns and stacked materials) or on
  the ground around the footprint (1-15 m outside it, clear of equipment and stacks). The motion is
  a closed-form function of time, :meth:`SiteActivity.workers_at`;
* stored materials on the slab (rebar bundles, formwork-panel stacks, pallets of bags; at most
  1 m high) keep ``Activity.landmark_clearance`` in plan from every structural landmark;
  on the ground they keep it from every marker sheet, as equipment does;
* equipment (mobile crane with its boom at 20 deg, excavator, tipper truck, truck-mounted concrete
  pump with its boom folded) stands 4-16 m outside the footprint, turned along it, every part at
  most :data:`MAX_EQUIPMENT_HEIGHT` high (below the lowest viewpoint of the schedule, so no UAV
  starts inside one);
* scaffolding (two rows of standards, ledgers, a deck at slab level and a guard rail 1 m above
  it) stands 0.3 m outside a floor slab's edge (up to 2.3 m where walls or beams below stick
  out; ground-level elements are stood on), leaving ``landmark_clearance`` free at both
  corners; formwork wraps the lower 60 % of a share of the exposed columns (their tops stay free).

Sizes follow common equipment: a 50-t all-terrain crane carrier about 12 x 2.75 m, a 20-t
crawler excavator (tracks 4.5 m, house 3 m), a three-axle tipper 8 x 2.5 m, a 36-m truck pump
10 x 2.5 m folded at 4 m.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from uav_struct_env.errors import ConfigError
from uav_struct_env.named import resolve_named
from uav_struct_env.site.elements import Column, Slab
from uav_struct_env.site.model import Site

__all__ = [
    "ACTIVITY_PRESETS",
    "BOX_CORNER_SIGNS",
    "EQUIPMENT_KINDS",
    "MAX_EQUIPMENT_HEIGHT",
    "WORKER_HALF_EXTENTS",
    "WORKER_HEIGHT",
    "WORKER_SAMPLE_HEIGHTS",
    "Activity",
    "Box",
    "SiteActivity",
    "Worker",
    "make_activity",
    "worker_sample_points",
]

#: A worker's height (m) and the half extents of the box standing for one (shoulders x chest).
WORKER_HEIGHT = 1.75
WORKER_HALF_EXTENTS = (0.23, 0.14, WORKER_HEIGHT / 2)
#: Heights (fractions of WORKER_HEIGHT) of the points :func:`worker_sample_points` returns.
WORKER_SAMPLE_HEIGHTS = (0.1, 0.3, 0.5, 0.7, 0.9)
#: No equipment part reaches higher than this (m): below the schedule's lowest viewpoint (10 m).
MAX_EQUIPMENT_HEIGHT = 8.0
#: Equipment kinds :class:`Activity.equipment` may name.
EQUIPMENT_KINDS = ("mobile_crane", "excavator", "truck", "concrete_pump")
_MATERIAL_KINDS = ("rebar", "formwork_panels", "pallet")

#: Ground ring around the footprint where equipment (and ground stacks) stand, m out from it.
_EQUIPMENT_RING = (4.0, 16.0)
#: Ground ring where ground workers walk, m out from the footprint.
_WORKER_RING = (1.0, 15.0)
#: Margins (m): a slab worker from the slab's edges and openings and from columns; any item from
#: another; scaffold from the slab edge (inner row) and its width.
_EDGE_MARGIN = 0.4
_ITEM_GAP = 0.3
_SCAFFOLD_OFFSETS, _SCAFFOLD_WIDTH = (0.3, 0.8, 1.3, 1.8, 2.3), 1.0
_MAX_TRIES = 300
#: Candidate points drawn at once for a worker's start and for each next waypoint.
_CANDIDATES = 24
_WAYPOINTS = 8

_HI_VIS = ((1.0, 0.45, 0.05, 1.0), (0.85, 0.95, 0.1, 1.0), (0.95, 0.3, 0.1, 1.0))

#: (8, 3) signs of a box's corners about its centre (x slowest, as ``np.meshgrid(..., "ij")``).
BOX_CORNER_SIGNS = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
BOX_CORNER_SIGNS.flags.writeable = False

_STEEL = (0.62, 0.63, 0.66, 1.0)
_YELLOW = (0.95, 0.72, 0.08, 1.0)
_DARK = (0.15, 0.15, 0.16, 1.0)
_GLASS = (0.25, 0.3, 0.35, 1.0)


@dataclass(frozen=True)
class Activity:
    """How much is going on at the site; all counts are upper bounds (placement may skip items).

    Attributes:
        name: preset name, for reports.
        slab_workers: workers walking on the topmost floor slabs.
        ground_workers: workers walking on the ground around the building.
        equipment: equipment to park around the building, kinds from :data:`EQUIPMENT_KINDS`.
        slab_materials: stacks of stored material on the floor slabs.
        ground_materials: stacks of stored material on the ground.
        scaffold_edges: floor-slab edges with a scaffolding run (longest edges first).
        column_formwork: share (0-1) of the exposed columns wrapped in formwork.
        walking_speed: ``(low, high)`` walking speed, m/s; each worker draws its own.
        landmark_clearance: plan distance (m) kept between stored materials, equipment and
            scaffold ends and every structural landmark and marker sheet.
    """

    name: str = "custom"
    slab_workers: int = 0
    ground_workers: int = 0
    equipment: tuple[str, ...] = ()
    slab_materials: int = 0
    ground_materials: int = 0
    scaffold_edges: int = 0
    column_formwork: float = 0.0
    walking_speed: tuple[float, float] = (0.8, 1.4)
    landmark_clearance: float = 2.0

    def __post_init__(self) -> None:
        for name in ("slab_workers", "ground_workers", "slab_materials", "ground_materials",
                     "scaffold_edges"):
            check_number(f"activity {name}", getattr(self, name), 0, 200, integer=True,
                         error=ConfigError, type_error=ConfigError)
        if isinstance(self.equipment, str):
            raise ConfigError(f"activity equipment must be a tuple of kinds, got {self.equipment!r}")
        equipment = tuple(self.equipment)
        unknown = [k for k in equipment if k not in EQUIPMENT_KINDS]
        if unknown:
            raise ConfigError(f"activity equipment must be drawn from {EQUIPMENT_KINDS}, got {unknown}")
        object.__setattr__(self, "equipment", equipment)
        check_number("activity column_formwork", self.column_formwork, 0, 1,
                     error=ConfigError, type_error=ConfigError)
        speed = self.walking_speed
        if isinstance(speed, (str, bytes)) or len(speed) != 2:
            raise ConfigError(f"activity walking_speed must be (low, high) m/s, got {speed!r}")
        lo = check_number("activity walking_speed[0]", speed[0], 0, 5, error=ConfigError,
                          type_error=ConfigError)
        check_number("activity walking_speed[1]", speed[1], lo, 5, error=ConfigError,
                     type_error=ConfigError)
        object.__setattr__(self, "walking_speed", (float(speed[0]), float(speed[1])))
        check_number("activity landmark_clearance", self.landmark_clearance, 0, 20,
                     error=ConfigError, type_error=ConfigError)

    @property
    def is_none(self) -> bool:
        """True when nothing is placed."""
        return not (self.slab_workers or self.ground_workers or self.equipment or self.slab_materials
                    or self.ground_materials or self.scaffold_edges or self.column_formwork)


ACTIVITY_PRESETS: dict[str, Activity] = {
    "none": Activity("none"),
    "light": Activity("light", slab_workers=3, ground_workers=3, equipment=("truck",),
                      slab_materials=2, ground_materials=2, scaffold_edges=1, column_formwork=0.25),
    "busy": Activity("busy", slab_workers=8, ground_workers=8, equipment=EQUIPMENT_KINDS,
                     slab_materials=6, ground_materials=5, scaffold_edges=4, column_formwork=0.5),
}


def make_activity(activity: str | Activity) -> Activity:
    """Resolve a preset name (:data:`ACTIVITY_PRESETS`) or pass an :class:`Activity` through.

    Raises:
        ConfigError: for an unknown name or another type.
    """
    return resolve_named("activity", activity, ACTIVITY_PRESETS, Activity, "an Activity")


@dataclass(frozen=True, eq=False)
class Box:
    """One solid of the activity layer: an oriented box.

    Attributes:
        name: unique within a layout (``"excavator 1/boom"``, ``"worker 3"``).
        kind: the item kind (``"worker"``, ``"mobile_crane"``, ``"rebar"``, ``"scaffold"``, ...).
        world_from_box: (4, 4) pose of the box centre, project frame.
        half_extents: (3,) half sizes along the box axes, m.
        rgba: colour.
    """

    name: str
    kind: str
    world_from_box: NDArray[np.float64]
    half_extents: NDArray[np.float64]
    rgba: tuple[float, float, float, float] = _STEEL

    @property
    def corners(self) -> NDArray[np.float64]:
        """(8, 3) corners in the project frame."""
        local = BOX_CORNER_SIGNS * self.half_extents
        return local @ self.world_from_box[:3, :3].T + self.world_from_box[:3, 3]

    @property
    def aabb(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Axis-aligned bounds ``(lo (3,), hi (3,))``."""
        c = self.corners
        return c.min(axis=0), c.max(axis=0)


def _pose(xyz: Sequence[float], yaw: float = 0.0, pitch: float = 0.0) -> NDArray[np.float64]:
    """4x4 pose: turned ``yaw`` about z, then its x axis raised by ``pitch`` (rad)."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])  # x axis tilted up by pitch
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry
    T[:3, 3] = xyz
    return T


@dataclass(frozen=True, eq=False)
class Worker:
    """A worker walking back and forth along a polyline at a constant speed.

    Attributes:
        name: ``"worker k"``.
        surface: ``"slab"`` or ``"ground"``.
        z: elevation of the surface walked on, m.
        waypoints: (N, 2) plan polyline, m (N >= 1; one point: standing still).
        speed: walking speed, m/s.
        phase: distance (m) already walked at time 0.
        rgba: hi-vis colour.
    """

    name: str
    surface: str
    z: float
    waypoints: NDArray[np.float64]
    speed: float
    phase: float
    rgba: tuple[float, float, float, float]

    @cached_property
    def _cumulative(self) -> NDArray[np.float64]:
        seg = np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1)
        return np.concatenate([[0.0], np.cumsum(seg)])

    def at(self, t: float) -> tuple[NDArray[np.float64], float]:
        """``(feet xyz (3,), heading rad)`` at time ``t`` s: out along the polyline, then back."""
        cum = self._cumulative
        length = float(cum[-1])
        if length <= 0:
            return np.array([*self.waypoints[0], self.z]), 0.0
        s = (self.phase + self.speed * float(t)) % (2 * length)
        forward = s <= length
        s = s if forward else 2 * length - s
        k = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2))
        a, b = self.waypoints[k], self.waypoints[k + 1]
        f = (s - cum[k]) / max(cum[k + 1] - cum[k], 1e-12)
        xy = a + f * (b - a)
        d = (b - a) if forward else (a - b)
        return np.array([xy[0], xy[1], self.z]), math.atan2(d[1], d[0])

    def box_at(self, t: float) -> Box:
        """The worker's box at time ``t``."""
        feet, heading = self.at(t)
        half = np.array(WORKER_HALF_EXTENTS)
        return Box(self.name, "worker", _pose(feet + [0.0, 0.0, half[2]], heading), half, self.rgba)

    def points_at(self, t: float) -> NDArray[np.float64]:
        """(2, 3): the feet point (ground contact, centre) and the head top, at time ``t``."""
        feet, _ = self.at(t)
        return np.stack([feet, feet + [0.0, 0.0, WORKER_HEIGHT]])


def worker_sample_points(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """(5, 3) points along a worker's axis between its feet and head (:data:`WORKER_SAMPLE_HEIGHTS`)."""
    f = np.asarray(WORKER_SAMPLE_HEIGHTS)[:, None]
    return points[0] + f * (points[1] - points[0])


# ------------------------------------------------------------------------------ plan geometry
@dataclass(frozen=True)
class _Rect:
    """A plan rectangle: centre, half sizes along its own axes, yaw; the footprint of an item."""

    cx: float
    cy: float
    hx: float
    hy: float
    yaw: float

    def axes(self) -> NDArray[np.float64]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, s], [-s, c]])

    def corners(self, pad: float = 0.0) -> NDArray[np.float64]:
        ax = self.axes()
        h = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [self.hx + pad, self.hy + pad]
        return np.array([self.cx, self.cy]) + h @ ax

    def overlaps(self, other: _Rect, pad: float = 0.0) -> bool:
        """Separating-axis test of the two rectangles, this one grown by ``pad``."""
        a, b = self.corners(pad), other.corners()
        for axis in np.concatenate([self.axes(), other.axes()]):
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
        return True

    def distance_to(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Plan distance (N,) from points (N, 2) to the rectangle (0 inside)."""
        local = (np.asarray(xy).reshape(-1, 2) - [self.cx, self.cy]) @ self.axes().T
        gap = np.maximum(np.abs(local) - [self.hx, self.hy], 0.0)
        return np.hypot(gap[:, 0], gap[:, 1])


def _ring_distance(xy: NDArray[np.float64], bounds: tuple[float, float, float, float]) -> NDArray[np.float64]:
    """Signed-free plan distance (N,) of points outside the footprint rectangle (0 inside)."""
    xmin, ymin, xmax, ymax = bounds
    p = np.asarray(xy).reshape(-1, 2)
    gx = np.maximum(np.maximum(xmin - p[:, 0], p[:, 0] - xmax), 0.0)
    gy = np.maximum(np.maximum(ymin - p[:, 1], p[:, 1] - ymax), 0.0)
    return np.hypot(gx, gy)


class SiteActivity:
    """The activity layout of one site: static boxes and moving workers.

    Args:
        site: the site (its stage decides which floor is walked on and which columns stand).
        activity: a preset name or an :class:`Activity`.
        seed: int or sequence of ints for ``numpy.random.SeedSequence``; the same seed gives the
            same layout and motion.

    Attributes:
        static: every non-moving box (equipment, materials, scaffolding, formwork).
        workers: the workers, :class:`Worker`.
    """

    def __init__(self, site: Site, activity: str | Activity, seed: int | Sequence[int] = 0) -> None:
        if not isinstance(site, Site):
            raise TypeError(f"site must be a uav_struct_env.site.Site, got {type(site).__name__}")
        self.site = site
        self.activity = make_activity(activity)
        a = self.activity
        rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(6)]
        self._bounds = site.footprint_bounds
        #: (L, 3) structural landmarks (slab corners, opening corners, column tops).
        self._landmarks = self._structural_landmarks()
        self._markers = [_Rect(m.center[0], m.center[1], m.footprint_half_extent,
                               m.footprint_half_extent, m.yaw) for m in site.markers]
        self._standing = [c for c in site.columns if self._on_floor(c)]
        #: (C, 4) plan boxes (xmin, ymin, xmax, ymax) of the columns standing on a floor slab.
        self._column_boxes = np.array([c.bounds for c in self._standing], dtype=np.float64).reshape(-1, 4)
        #: Plan footprints taken so far: (rect, surface z) pairs.
        self._taken: list[tuple[_Rect, float]] = []
        self._taken_cache: dict[tuple[float, int], tuple[NDArray, NDArray, NDArray]] = {}
        static: list[Box] = []
        static += self._slab_materials(rngs[0], a.slab_materials)
        static += self._scaffolding(a.scaffold_edges)
        static += self._formwork(rngs[1], a.column_formwork)
        static += self._equipment(rngs[2], a.equipment)
        static += self._ground_materials(rngs[3], a.ground_materials)
        self.static: tuple[Box, ...] = tuple(static)
        workers = self._workers(rngs[4], a.slab_workers, "slab")
        workers += self._workers(rngs[5], a.ground_workers, "ground", start=len(workers))
        self.workers: tuple[Worker, ...] = tuple(workers)

    # -------------------------------------------------------------------------- public
    def workers_at(self, t: float) -> dict[str, Box]:
        """Every worker's box at time ``t`` (s since the layout's start), by name."""
        return {w.name: w.box_at(t) for w in self.workers}

    def worker_points(self, t: float) -> dict[str, NDArray[np.float64]]:
        """Every worker's (2, 3) feet and head-top points at time ``t``, by name."""
        return {w.name: w.points_at(t) for w in self.workers}

    def static_aabbs(self) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[str, ...]]:
        """``(lo (B, 3), hi (B, 3), names)``: the static boxes' axis-aligned bounds (collision)."""
        if not self.static:
            return np.zeros((0, 3)), np.zeros((0, 3)), ()
        lo, hi = zip(*(b.aabb for b in self.static), strict=True)
        return np.array(lo), np.array(hi), tuple(b.name for b in self.static)

    def __repr__(self) -> str:
        return (f"SiteActivity(site={self.site.name!r}, activity={self.activity.name!r}, "
                f"static={len(self.static)} boxes, workers={len(self.workers)})")

    # -------------------------------------------------------------------------- site facts
    def _structural_landmarks(self) -> NDArray[np.float64]:
        sets = [self.site.landmarks(n).xyz for n in ("slab_corners", "opening_corners", "column_tops")]
        return np.concatenate(sets).reshape(-1, 3)

    def _on_floor(self, column: Column) -> bool:
        """Whether a built column stands on (or passes through) a floor slab's top."""
        return any(column.z_top > s.z_top + 1e-6 and column.z_bottom < s.z_top + 0.05
                   for s in self.site.floor)

    def _slab_ok(self, slab: Slab, rect: _Rect, margin: float) -> bool:
        """The rectangle (grown by ``margin``) lies on the slab, off openings and columns."""
        pts = rect.corners(margin)
        pts = np.concatenate([pts, [[rect.cx, rect.cy]], (pts + np.roll(pts, 1, axis=0)) / 2])
        if not np.all(slab.covers(pts)):
            return False
        for c in self._standing:
            xmin, ymin, xmax, ymax = c.bounds
            col = _Rect((xmin + xmax) / 2, (ymin + ymax) / 2, (xmax - xmin) / 2, (ymax - ymin) / 2, 0.0)
            if rect.overlaps(col, margin):
                return False
        return True

    def _free(self, rect: _Rect, z: float, pad: float = _ITEM_GAP) -> bool:
        return not any(abs(z - z2) < 0.5 and rect.overlaps(r, pad) for r, z2 in self._taken)

    def _clear_of_landmarks(self, rect: _Rect, z: float) -> bool:
        """``landmark_clearance`` from the landmarks a low item on surface ``z`` could hide.

        Those are the structural landmarks from 0.5 m below to 2 m above ``z`` and, on the ground,
        the marker sheets; higher landmarks (the column tops over a slab) only need to be off the
        item.
        """
        d = self.activity.landmark_clearance
        if len(self._landmarks):
            dz = self._landmarks[:, 2] - z
            near = rect.distance_to(self._landmarks[:, :2])
            low = (dz > -0.5) & (dz < 2.0)
            if np.any(near[low] < d) or np.any(near[~low] < _ITEM_GAP):
                return False
        return z > 0.5 or not any(rect.overlaps(m, d) for m in self._markers)

    def _pick_slab(self, rng: np.random.Generator) -> Slab | None:
        slabs = self.site.floor
        if not slabs:
            return None
        if len(slabs) == 1:
            return slabs[0]
        areas = np.array([(s.bounds[2] - s.bounds[0]) * (s.bounds[3] - s.bounds[1]) for s in slabs])
        return slabs[int(rng.choice(len(slabs), p=areas / areas.sum()))]

    def _ground_point(self, rng: np.random.Generator, ring: tuple[float, float]) -> NDArray[np.float64]:
        """A plan point drawn in the square around the footprint grown by ``ring[1]``."""
        xmin, ymin, xmax, ymax = self._bounds
        r = ring[1]
        return np.array([rng.uniform(xmin - r, xmax + r), rng.uniform(ymin - r, ymax + r)])

    # -------------------------------------------------------------------------- materials
    def _material(self, kind: str, name: str, rect: _Rect, z: float, rng: np.random.Generator) -> list[Box]:
        if kind == "rebar":  # bundles of 12 m bars on timber bearers
            h = 0.25
            return [Box(f"{name}/bundle", kind, _pose((rect.cx, rect.cy, z + 0.1 + h / 2), rect.yaw),
                        np.array([rect.hx, rect.hy, h / 2]), (0.45, 0.25, 0.15, 1.0))]
        if kind == "formwork_panels":  # a stack of plywood panels
            h = float(rng.uniform(0.4, 1.0))
            return [Box(f"{name}/stack", kind, _pose((rect.cx, rect.cy, z + h / 2), rect.yaw),
                        np.array([rect.hx, rect.hy, h / 2]), (0.78, 0.3, 0.12, 1.0))]
        h = 0.9  # a pallet of cement bags
        return [
            Box(f"{name}/pallet", kind, _pose((rect.cx, rect.cy, z + 0.07), rect.yaw),
                np.array([rect.hx, rect.hy, 0.07]), (0.6, 0.45, 0.25, 1.0)),
            Box(f"{name}/bags", kind, _pose((rect.cx, rect.cy, z + 0.14 + (h - 0.14) / 2), rect.yaw),
                np.array([rect.hx - 0.05, rect.hy - 0.05, (h - 0.14) / 2]), (0.82, 0.8, 0.74, 1.0)),
        ]

    _MATERIAL_SIZES = {"rebar": (2.0, 0.3), "formwork_panels": (1.25, 0.62), "pallet": (0.6, 0.5)}

    def _slab_materials(self, rng: np.random.Generator, n: int) -> list[Box]:
        boxes: list[Box] = []
        for k in range(n):
            kind = _MATERIAL_KINDS[int(rng.integers(len(_MATERIAL_KINDS)))]
            hx, hy = self._MATERIAL_SIZES[kind]
            for _ in range(_MAX_TRIES):
                slab = self._pick_slab(rng)
                if slab is None:
                    return boxes
                xmin, ymin, xmax, ymax = slab.bounds
                rect = _Rect(rng.uniform(xmin, xmax), rng.uniform(ymin, ymax), hx, hy,
                             float(rng.uniform(0, math.pi)))
                if (self._clear_of_landmarks(rect, slab.z_top) and self._free(rect, slab.z_top)
                        and self._slab_ok(slab, rect, _ITEM_GAP)):
                    self._taken.append((rect, slab.z_top))
                    boxes += self._material(kind, f"{kind} s{k}", rect, slab.z_top, rng)
                    break
        return boxes

    def _ground_rect(self, rng: np.random.Generator, hx: float, hy: float,
                     ring: tuple[float, float]) -> _Rect | None:
        """A free rectangle on the ground in ``ring``, turned along the footprint's nearer side."""
        xmin, ymin, xmax, ymax = self._bounds
        for _ in range(_MAX_TRIES):
            c = self._ground_point(rng, ring)
            outside_x = c[0] < xmin or c[0] > xmax
            outside_y = c[1] < ymin or c[1] > ymax
            yaw = math.pi / 2 if outside_x and not outside_y else 0.0
            yaw += float(rng.uniform(-0.2, 0.2)) + (math.pi if rng.random() < 0.5 else 0.0)
            rect = _Rect(float(c[0]), float(c[1]), hx, hy, yaw)
            d = _ring_distance(rect.corners(), self._bounds)
            if (d.min() >= ring[0] and _ring_distance(c, self._bounds)[0] <= ring[1]
                    and self._clear_of_landmarks(rect, 0.0) and self._free(rect, 0.0, 1.0)):
                self._taken.append((rect, 0.0))
                return rect
        return None

    def _ground_materials(self, rng: np.random.Generator, n: int) -> list[Box]:
        boxes: list[Box] = []
        for k in range(n):
            kind = _MATERIAL_KINDS[int(rng.integers(len(_MATERIAL_KINDS)))]
            rect = self._ground_rect(rng, *self._MATERIAL_SIZES[kind], (2.0, 12.0))
            if rect is not None:
                boxes += self._material(kind, f"{kind} g{k}", rect, 0.0, rng)
        return boxes

    # -------------------------------------------------------------------------- scaffolding
    def _scaffolding(self, n_edges: int) -> list[Box]:
        """Scaffold runs outside the longest floor-slab edges, clear of the corners."""
        edges = []
        for s in self.site.floor:
            o = s.outline
            for i in range(len(o)):
                a, b = o[i], o[(i + 1) % len(o)]
                edges.append((float(np.linalg.norm(b - a)), s, a, b))
        edges.sort(key=lambda e: -e[0])
        boxes: list[Box] = []
        clearance = max(self.activity.landmark_clearance, 1.5)
        for length, slab, a, b in edges[:n_edges]:
            run = min(length - 2 * clearance, 10.0)
            if run < 2.0:
                continue
            along = (b - a) / length
            out = np.array([along[1], -along[0]])  # outward: outlines run counter-clockwise
            yaw = math.atan2(along[1], along[0])
            for offset in _SCAFFOLD_OFFSETS:  # the nearest standing place clear of the building
                mid = (a + b) / 2 + out * (offset + _SCAFFOLD_WIDTH / 2)
                rect = _Rect(float(mid[0]), float(mid[1]), run / 2, _SCAFFOLD_WIDTH / 2, yaw)
                if self._clear_of_building(rect, slab.z_top + 1.0) and self._free(rect, 0.0):
                    self._taken.append((rect, 0.0))
                    boxes += self._scaffold_run(f"scaffold {len(self._taken)}", rect, slab.z_top)
                    break
        return boxes

    def _clear_of_building(self, rect: _Rect, top: float) -> bool:
        """No built element's plan box below ``top`` overlaps the rectangle."""
        for e in self.site.built:
            if e.z_bottom >= top or e.z_top <= 0.05:  # above it, or at ground level (stood on)
                continue
            xmin, ymin, xmax, ymax = e.bounds
            if isinstance(e, Slab) and e in self.site.floor and e.z_top <= top:
                # the floor itself: only its outline matters, the scaffold stands outside it
                if np.any(e.covers(rect.corners(-0.01))):
                    return False
                continue
            box = _Rect((xmin + xmax) / 2, (ymin + ymax) / 2, (xmax - xmin) / 2, (ymax - ymin) / 2, 0.0)
            if rect.overlaps(box, 0.05):
                return False
        return True

    def _scaffold_run(self, name: str, rect: _Rect, deck_z: float) -> list[Box]:
        top = deck_z + 1.0  # guard rail
        ax = rect.axes()
        centre = np.array([rect.cx, rect.cy])
        n_bays = max(1, round(2 * rect.hx / 2.5))
        xs = np.linspace(-rect.hx, rect.hx, n_bays + 1)
        boxes = []
        post = np.array([0.025, 0.025, top / 2])
        for row, y in (("in", -rect.hy), ("out", rect.hy)):
            for i, x in enumerate(xs):
                xy = centre + x * ax[0] + y * ax[1]
                boxes.append(Box(f"{name}/standard {row} {i}", "scaffold", _pose((*xy, top / 2), rect.yaw),
                                 post, _STEEL))
        rail = np.array([rect.hx, 0.025, 0.025])
        lifts = [*np.arange(2.0, deck_z - 0.5, 2.0), deck_z + 0.5, top]
        for j, z in enumerate(lifts):
            xy = centre + rect.hy * ax[1]
            boxes.append(Box(f"{name}/ledger {j}", "scaffold", _pose((*xy, z), rect.yaw), rail, _STEEL))
        boxes.append(Box(f"{name}/deck", "scaffold", _pose((rect.cx, rect.cy, deck_z - 0.03), rect.yaw),
                         np.array([rect.hx, rect.hy, 0.03]), (0.7, 0.55, 0.3, 1.0)))
        return boxes

    # -------------------------------------------------------------------------- formwork
    def _formwork(self, rng: np.random.Generator, share: float) -> list[Box]:
        columns = self.site.exposed_columns
        n = int(round(share * len(columns)))
        if n == 0:
            return []
        chosen = rng.choice(len(columns), size=n, replace=False)
        boxes = []
        for k in sorted(chosen.tolist()):
            c = columns[k]
            xmin, ymin, xmax, ymax = c.bounds
            h = 0.6 * (c.z_top - c.z_bottom)
            half = np.array([(xmax - xmin) / 2 + 0.04, (ymax - ymin) / 2 + 0.04, h / 2])
            boxes.append(Box(f"formwork {c.name}", "formwork",
                             _pose(((xmin + xmax) / 2, (ymin + ymax) / 2, c.z_bottom + h / 2)), half,
                             (0.8, 0.62, 0.2, 1.0)))
        return boxes

    # -------------------------------------------------------------------------- equipment
    def _equipment(self, rng: np.random.Generator, kinds: tuple[str, ...]) -> list[Box]:
        boxes: list[Box] = []
        for k, kind in enumerate(kinds):
            parts = _EQUIPMENT[kind]()
            local = np.array([c for _, lo, hi, *_ in parts for c in (lo, hi)])
            hx = float(np.abs(local[:, 0]).max())
            hy = float(np.abs(local[:, 1]).max())
            rect = self._ground_rect(rng, hx, hy, _EQUIPMENT_RING)
            if rect is None:
                continue
            slew = float(rng.uniform(-0.6, 0.6)) if kind == "excavator" else 0.0
            boxes += _place_parts(f"{kind} {k}", kind, parts, rect, slew)
        return boxes

    # -------------------------------------------------------------------------- workers
    def _walkable(self, surface: str, slab: Slab | None, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether a worker may stand at each plan point (..., 2); shape ``xy.shape[:-1]``."""
        xy = np.asarray(xy, dtype=np.float64)
        shape = xy.shape[:-1]
        xy = xy.reshape(-1, 2)
        reach = 0.25  # a worker's plan radius
        z = slab.z_top if slab is not None else 0.0
        ok = np.ones(len(xy), dtype=bool)
        centre, rot, half = self._taken_arrays(z)
        if len(centre):  # plan distance from every point to every item on this surface
            dx, dy = xy[:, :1] - centre[:, 0], xy[:, 1:] - centre[:, 1]  # (N, R)
            gx = np.maximum(np.abs(dx * rot[:, 0, 0] + dy * rot[:, 0, 1]) - half[:, 0], 0.0)
            gy = np.maximum(np.abs(dx * rot[:, 1, 0] + dy * rot[:, 1, 1]) - half[:, 1], 0.0)
            ok &= (gx * gx + gy * gy).min(axis=1) >= (reach + 0.2) ** 2
        if surface == "ground":
            d = _ring_distance(xy, self._bounds)
            return (ok & (d >= _WORKER_RING[0]) & (d <= _WORKER_RING[1])).reshape(shape)
        m = reach + _EDGE_MARGIN
        xmin, ymin, xmax, ymax = slab.bounds
        ok &= (xy[:, 0] >= xmin + m) & (xy[:, 0] <= xmax - m)
        ok &= (xy[:, 1] >= ymin + m) & (xy[:, 1] <= ymax - m)
        if self._column_boxes.size:
            lo, hi = self._column_boxes[:, :2], self._column_boxes[:, 2:]
            gap = np.maximum(np.maximum(lo[None] - xy[:, None], xy[:, None] - hi[None]), 0.0)
            ok &= np.hypot(gap[..., 0], gap[..., 1]).min(axis=1) >= m
        ring = m * np.array([[1, 0], [-1, 0], [0, 1], [0, -1], [0.7, 0.7], [-0.7, 0.7], [0.7, -0.7],
                             [-0.7, -0.7], [0, 0]])
        rows = np.flatnonzero(ok)  # the polygon test only where the cheap tests passed
        if len(rows):
            on = slab.covers((xy[rows, None, :] + ring[None]).reshape(-1, 2)).reshape(len(rows), -1)
            ok[rows] = on.all(axis=1)
        return ok.reshape(shape)

    def _taken_arrays(self, z: float) -> tuple[NDArray, NDArray, NDArray]:
        """Centres (R, 2), axes (R, 2, 2) and half sizes (R, 2) of the items on surface ``z``."""
        key = (round(z, 3), len(self._taken))
        if key not in self._taken_cache:
            rects = [r for r, z2 in self._taken if abs(z - z2) < 0.5]
            self._taken_cache[key] = (
                np.array([[r.cx, r.cy] for r in rects]).reshape(-1, 2),
                np.array([r.axes() for r in rects]).reshape(-1, 2, 2),
                np.array([[r.hx, r.hy] for r in rects]).reshape(-1, 2),
            )
        return self._taken_cache[key]

    def _workers(self, rng: np.random.Generator, n: int, surface: str, start: int = 0) -> list[Worker]:
        workers = []
        for _ in range(n):
            slab = self._pick_slab(rng) if surface == "slab" else None
            if surface == "slab" and slab is None:
                break
            z = slab.z_top if slab is not None else 0.0
            if slab is None:
                starts = np.array([self._ground_point(rng, _WORKER_RING) for _ in range(_CANDIDATES)])
            else:
                b = slab.bounds
                starts = np.array([[rng.uniform(b[0], b[2]), rng.uniform(b[1], b[3])]
                                   for _ in range(_CANDIDATES)])
            good = np.flatnonzero(self._walkable(surface, slab, starts))
            if len(good) == 0:
                continue
            path = [starts[good[0]]]
            f = np.linspace(0.0, 1.0, 28)[None, :, None]  # <= 0.42 m apart
            for _ in range(_WAYPOINTS - 1):
                # the next waypoint within 8 m (a path stays local): the first candidate whose
                # whole segment is walkable
                ends = path[-1] + rng.uniform(-8, 8, (_CANDIDATES, 2))
                along = path[-1] + f * (ends[:, None, :] - path[-1])
                good = np.flatnonzero(self._walkable(surface, slab, along).all(axis=1))
                if len(good):
                    path.append(ends[good[0]])
            waypoints = np.array(path)
            length = float(np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum())
            speed = float(rng.uniform(*self.activity.walking_speed))
            phase = float(rng.uniform(0, 2 * length)) if length > 0 else 0.0
            colour = _HI_VIS[int(rng.integers(len(_HI_VIS)))]
            workers.append(Worker(f"worker {start + len(workers)}", surface, z, waypoints, speed, phase,
                                  colour))
        return workers


# ------------------------------------------------------------------------------ equipment shapes
# Each part: (label, lo (3,), hi (3,), rgba, pitch about its lo-x end (rad) or 0). Local frame:
# x along the machine (front +x), z up from the ground, centred on the machine's plan centre.
_Part = tuple[str, tuple[float, float, float], tuple[float, float, float], tuple[float, ...], float]


def _truck() -> list[_Part]:
    return [
        ("wheels", (-3.6, -1.2, 0.0), (3.4, 1.2, 1.0), _DARK, 0.0),
        ("chassis", (-4.0, -1.25, 0.9), (4.0, 1.25, 1.4), _DARK, 0.0),
        ("cab", (2.0, -1.25, 1.4), (4.0, 1.25, 3.2), (0.85, 0.15, 0.12, 1.0), 0.0),
        ("bed", (-4.0, -1.25, 1.4), (1.8, 1.25, 2.9), (0.55, 0.55, 0.58, 1.0), 0.0),
    ]


def _excavator() -> list[_Part]:
    return [
        ("track L", (-2.25, -1.5, 0.0), (2.25, -0.9, 0.9), _DARK, 0.0),
        ("track R", (-2.25, 0.9, 0.0), (2.25, 1.5, 0.9), _DARK, 0.0),
        ("house", (-1.8, -1.3, 0.9), (1.2, 1.3, 2.2), _YELLOW, 0.0),
        ("cab", (0.2, 0.3, 2.2), (1.2, 1.2, 3.0), _GLASS, 0.0),
        ("boom", (1.0, -0.3, 1.6), (6.0, 0.3, 2.2), _YELLOW, math.radians(35)),
        ("arm", (4.6, -0.22, 0.2), (5.0, 0.22, 4.6), _YELLOW, 0.0),
        ("bucket", (4.3, -0.6, 0.0), (5.5, 0.6, 0.9), _DARK, 0.0),
    ]


def _mobile_crane() -> list[_Part]:
    return [
        ("wheels", (-5.5, -1.3, 0.0), (5.5, 1.3, 1.1), _DARK, 0.0),
        ("carrier", (-6.0, -1.375, 1.1), (6.0, 1.375, 2.1), _YELLOW, 0.0),
        ("cab", (4.2, -1.375, 2.1), (6.0, -0.3, 3.6), _YELLOW, 0.0),
        ("superstructure", (-4.5, -1.3, 2.1), (-0.5, 1.3, 3.4), _YELLOW, 0.0),
        ("operator cab", (-1.5, 0.6, 2.1), (0.0, 1.35, 3.8), _GLASS, 0.0),
        ("boom", (-3.5, -0.5, 3.0), (8.0, 0.5, 4.0), _YELLOW, math.radians(20)),
        ("outrigger front", (3.0, -3.2, 0.0), (3.4, 3.2, 0.5), _DARK, 0.0),
        ("outrigger rear", (-4.5, -3.2, 0.0), (-4.1, 3.2, 0.5), _DARK, 0.0),
    ]


def _concrete_pump() -> list[_Part]:
    return [
        ("wheels", (-4.5, -1.2, 0.0), (4.5, 1.2, 1.0), _DARK, 0.0),
        ("chassis", (-5.0, -1.25, 1.0), (5.0, 1.25, 1.5), _DARK, 0.0),
        ("cab", (3.2, -1.25, 1.5), (5.0, 1.25, 3.2), (0.9, 0.9, 0.92, 1.0), 0.0),
        ("pump", (-5.0, -1.2, 1.5), (-3.0, 1.2, 2.6), (0.55, 0.55, 0.58, 1.0), 0.0),
        ("turret", (1.5, -1.0, 1.5), (3.0, 1.0, 3.0), (0.95, 0.5, 0.1, 1.0), 0.0),
        ("boom", (-4.5, -0.5, 3.0), (4.5, 0.5, 4.0), (0.95, 0.5, 0.1, 1.0), 0.0),
        ("outrigger front", (2.2, -3.0, 0.0), (2.6, 3.0, 0.5), _DARK, 0.0),
        ("outrigger rear", (-3.8, -3.0, 0.0), (-3.4, 3.0, 0.5), _DARK, 0.0),
    ]


_EQUIPMENT = {"mobile_crane": _mobile_crane, "excavator": _excavator, "truck": _truck,
              "concrete_pump": _concrete_pump}


def _place_parts(name: str, kind: str, parts: list[_Part], rect: _Rect, slew: float) -> list[Box]:
    """The parts as boxes at the machine's footprint ``rect`` (a pitched part pivots at its lo-x end)."""
    machine = _pose((rect.cx, rect.cy, 0.0), rect.yaw)
    boxes = []
    for label, lo, hi, rgba, pitch in parts:
        lo_a, hi_a = np.array(lo), np.array(hi)
        half = (hi_a - lo_a) / 2
        if pitch:
            pivot = np.array([lo_a[0], (lo_a[1] + hi_a[1]) / 2, (lo_a[2] + hi_a[2]) / 2])
            local = _pose(pivot, 0.0, pitch) @ _pose((half[0], 0.0, 0.0))
        else:
            local = _pose((lo_a + hi_a) / 2)
        upper = label not in ("track L", "track R", "wheels", "chassis", "carrier") and kind == "excavator"
        turn = _pose((0.0, 0.0, 0.0), slew) if upper else np.eye(4)
        boxes.append(Box(f"{name}/{label}", kind, machine @ turn @ local, half, rgba))
    return boxes
