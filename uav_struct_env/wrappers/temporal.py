"""``FilterPoses``: each agent's pose filtered over time, one :class:`~localization.temporal.PoseFilter` each.

:class:`FilterPoses` wraps a :class:`~uav_struct_env.wrappers.localize.LocalizePoses` (directly
or through other wrappers) and keeps a :class:`PoseTracks`. Per agent and step it

1. predicts the filter over the control period with the agent's *commanded* motion: the action
   applied by :func:`~uav_struct_env.sim.uav.step_uav` to the filtered pose (heading and gimbal
   pitch from the estimate, never the truth), so a real UAV could do the same;
2. fuses the env's attitude reading and, when ``info["gnss_fix"]``, its GNSS reading, with the
   noise model the env's sensor model names (:func:`filter_noise_for`) and its multipath factor
   at the *estimated* clearance from the BIM;
3. gives the prediction and its sigmas as the association prior of the frame's localization
   (:attr:`LocalizePoses.prior_source <uav_struct_env.wrappers.localize.LocalizePoses>`);
4. fuses the frame's visual fix (chi-square gated).

Nothing here reads the ground truth but the errors it reports. ``pose`` / ``pose_std`` become
the filtered pose and its sigmas at every step (also when the frame fails), ``localized`` is 1
when the frame's fix was accepted by the filter's gate, and ``info["localization"]`` gains
``filtered_translation_error_m``, ``filtered_rotation_error_deg``, ``filtered_position_std_m``,
``fix_accepted``, ``fix_nis`` (UNDEFINED without a fix) and ``gnss_fix``; its
``prior_translation_error_m`` is then the prediction's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from localization import PoseEstimate, PriorSigmas
from localization.geometry.transforms import invert, so3_log
from localization.metrics import pose_errors
from localization.temporal import FilterNoise, PoseFilter, Update, attitude_of
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.uav import ACTION_COMPONENTS, Obstacles, UavState, step_uav
from uav_struct_env.wrappers.base import ParallelWrapper, find_wrapper
from uav_struct_env.wrappers.localize import UNDEFINED, LocalizePoses, info_number, set_pose_keys

__all__ = ["FilterPoses", "PoseTracks", "filter_noise_for"]


def filter_noise_for(sensor: Any) -> FilterNoise:
    """The :class:`~localization.temporal.FilterNoise` an env sensor model names.

    The model's own ``filter_noise()`` (:mod:`uav_struct_env.sim.sensors`); a model object
    without one gets the filter's defaults (those of ``gnss_ins``).
    """
    own = getattr(sensor, "filter_noise", None)
    return own() if callable(own) else FilterNoise()


class FilterPoses(ParallelWrapper):
    """Filter every agent's pose over time (module docstring).

    Args:
        env: a wrapper chain that contains a :class:`~uav_struct_env.wrappers.localize.LocalizePoses`.
        noise: the filters' :class:`~localization.temporal.FilterNoise` (default: the one the
            env's sensor model names, :func:`filter_noise_for`).

    Raises:
        ConfigError: without a LocalizePoses below, with a LocalizePoses whose prior already
            comes from another filter, or if ``noise`` is not a FilterNoise.
    """

    def __init__(self, env: Any, noise: FilterNoise | None = None) -> None:
        super().__init__(env)
        loc = find_wrapper(env, LocalizePoses)
        if loc is None:
            raise ConfigError("FilterPoses needs a LocalizePoses wrapper below it")
        if loc.prior_source is not None:
            raise ConfigError("the LocalizePoses below already takes its prior from another FilterPoses")
        self.tracks = PoseTracks(env.unwrapped, noise)
        self._loc = loc
        loc.prior_source = self.tracks.prior

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Forget every filter, reset the env (localizing from the first readings) and fuse."""
        self.tracks.reset()
        obs, infos = self.env.reset(seed=seed, options=options)
        self._fuse(obs, infos)
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env with the actions recorded for the prediction, then fuse every fix."""
        self.tracks.command(actions)
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        self._fuse(obs, infos)
        return obs, rewards, terminations, truncations, infos

    def _fuse(self, obs: dict, infos: dict) -> None:
        for agent in obs:
            info = infos[agent]
            fix = self.tracks.fuse(agent, self._loc.last_frames[agent].estimate)
            filt = self.tracks.filters[agent]
            set_pose_keys(obs[agent], filt.world_from_cam, filt.pose_std, fix is not None and fix.accepted)
            info["localization"].update(self._info(agent, info))

    def _info(self, agent: str, info: dict) -> dict[str, Any]:
        """The filter's keys of ``info["localization"]`` (module docstring)."""
        filt = self.tracks.filters[agent]
        t_err, r_err = pose_errors(filt.cam_from_world, invert(info["world_from_cam"]))
        fix = self.tracks.last_updates[agent].get("pose")
        return {
            "filtered_translation_error_m": info_number(t_err),
            "filtered_rotation_error_deg": info_number(r_err),
            "filtered_position_std_m": info_number(np.sqrt(np.sum(filt.pose_std[:3] ** 2))),
            "fix_accepted": bool(fix is not None and fix.accepted),
            "fix_nis": UNDEFINED if fix is None else info_number(fix.nis),
            "gnss_fix": bool(info.get("gnss_fix", True)),
        }

    def estimated_position(self, agent: str) -> np.ndarray:
        """(3,) the filtered camera centre of ``agent``."""
        return self.tracks.filters[agent].position.copy()


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
