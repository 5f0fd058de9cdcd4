"""Kinematic camera UAV: state, normalized viewpoint commands, geofence and collision geometry.

Viewpoint planning, not flight control: a UAV is its camera centre, a heading and a stabilized
gimbal pitch; commands are velocities held for one control period (explicit Euler). The camera
sits at the UAV's position (the Mavic 2 Pro's ~0.1 m gimbal offset is ignored) and the gimbal
keeps the camera roll at zero, so the true attitude is ``(0, gimbal_pitch, yaw)`` in the
convention of :mod:`uav_struct_env.sim.attitude` (positive pitch looks down).

Action (float32 (5,), each in [-1, 1], see :data:`ACTION_COMPONENTS`):

====  ======================  =================================================================
idx   component               scaling (defaults of :class:`FlightLimits`)
====  ======================  =================================================================
0     ``forward``             horizontal velocity along the heading, x ``max_horizontal_speed``
1     ``left``                horizontal velocity 90 deg left of the heading, same scale; the
                              (forward, left) pair is clipped to the unit disc first
2     ``up``                  vertical velocity: +1 -> ``max_ascent_speed``,
                              -1 -> ``max_descent_speed`` downwards
3     ``yaw_rate``            heading rate, counter-clockwise seen from above, x ``max_yaw_rate``
4     ``gimbal_pitch_rate``   camera pitch rate, positive tilts the camera *down*,
                              x ``max_gimbal_rate``; pitch clipped to the gimbal range
====  ======================  =================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import as_floats, check_number
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.attitude import world_from_cam_from_attitude
from uav_struct_env.site import Site
from uav_struct_env.site.elements import element_boxes

__all__ = [
    "ACTION_COMPONENTS",
    "FlightLimits",
    "Geofence",
    "Obstacles",
    "UavState",
    "step_uav",
    "wrap_angle",
]

ACTION_COMPONENTS = ("forward", "left", "up", "yaw_rate", "gimbal_pitch_rate")


def wrap_angle(a: ArrayLike) -> NDArray[np.float64] | float:
    """Wrap angles (rad) to [-pi, pi)."""
    if isinstance(a, float):  # one angle (np.float64 too): Python's % is numpy's remainder
        return (float(a) + math.pi) % (2.0 * math.pi) - math.pi
    out = (np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi
    return float(out) if out.ndim == 0 else out


def _check_positive(owner: str, name: str, value: float) -> None:
    check_number(f"{owner}.{name}", value, 0, lo_open=True, error=ConfigError, type_error=ConfigError)


@dataclass(frozen=True)
class FlightLimits:
    """Command limits of a DJI Mavic 2 Pro class camera UAV (SI units, rad).

    DJI's published Mavic 2 Pro specifications: max speed 72 km/h (20 m/s) in S-mode, max ascent
    5 m/s (S-mode) / 4 m/s (P-mode), max descent 3 m/s, max angular velocity 200 deg/s, gimbal
    controllable tilt -90 deg (down) to +30 deg (up), max tilt control speed 120 deg/s.
    The defaults are the calmer P-mode-like values a viewpoint survey would fly: 10 m/s
    horizontal, 4 m/s up, 3 m/s down, 100 deg/s yaw, 90 deg/s gimbal. In this project's attitude
    convention positive pitch looks down, so DJI's tilt range -90..+30 deg is camera pitch
    ``-30 deg .. +90 deg``.

    Attributes:
        max_horizontal_speed: speed of a full forward/left command, m/s.
        max_ascent_speed: climb rate of a full up command, m/s.
        max_descent_speed: sink rate of a full down command, m/s.
        max_yaw_rate: yaw rate of a full yaw command, rad/s.
        max_gimbal_rate: gimbal pitch rate of a full gimbal command, rad/s.
        gimbal_pitch_min: lowest camera pitch (negative looks up), rad.
        gimbal_pitch_max: highest camera pitch (positive looks down), rad.
    """

    max_horizontal_speed: float = 10.0
    max_ascent_speed: float = 4.0
    max_descent_speed: float = 3.0
    max_yaw_rate: float = math.radians(100.0)
    max_gimbal_rate: float = math.radians(90.0)
    gimbal_pitch_min: float = math.radians(-30.0)
    gimbal_pitch_max: float = math.radians(90.0)

    def __post_init__(self) -> None:
        for name in (
            "max_horizontal_speed",
            "max_ascent_speed",
            "max_descent_speed",
            "max_yaw_rate",
            "max_gimbal_rate",
        ):
            _check_positive("FlightLimits", name, getattr(self, name))
        lo, hi = self.gimbal_pitch_min, self.gimbal_pitch_max
        if not (-math.pi / 2 <= lo < hi <= math.pi / 2):
            raise ConfigError(
                f"FlightLimits gimbal pitch range must satisfy -pi/2 <= min < max <= pi/2 rad, "
                f"got ({lo!r}, {hi!r})"
            )


@dataclass(frozen=True)
class Geofence:
    """The flight area of the UAVs.

    Camera altitude above ground in ``[min_altitude, max_altitude]`` m and horizontal distance
    from the site centre at most ``max_distance`` m.

    Defaults: 2 m above ground, 120 m (the common EU/US limit for open-category flights), and
    60 m from the building centre (the paper's viewpoints are 15-35 m out).

    Attributes:
        min_altitude: lowest camera altitude above ground, m.
        max_altitude: highest camera altitude above ground, m.
        max_distance: largest horizontal distance from the site centre, m (scaled up with the
            schedule for buildings larger than the paper's).
    """

    min_altitude: float = 2.0
    max_altitude: float = 120.0
    max_distance: float = 60.0

    def __post_init__(self) -> None:
        for name in ("min_altitude", "max_altitude", "max_distance"):
            _check_positive("Geofence", name, getattr(self, name))
        if self.min_altitude >= self.max_altitude:
            raise ConfigError(
                f"Geofence.min_altitude ({self.min_altitude}) must be below max_altitude "
                f"({self.max_altitude})"
            )

    def scaled(self, factor: float) -> Geofence:
        """The fence with ``max_distance`` times ``factor`` (for a building larger than the paper's)."""
        if factor == 1.0:
            return self
        return Geofence(self.min_altitude, self.max_altitude, self.max_distance * factor)

    def violation(self, position: ArrayLike, center_xy: ArrayLike) -> str | None:
        """Why ``position`` (3,) is outside the fence (``"below_min_altitude"`` ...), or None."""
        x, y, z = as_floats("position", position, 3)
        if z < self.min_altitude:
            return "below_min_altitude"
        if z > self.max_altitude:
            return "above_max_altitude"
        cx, cy = as_floats("center_xy", center_xy, 2)
        if float(np.hypot(x - cx, y - cy)) > self.max_distance:
            return "beyond_max_distance"
        return None


@dataclass(frozen=True)
class UavState:
    """Kinematic state: camera centre (3,) in the project frame, heading and gimbal pitch (rad)."""

    position: tuple[float, float, float]
    yaw: float
    pitch: float

    @classmethod
    def make(cls, position: ArrayLike, yaw: float, pitch: float) -> UavState:
        """Build from an array position; the yaw is wrapped to [-pi, pi)."""
        if type(position) is tuple and len(position) == 3:  # step_uav's (x, y, z) floats
            p = position
        else:
            p = np.asarray(position, dtype=np.float64).reshape(3)
        return cls((float(p[0]), float(p[1]), float(p[2])), float(wrap_angle(float(yaw))), float(pitch))

    @classmethod
    def from_world_from_cam(cls, world_from_cam: ArrayLike) -> UavState:
        """The state whose camera is nearest a (4, 4) ``world_from_cam`` (an estimate, say).

        Position as given; heading and gimbal pitch of the optical axis (the yaw and pitch of
        :func:`~localization.geometry.attitude.attitude_from_world_from_cam`, at a fraction of its
        cost); a roll is dropped. Looking straight down, the heading is the camera's left
        axis.
        """
        T = np.asarray(world_from_cam, dtype=np.float64)
        fx, fy, fz = float(T[0, 2]), float(T[1, 2]), float(T[2, 2])  # camera z: the body's forward
        if math.hypot(fx, fy) > 1e-9:
            yaw = math.atan2(fy, fx)
        else:  # camera x is the body's right: horizontal while the roll is 0
            yaw = math.atan2(T[1, 0], T[0, 0]) + 0.5 * math.pi
        pitch = math.asin(min(1.0, max(-1.0, -fz)))
        return cls.make(T[:3, 3], yaw, pitch)

    @property
    def xyz(self) -> NDArray[np.float64]:
        """Position as a float64 (3,) array."""
        return np.array(self.position)

    @property
    def attitude(self) -> NDArray[np.float64]:
        """True camera (roll, pitch, yaw), rad; roll is held at 0 by the gimbal."""
        return np.array([0.0, self.pitch, self.yaw])

    @property
    def world_from_cam(self) -> NDArray[np.float64]:
        """Ground-truth 4x4 ``world_from_cam`` (a fresh copy; computed once per state)."""
        cached = self.__dict__.get("_world_from_cam")
        if cached is None:  # a frozen state's pose never changes; an env step asks several times
            cached = world_from_cam_from_attitude(self.position, (0.0, self.pitch, self.yaw))
            object.__setattr__(self, "_world_from_cam", cached)
        return cached.copy()


def step_uav(
    state: UavState, action: NDArray[np.floating], limits: FlightLimits, dt: float
) -> UavState:
    """Advance one control period ``dt`` (s) under a normalized action (5,) already in [-1, 1].

    Velocities are expressed in the heading frame at the start of the period (explicit Euler).
    """
    # on Python floats: the same arithmetic as on (5,) arrays, a fifth of the overhead
    a = np.asarray(action, dtype=np.float64).reshape(5)
    forward, left, up, yaw_rate, pitch_rate = (float(x) for x in a)
    norm = float(np.hypot(forward, left))  # C's hypot (math.hypot rounds differently)
    if norm > 1.0:
        forward, left = forward / norm, left / norm
    v_fwd, v_left = forward * limits.max_horizontal_speed, left * limits.max_horizontal_speed
    v_up = up * (limits.max_ascent_speed if up >= 0 else limits.max_descent_speed)
    c, s = math.cos(state.yaw), math.sin(state.yaw)
    x, y, z = state.position
    position = (x + dt * (c * v_fwd - s * v_left), y + dt * (s * v_fwd + c * v_left), z + dt * v_up)
    yaw = state.yaw + dt * yaw_rate * limits.max_yaw_rate
    pitch = min(max(state.pitch + dt * pitch_rate * limits.max_gimbal_rate, limits.gimbal_pitch_min),
                limits.gimbal_pitch_max)
    return UavState.make(position, yaw, pitch)


@dataclass(frozen=True, eq=False)
class Obstacles:
    """The structure as axis-aligned boxes ``lo`` (B, 3), ``hi`` (B, 3), with names (B,).

    Built from a :class:`~uav_struct_env.site.Site`: every element built at its stage, cut into
    boxes around openings (a UAV may pass through the stair opening). Markers lie flat on the
    ground and are not obstacles; the ground is handled by the geofence's minimum altitude.
    """

    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    names: tuple[str, ...]

    @classmethod
    def from_site(cls, site: Site) -> Obstacles:
        """The elements built at the site's stage as boxes (:func:`element_boxes`)."""
        lo, hi, names = [], [], []
        for element in site.built:
            a, b = element_boxes(element)
            lo.append(a)
            hi.append(b)
            names += [element.name] * len(a)
        return cls(
            np.concatenate(lo).reshape(-1, 3),
            np.concatenate(hi).reshape(-1, 3),
            tuple(names),
        )

    def with_boxes(self, lo: ArrayLike, hi: ArrayLike, names: tuple[str, ...]) -> Obstacles:
        """These obstacles plus boxes ``lo`` (B, 3), ``hi`` (B, 3) named ``names`` (site activity)."""
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 3)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 3)
        if len(lo) == 0:
            return self
        return Obstacles(
            np.concatenate([self.lo, lo]), np.concatenate([self.hi, hi]), self.names + tuple(names)
        )

    @cached_property
    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Overall bounding box ``(lo (3,), hi (3,))`` of the structure."""
        return self.lo.min(axis=0), self.hi.max(axis=0)

    def distances(self, points: ArrayLike) -> NDArray[np.float64]:
        """Euclidean distance (N,) from each point (N, 3) to the nearest box (0 inside one)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 1, 3)
        if len(self.lo) == 0:
            return np.full(p.shape[0], np.inf)
        gap = np.maximum(np.maximum(self.lo[None] - p, p - self.hi[None]), 0.0)
        return np.sqrt((gap**2).sum(axis=2)).min(axis=1)

    def nearest(self, point: ArrayLike) -> tuple[float, str]:
        """``(distance, name)`` of the box nearest to one point (3,)."""
        p = np.asarray(point, dtype=np.float64).reshape(1, 3)
        gap = np.maximum(np.maximum(self.lo - p, p - self.hi), 0.0)
        d = np.sqrt((gap**2).sum(axis=1))
        k = int(np.argmin(d))
        return float(d[k]), self.names[k]
