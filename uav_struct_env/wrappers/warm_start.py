"""``WarmStart``: start each frame's robust association from the pose the agent should be at.

Each step, before the env steps, the wrapper predicts every agent's coming pose from its previous
successful estimate and the action it was commanded (the env's kinematics,
:func:`~uav_struct_env.sim.uav.step_uav`, applied to the estimate: what a real UAV's flight
controller knows) and hands it to the :class:`~uav_struct_env.wrappers.localize.LocalizePoses`
below as the frame's warm start. The robust association tries that pose first and searches
hypotheses only when it does not explain the whole frame (:mod:`localization.associate`, *Warm
start*); ``info["localization"]["warm_started"]`` says which frames it answered. The training
configurations use it: the same poses for less search (docs/benchmarks.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from localization.geometry.transforms import invert
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.uav import UavState, step_uav
from uav_struct_env.wrappers.base import ParallelWrapper, find_wrapper
from uav_struct_env.wrappers.localize import LocalizePoses

__all__ = ["WarmStart"]


class WarmStart(ParallelWrapper):
    """Warm-start every agent's next frame from its last estimate and action (module docstring).

    Args:
        env: a wrapper chain that contains a :class:`~uav_struct_env.wrappers.localize.LocalizePoses`.

    Raises:
        ConfigError: without a LocalizePoses below.
    """

    def __init__(self, env: Any) -> None:
        super().__init__(env)
        loc = find_wrapper(env, LocalizePoses)
        if loc is None:
            raise ConfigError("WarmStart needs a LocalizePoses wrapper below it")
        self._loc = loc
        config = env.unwrapped.config
        self._limits, self._dt = config.limits, float(config.control_period)
        #: per agent, the last successful estimate's ``world_from_cam``
        self._estimated: dict[str, np.ndarray] = {}

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env (no warm start for a first frame) and keep every successful estimate."""
        self._estimated = {}
        self._loc.warm_starts = {}
        obs, infos = self.env.reset(seed=seed, options=options)
        self._keep(obs)
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Predict every estimated agent's pose after its action, then step the env."""
        self._loc.warm_starts = {a: self._predict(T, actions.get(a)) for a, T in self._estimated.items()}
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        self._keep(obs)
        return obs, rewards, terminations, truncations, infos

    def _keep(self, obs: dict) -> None:
        for agent in obs:
            est = self._loc.last_frames[agent].estimate
            if est.success:
                self._estimated[agent] = invert(est.cam_from_world)
            else:
                self._estimated.pop(agent, None)

    def _predict(self, world_from_cam: np.ndarray, action: Any) -> np.ndarray:
        """``cam_from_world`` after ``action`` (None: hover, as the env) from an estimated pose."""
        a = np.zeros(5)
        if action is not None:  # clipped to [-1, 1] as the env does (np.clip's result, cheaper)
            a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), -1.0), 1.0)
        state = step_uav(UavState.from_world_from_cam(world_from_cam), a, self._limits, self._dt)
        return invert(state.world_from_cam)
