"""Localization over time for the wrapper: one :class:`~localization.temporal.PoseFilter` per agent.

:class:`PoseTracks` is what :class:`~uav_struct_env.wrappers.LocalizePoses` uses with
``temporal=True``. Per agent and step it

1. predicts the filter over the control period with the agent's *commanded* motion: the action
   applied by :func:`~uav_struct_env.sim.uav.step_uav` to the filtered pose (heading and gimbal
   pitch from the estimate, never the truth), so a real UAV could do the same;
2. fuses the env's attitude reading and, when ``info["gnss_fix"]``, its GNSS reading, with the
   noise model of the env's sensor model (:func:`filter_noise_for`) and its multipath factor at
   the *estimated* clearance from the BIM;
3. gives the prediction and its sigmas as the association prior of the frame's localization;
4. fuses the frame's visual fix (chi-square gated).

Nothing here reads the ground truth.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from localization import PoseEstimate, PriorSigmas
from localization.geometry.transforms import so3_log
from localization.temporal import FilterNoise, PoseFilter, Update, attitude_of
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.sensors import DegradedGnssNoise, GnssInsNoise, NoNoise, PaperNoise
from uav_struct_env.sim.uav import ACTION_COMPONENTS, Obstacles, UavState, step_uav

__all__ = ["PoseTracks", "filter_noise_for"]

#: White noise the filter assumes for a sensor model that has none (``none``, ``paper``), m / rad.
_FLOOR_POSITION_M = 0.05
_FLOOR_ROTATION_RAD = math.radians(0.05)


def filter_noise_for(sensor: Any) -> FilterNoise:
    """The :class:`~localization.temporal.FilterNoise` matching an env sensor model.

    ``gnss_ins`` and ``gnss_degraded`` give their own sigmas and bias time (the degraded model's
    jumps are left to the GNSS gate, its outages to ``info["gnss_fix"]``); ``paper`` is a bias of
    its fixed offsets that never decorrelates (it is one per episode and viewpoint); ``none`` a
    tiny noise floor. Another model object: the ``gnss_ins`` defaults.
    """
    if isinstance(sensor, DegradedGnssNoise):
        sensor = sensor.base
    if isinstance(sensor, GnssInsNoise):
        return FilterNoise(
            gnss_white_sigma=sensor.gnss_white_sigma,
            gnss_bias_sigma=sensor.gnss_bias_sigma,
            gnss_bias_tau=sensor.gnss_bias_tau,
            attitude_white_sigma=sensor.attitude_white_sigma,
            attitude_bias_sigma=sensor.attitude_bias_sigma,
        )
    if isinstance(sensor, PaperNoise):
        return FilterNoise(
            gnss_white_sigma=(_FLOOR_POSITION_M,) * 3,
            gnss_bias_sigma=(sensor.position_offset,) * 3,
            gnss_bias_tau=1.0e6,
            attitude_white_sigma=(_FLOOR_ROTATION_RAD,) * 3,
            attitude_bias_sigma=(sensor.roll_offset, sensor.pitch_offset, sensor.yaw_offset),
        )
    if isinstance(sensor, NoNoise):
        return FilterNoise(
            gnss_white_sigma=(_FLOOR_POSITION_M,) * 3,
            gnss_bias_sigma=(0.0,) * 3,
            attitude_white_sigma=(_FLOOR_ROTATION_RAD,) * 3,
            attitude_bias_sigma=(0.0,) * 3,
            estimate_gnss_bias=False,
            estimate_attitude_bias=False,
        )
    return FilterNoise()


class PoseTracks:
    """One pose filter per agent of a ``uav_struct_v0`` env (module docstring).

    Args:
        base: the unwrapped env (its ``config``: limits, control period, sensor model; its
            design ``site``, the BIM, for the clearance of the estimated position).
        noise: the filters' :class:`~localization.temporal.FilterNoise`; default
            :func:`filter_noise_for` the env's sensor model.

    Raises:
        ConfigError: if ``noise`` is not a FilterNoise.
    """

    def __init__(self, base: Any, noise: FilterNoise | None = None) -> None:
        if noise is not None and not isinstance(noise, FilterNoise):
            raise ConfigError(f"filter_noise must be a localization.temporal.FilterNoise, got {noise!r}")
        config = base.config
        self.noise = filter_noise_for(config.noise) if noise is None else noise
        self._sensor = config.noise
        self._limits = config.limits
        self._dt = float(config.control_period)
        self._obstacles = Obstacles.from_site(base.site)
        self.filters: dict[str, PoseFilter] = {}
        self.last_updates: dict[str, dict[str, Update]] = {}
        self._actions: dict[str, Any] = {}

    def reset(self) -> None:
        """Forget every filter (a new episode starts from its first readings)."""
        self.filters = {}
        self.last_updates = {}
        self._actions = {}

    def command(self, actions: dict[str, Any]) -> None:
        """Record the actions of the coming step (agents without one hover, as in the env)."""
        self._actions = dict(actions)

    def prior(self, agent: str, obs: dict, info: dict) -> tuple[np.ndarray, PriorSigmas]:
        """Predict ``agent``'s filter, fuse its readings; the prior ``(cam_from_world, sigmas)``."""
        gnss = np.asarray(obs["gnss"], dtype=np.float64) if info.get("gnss_fix", True) else None
        attitude = np.asarray(obs["attitude"], dtype=np.float64)
        filt = self.filters.get(agent)
        updates: dict[str, Update] = {}
        if filt is None:
            filt = self.filters[agent] = PoseFilter(self.noise)
            scale = self._gnss_scale(gnss) if gnss is not None else 1.0
            for upd in filt.start(gnss, attitude, gnss_scale=scale):
                updates[upd.kind] = upd
        else:
            displacement, rotation = self._motion(filt, self._actions.get(agent))
            filt.predict(self._dt, displacement, rotation, gnss_scale=self._gnss_scale(filt.position))
            updates["attitude"] = filt.update_attitude(attitude)
            if gnss is not None:
                updates["gnss"] = filt.update_gnss(gnss, scale=self._gnss_scale(filt.position))
        self.last_updates[agent] = updates
        return filt.cam_from_world, filt.prior_sigmas()

    def fuse(self, agent: str, estimate: PoseEstimate) -> Update | None:
        """Fuse a successful visual fix into ``agent``'s filter (None when there was none)."""
        if not estimate.success:
            return None
        upd = self.filters[agent].update_pose(estimate.cam_from_world, estimate.covariance)
        self.last_updates[agent]["pose"] = upd
        return upd

    def _gnss_scale(self, position: np.ndarray) -> float:
        factor = getattr(self._sensor, "multipath_factor", None)
        if factor is None:
            return 1.0
        clearance = float(self._obstacles.distances(np.asarray(position, dtype=np.float64)[None])[0])
        return float(factor(clearance))

    def _motion(self, filt: PoseFilter, action: Any) -> tuple[np.ndarray, np.ndarray]:
        """World-frame displacement and rotation vector of ``action`` from the filtered pose."""
        a = np.zeros(len(ACTION_COMPONENTS)) if action is None else np.asarray(action, dtype=np.float64)
        a = np.clip(a, -1.0, 1.0)
        position, (_, pitch, yaw) = attitude_of(filt.world_from_cam)
        now = UavState.make(position, yaw, pitch)
        nxt = step_uav(now, a, self._limits, self._dt)
        R0, R1 = now.world_from_cam[:3, :3], nxt.world_from_cam[:3, :3]
        return nxt.xyz - now.xyz, so3_log(R1 @ R0.T)
