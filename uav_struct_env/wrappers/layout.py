"""``LayoutObservation``: landmark-layout features as their own observation key, ``layout``.

``layout`` float32 (10,) (:data:`LAYOUT_COMPONENTS`), from the last localization of a
:class:`~uav_struct_env.wrappers.localize.LocalizePoses` below it and the BIM:

0. ``inlier_frac``: correspondences of the pose / M (0 when localization failed);
1. ``detected_frac``: detections / M (capped at 2);
2. 3. ``centroid_u``, ``centroid_v``: the detections' centroid scaled to [-1, 1];
4. 5. ``spread_u``, ``spread_v``: their std scaled by the half image size (zeros when nothing is
   detected);
6. 7. 8. ``site_dir_x/y/z``: unit direction to the site centre in the camera frame (x right,
   y down, z forward);
9. ``site_distance_hm``: its distance in hectometres (capped at 2);

the last four from the estimated pose (the prior's where localization failed). None of them
needs ground truth, so a policy trained on them can fly a real UAV. With ``privileged=True``
component 0 is instead the simulator's true visible fraction, ``visible_frac`` (visible
landmarks / M; :data:`PRIVILEGED_LAYOUT_COMPONENTS`): privileged information, asked for by name.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from numba import njit

from uav_struct_env.errors import ConfigError
from uav_struct_env.stack import FrameLocalization
from uav_struct_env.wrappers.base import ParallelWrapper, find_wrapper
from uav_struct_env.wrappers.localize import LocalizePoses

__all__ = ["LAYOUT_COMPONENTS", "PRIVILEGED_LAYOUT_COMPONENTS", "LayoutObservation"]

_SHARED = (
    "detected_frac",
    "centroid_u",
    "centroid_v",
    "spread_u",
    "spread_v",
    "site_dir_x",
    "site_dir_y",
    "site_dir_z",
    "site_distance_hm",
)
#: The default (deployable) layout features, in order.
LAYOUT_COMPONENTS = ("inlier_frac", *_SHARED)
#: The layout with ``privileged=True``: component 0 is the true visible fraction.
PRIVILEGED_LAYOUT_COMPONENTS = ("visible_frac", *_SHARED)


class LayoutObservation(ParallelWrapper):
    """Add the ``layout`` observation (module docstring).

    Args:
        env: a wrapper chain that contains a :class:`LocalizePoses`.
        privileged: put the simulator's true visible fraction in component 0 (needs the env's
            landmark truth; a real UAV does not have it).

    Raises:
        ConfigError: without a :class:`LocalizePoses` below.
    """

    def __init__(self, env: Any, privileged: bool = False) -> None:
        super().__init__(env)
        loc = find_wrapper(env, LocalizePoses)
        if loc is None:
            raise ConfigError("LayoutObservation needs a LocalizePoses wrapper below it")
        self._loc = loc
        self.privileged = bool(privileged)
        self.components = PRIVILEGED_LAYOUT_COMPONENTS if self.privileged else LAYOUT_COMPONENTS
        self._site_center = np.asarray(env.unwrapped.site.center, dtype=np.float64).reshape(3)
        keys = dict(env.observation_space(env.possible_agents[0]).spaces)
        keys["layout"] = spaces.Box(-1.0, 2.0, (len(self.components),), np.float32)
        self._observation_space = spaces.Dict(keys)

    def observation_space(self, agent: str) -> spaces.Dict:
        """The cached observation space shared by all agents: the env's plus ``layout``."""
        self.env.observation_space(agent)
        return self._observation_space

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env and add every agent's layout."""
        obs, infos = self.env.reset(seed=seed, options=options)
        self._add(obs, infos)
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env and add the layout of every agent that produced an observation."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        self._add(obs, infos)
        return obs, rewards, terminations, truncations, infos

    def _add(self, obs: dict, infos: dict) -> None:
        for agent in obs:
            truth = infos[agent].get("landmarks", {}).get(self._loc.landmarks) if self.privileged else None
            obs[agent]["layout"] = self.features(self._loc.last_frames[agent], truth)

    def features(self, frame: FrameLocalization, truth: dict | None = None) -> np.ndarray:
        """(10,) float32 layout features of one frame (``truth``: privileged component 0)."""
        m = max(len(self._loc.model_ids), 1)
        w, h = self._loc.image_size
        out = np.zeros(len(self.components), np.float32)
        cam_from_world = frame.estimate.cam_from_world
        to_site = cam_from_world[:3, :3] @ self._site_center + cam_from_world[:3, 3]
        dist = float(np.linalg.norm(to_site))
        out[6:9] = to_site / dist if dist > 0 else 0.0
        out[9] = min(dist / 100.0, 2.0)
        if self.privileged:
            out[0] = float(np.sum(truth["visible"])) / m if truth is not None else 0.0
        else:
            out[0] = min(frame.estimate.n_inliers / m, 2.0) if frame.estimate.success else 0.0
        uv = frame.detections.uv
        out[1] = min(len(uv) / m, 2.0)
        if len(uv):
            out[2:6] = _centroid_spread(uv, w / 2.0, h / 2.0)
        return out


@njit(cache=True, nogil=True)
def _centroid_spread(uv: np.ndarray, half_w: float, half_h: float) -> np.ndarray:
    """(4,) the detections' centroid in [-1, 1] and their std over the half image size (<= 2).

    numpy's ``uv.mean(axis=0)`` and ``uv.std(axis=0)`` (a sum down the rows, in order, then the
    division; the squared deviations from that mean likewise) clipped as the components are, in
    one compiled loop, since it runs every agent-step: the same numbers as numpy's
    (tests/wrappers/test_localization_wrapper.py compares them bit for bit).
    """
    n = uv.shape[0]
    out = np.empty(4)
    for j, half in ((0, half_w), (1, half_h)):
        s = 0.0
        for i in range(n):
            s += uv[i, j]
        mean = s / n
        q = 0.0
        for i in range(n):
            d = uv[i, j] - mean
            q += d * d
        out[j] = min(max((mean - (half - 0.5)) / half, -1.0), 1.0)
        out[2 + j] = min(max(np.sqrt(q / n) / half, 0.0), 2.0)
    return out
