"""The scripted viewpoint schedule of the paper's study, as seeded data.

Each UAV ``i`` of ``n`` owns one side of the building: the side whose outward direction has
azimuth ``-90 deg + 360 deg * i / n`` (for four UAVs: ``uav_0`` south (-y), ``uav_1`` east (+x),
``uav_2`` north (+y), ``uav_3`` west (-x)). Its ``n_viewpoints`` viewpoints are a Latin-hypercube
sample (one stratum per viewpoint, strata randomly paired across dimensions) of

* horizontal distance out from the slab edge on the UAV's side (measured along the side's
  direction), ``distance`` m (default 15-35 m),
* camera height above ground, ``height`` m (default 10-25 m),
* azimuth within ``+-azimuth_spread / 2`` of the side's direction (default +-20 deg),

with the camera aimed (roll 0) at the centre of the bounding box of the structural landmarks and
the ArUco markers on the UAV's side, jittered by up to ``aim_jitter`` m per axis. A drawn
viewpoint is kept only if every structural landmark of both construction stages (slab corners,
opening corners, column tops) and all four corners of at least ``min_markers_in_view`` of the
markers on the UAV's side project inside the image with ``margin_px`` to spare for the reference
camera (the paper's 1280 x 720, fx = fy = 1108.5 px); otherwise it is redrawn in the same strata.
(From 15 m out the near-side markers often fall below the frame, so both cannot be required.)
In-frame is a projection check: columns may still occlude some landmarks.

The distance and height ranges are made for buildings up to :data:`REFERENCE_EXTENT` (plan side,
height; the family of :func:`~uav_struct_env.site.random_site` layouts, the paper's building
among them). :meth:`ScheduleSpec.fitted` scales both ranges by :func:`site_scale` for a larger
building (an imported IFC building), and :func:`fit_schedule` widens them further, 25 % at a
time, until every UAV finds its viewpoints (a long building whose markers fall below the frame
from 15 m); the environment scales its geofence's distance by the same factor.

Everything comes from ``numpy.random.default_rng(spec.seed)``, so one seed is one schedule.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import invert, look_at, project
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.attitude import attitude_from_world_from_cam
from uav_struct_env.sim.uav import UavState
from uav_struct_env.site import Site

__all__ = [
    "PAPER_K",
    "REFERENCE_EXTENT",
    "ScheduleSpec",
    "ViewpointSchedule",
    "make_schedule",
    "sample_viewpoint",
    "side_azimuth",
    "side_name",
    "fit_schedule",
    "site_scale",
]

#: (largest plan side, height) in m of the buildings the default ranges are made for.
REFERENCE_EXTENT = (27.0, 9.0)


def site_scale(site: Site) -> float:
    """How much larger than :data:`REFERENCE_EXTENT` the building is (at least 1)."""
    xmin, ymin, xmax, ymax = site.footprint_bounds
    height = max(e.z_top for e in site.elements)
    return float(max(1.0, max(xmax - xmin, ymax - ymin) / REFERENCE_EXTENT[0], height / REFERENCE_EXTENT[1]))

_SIDE_NAMES_4 = ("south", "east", "north", "west")


@dataclass(frozen=True)
class ScheduleSpec:
    """Parameters of a viewpoint schedule (see the module docstring). Lengths m, angles rad.

    Attributes:
        n_viewpoints: viewpoints per UAV (the paper: 10).
        distance: ``(low, high)`` horizontal distance out from the slab edge on the UAV's side, m.
        height: ``(low, high)`` camera height above ground, m.
        azimuth_spread: width of the azimuth range around the side's outward direction, rad.
        aim_jitter: the aim point moves by up to this much per axis, m.
        margin_px: every structural landmark must project at least this far inside the image, px.
        min_markers_in_view: markers on the UAV's side whose four corners must be in the image.
        seed: seed of the schedule (one seed, one schedule).
        max_tries: draws per viewpoint before giving up with a ``ConfigError``.
        K: the reference camera's 3 x 3 intrinsics the in-view check uses (the paper's camera).
        image_size: ``(W, H)`` of the reference camera, px.
    """

    n_viewpoints: int = 10
    distance: tuple[float, float] = (15.0, 35.0)
    height: tuple[float, float] = (10.0, 25.0)
    azimuth_spread: float = math.radians(40.0)
    aim_jitter: float = 1.0
    margin_px: float = 20.0
    min_markers_in_view: int = 1
    seed: int = 0
    max_tries: int = 200
    K: tuple[tuple[float, ...], ...] = tuple(map(tuple, PAPER_K))
    image_size: tuple[int, int] = PAPER_IMAGE_SIZE

    def __post_init__(self) -> None:
        check_number("ScheduleSpec.n_viewpoints", self.n_viewpoints, 1, integer=True,
                     error=ConfigError, type_error=ConfigError)
        for name in ("distance", "height"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
                raise ConfigError(
                    f"ScheduleSpec.{name} must be (low, high) with 0 < low <= high, "
                    f"got {(lo, hi)!r}"
                )
        if not 0 <= self.azimuth_spread < 2 * math.pi:
            raise ConfigError(
                f"ScheduleSpec.azimuth_spread must be in [0, 2 pi) rad, got {self.azimuth_spread!r}"
            )

    def scaled(self, k: float) -> ScheduleSpec:
        """This spec with the distance and height ranges times ``k``."""
        if k == 1.0:
            return self
        return dataclasses.replace(
            self,
            distance=(self.distance[0] * k, self.distance[1] * k),
            height=(self.height[0] * k, self.height[1] * k),
        )


def side_azimuth(agent_index: int, n_agents: int) -> float:
    """Azimuth (rad, from +x towards +y) of the side owned by ``agent_index``."""
    return -math.pi / 2 + 2.0 * math.pi * agent_index / n_agents


def side_name(agent_index: int, n_agents: int) -> str:
    """``"south"``, ``"east"``, ``"north"``, ``"west"`` for four agents, else ``"side <i>"``."""
    return _SIDE_NAMES_4[agent_index] if n_agents == 4 else f"side {agent_index}"


@dataclass(frozen=True, eq=False)
class _ViewTargets:
    """What a viewpoint must see, precomputed from a site."""

    center: NDArray[np.float64]  # building centre, (3,)
    half_extent: NDArray[np.float64]  # footprint half sizes (hx, hy)
    structural: NDArray[np.float64]  # (M, 3), the floor's slab and columns stages
    markers: tuple[NDArray[np.float64], ...]  # per marker (4, 3) corners
    marker_centres: NDArray[np.float64]  # (K, 2)

    @classmethod
    def from_site(cls, site: Site) -> _ViewTargets:
        xmin, ymin, xmax, ymax = site.footprint_bounds
        return cls(
            center=np.asarray(site.center, dtype=np.float64),
            half_extent=np.array([(xmax - xmin) / 2, (ymax - ymin) / 2]),
            structural=site.with_columns_exposed().landmarks("all").xyz,
            markers=tuple(m.corners_world for m in site.markers),
            marker_centres=np.array([m.center[:2] for m in site.markers], dtype=np.float64).reshape(
                -1, 2
            ),
        )

    def edge_offset(self, azimuth: float) -> float:
        """Distance from the centre to the slab edge along the horizontal direction ``azimuth``."""
        c, s = abs(math.cos(azimuth)), abs(math.sin(azimuth))
        hx, hy = self.half_extent
        return float(min(hx / c if c > 1e-12 else np.inf, hy / s if s > 1e-12 else np.inf))

    def own_side_markers(self, azimuth: float) -> tuple[NDArray[np.float64], ...]:
        """Corners (4, 3) of each marker whose direction from the centre is within 45 deg."""
        if len(self.markers) == 0:
            return ()
        d = self.marker_centres - self.center[:2]
        ang = np.arctan2(d[:, 1], d[:, 0]) - azimuth
        near = np.abs((ang + np.pi) % (2 * np.pi) - np.pi) <= math.radians(45.0)
        return tuple(c for c, keep in zip(self.markers, near, strict=True) if keep)

    def aim(self, azimuth: float) -> NDArray[np.float64]:
        """Aim point: centre of the bounding box of the structure and the own-side markers."""
        pts = np.concatenate([self.structural, *self.own_side_markers(azimuth)])
        return (pts.min(axis=0) + pts.max(axis=0)) / 2


def _in_view(
    points: NDArray[np.float64], cam_from_world: NDArray[np.float64], spec: ScheduleSpec
) -> bool:
    if len(points) == 0:
        return True
    uv, depth = project(np.asarray(spec.K), cam_from_world, points)
    w, h = spec.image_size
    m = spec.margin_px
    return bool(
        np.all(depth > 0)
        and np.all(
            (uv[:, 0] >= m) & (uv[:, 0] <= w - 1 - m) & (uv[:, 1] >= m) & (uv[:, 1] <= h - 1 - m)
        )
    )


def sample_viewpoint(
    site_or_targets: Site | _ViewTargets,
    agent_index: int,
    n_agents: int,
    rng: np.random.Generator,
    spec: ScheduleSpec = ScheduleSpec(),
    strata: ArrayLike | None = None,
    n_strata: int = 1,
) -> tuple[UavState, NDArray[np.float64]]:
    """One viewpoint on the agent's side that passes the in-view check: ``(state, target (3,))``.

    ``strata`` (3,) ints select the stratum of (distance, height, azimuth) out of ``n_strata``
    (the Latin hypercube of :func:`make_schedule`); ``None`` samples the whole range.

    Raises:
        ConfigError: if no viewpoint passes the check in ``spec.max_tries`` draws.
    """
    targets = (
        site_or_targets
        if isinstance(site_or_targets, _ViewTargets)
        else _ViewTargets.from_site(site_or_targets)
    )
    s = np.zeros(3) if strata is None else np.asarray(strata, dtype=np.float64)
    base_az = side_azimuth(agent_index, n_agents)
    markers = targets.own_side_markers(base_az)
    need_markers = min(spec.min_markers_in_view, len(markers))
    radial0 = targets.edge_offset(base_az)
    aim = targets.aim(base_az)
    c = targets.center
    for _ in range(spec.max_tries):
        u = (s + rng.random(3)) / n_strata
        distance = spec.distance[0] + u[0] * (spec.distance[1] - spec.distance[0])
        height = spec.height[0] + u[1] * (spec.height[1] - spec.height[0])
        azimuth = base_az + (u[2] - 0.5) * spec.azimuth_spread
        target = aim + rng.uniform(-spec.aim_jitter, spec.aim_jitter, 3)
        r = radial0 + distance
        eye = np.array([c[0] + r * math.cos(azimuth), c[1] + r * math.sin(azimuth), height])
        cam_from_world = look_at(eye, target)
        if not _in_view(targets.structural, cam_from_world, spec):
            continue
        if sum(_in_view(m, cam_from_world, spec) for m in markers) < need_markers:
            continue
        _, (_, pitch, yaw) = attitude_from_world_from_cam(invert(cam_from_world))
        return UavState.make(eye, yaw, pitch), target
    raise ConfigError(
        f"no viewpoint for agent {agent_index} keeps every landmark in view after {spec.max_tries} "
        f"draws with distance {spec.distance} m, height {spec.height} m: widen the ranges or "
        "lower margin_px"
    )


@dataclass(frozen=True, eq=False)
class ViewpointSchedule:
    """Scripted viewpoints for ``n_agents`` UAVs, as arrays.

    ``positions`` (A, V, 3) m, ``attitudes`` (A, V, 3) true camera (roll, pitch, yaw) rad,
    ``targets`` (A, V, 3) aim points, ``center`` (3,) the building centre, ``sides`` (A,).
    """

    positions: NDArray[np.float64]
    attitudes: NDArray[np.float64]
    targets: NDArray[np.float64]
    center: NDArray[np.float64]
    sides: tuple[str, ...]
    spec: ScheduleSpec = field(default_factory=ScheduleSpec)

    @property
    def n_agents(self) -> int:
        """Number of UAVs."""
        return int(self.positions.shape[0])

    @property
    def n_viewpoints(self) -> int:
        """Viewpoints per UAV."""
        return int(self.positions.shape[1])

    def state(self, agent_index: int, k: int) -> UavState:
        """The kinematic state of UAV ``agent_index`` at viewpoint ``k``."""
        roll, pitch, yaw = self.attitudes[agent_index, k]
        return UavState.make(self.positions[agent_index, k], yaw, pitch)

    def world_from_cam(self, agent_index: int, k: int) -> NDArray[np.float64]:
        """Ground-truth 4x4 ``world_from_cam`` of UAV ``agent_index`` at viewpoint ``k``."""
        return self.state(agent_index, k).world_from_cam

    @cached_property
    def horizontal_distances(self) -> NDArray[np.float64]:
        """(A, V) horizontal distance from the building centre, m."""
        d = self.positions[..., :2] - self.center[:2]
        return np.hypot(d[..., 0], d[..., 1])

    def as_dict(self) -> dict:
        """Plain lists, for JSON reports."""
        return {
            "positions_m": self.positions.tolist(),
            "attitudes_rad": self.attitudes.tolist(),
            "targets_m": self.targets.tolist(),
            "sides": list(self.sides),
            "seed": self.spec.seed,
        }


def make_schedule(
    site: Site, n_agents: int = 4, spec: ScheduleSpec = ScheduleSpec()
) -> ViewpointSchedule:
    """The seeded viewpoint schedule of ``n_agents`` UAVs around ``site`` (module docstring)."""
    check_number("n_agents", n_agents, 1, integer=True, error=ConfigError, type_error=ConfigError)
    rng = np.random.default_rng(spec.seed)
    targets = _ViewTargets.from_site(site)
    V = spec.n_viewpoints
    positions = np.zeros((n_agents, V, 3))
    attitudes = np.zeros((n_agents, V, 3))
    aims = np.zeros((n_agents, V, 3))
    for i in range(n_agents):
        strata = np.stack([rng.permutation(V) for _ in range(3)], axis=1)  # (V, 3)
        for k in range(V):
            state, target = sample_viewpoint(targets, i, n_agents, rng, spec, strata[k], V)
            positions[i, k] = state.xyz
            attitudes[i, k] = state.attitude
            aims[i, k] = target
    return ViewpointSchedule(
        positions,
        attitudes,
        aims,
        targets.center.copy(),
        tuple(side_name(i, n_agents) for i in range(n_agents)),
        spec,
    )


def fit_schedule(
    site: Site, n_agents: int = 4, spec: ScheduleSpec = ScheduleSpec(), *, attempts: int = 6
) -> tuple[ViewpointSchedule, float]:
    """:func:`make_schedule` with the ranges scaled to the building: ``(schedule, factor)``.

    Starts at :func:`site_scale` (1 for the paper's and the random layouts, whose schedules are
    unchanged) and widens the ranges by 25 % per failed attempt.

    Raises:
        ConfigError: the last attempt's error, if no attempt finds every viewpoint.
    """
    k = site_scale(site)
    for attempt in range(attempts):
        try:
            return make_schedule(site, n_agents, spec.scaled(k)), k
        except ConfigError:
            if attempt == attempts - 1:
                raise
            k *= 1.25
    raise AssertionError("unreachable")
