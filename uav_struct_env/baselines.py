"""Scripted viewpoint policies to compare trained ones with: random, hold, orbit and greedy-CRB.

Each policy is a callable ``policy(obs, env) -> {agent: action (5,) float32}`` over the live
agents' observations of a :class:`~uav_struct_env.wrappers.LocalizationWrapper`-wrapped env (the
training configurations of :mod:`uav_struct_env.wrappers.configs`). None reads the simulator's
truth: they act on the wrapper's estimated pose (``obs["pose"]``, the onboard prior where the
localization failed) and on the BIM, as a deployed policy would. Where the configuration shows the
policy no pose (``pixels``: camera, GNSS and attitude only), they read the same pose from the
wrapper's localization layer (:func:`estimated_pose`): a scripted policy needs a pose to act on.

* ``random``: uniform actions (seeded);
* ``hold``: hover at the starting viewpoint;
* ``orbit``: fly sideways around the building, turning towards its centre;
* ``greedy``: each step, the action of a fixed candidate set whose predicted next viewpoint has
  the lowest Cramér-Rao bound of its own position (:func:`localization.metrics.cramer_rao_bound`
  of the landmarks predicted in frame, at the wrapper's pixel noise). The prediction flies the
  kinematic model (:func:`uav_struct_env.sim.uav.step_uav`) from the estimated pose and ignores
  occlusion; candidates that would leave the geofence or come within ``clearance`` (10 m) of
  the structure are skipped. Where no candidate sees at least ``min_landmarks`` landmarks it turns
  towards the building and approaches (the orbit policy's heading law).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization.geometry.transforms import invert, matrix_from_quat_wxyz, quat_wxyz_from_matrix
from localization.metrics import cramer_rao_bound
from uav_struct_env.sim.attitude import attitude_from_world_from_cam
from uav_struct_env.sim.uav import UavState, step_uav

__all__ = ["BASELINES", "GreedyCrbPolicy", "RandomPolicy", "estimated_pose", "hold_policy", "make_baseline",
           "orbit_policy"]

#: The scripted policies by name (see the module docstring).
BASELINES = ("random", "hold", "orbit", "greedy")


class RandomPolicy:
    """Uniform actions in [-1, 1]^5 from its own seeded generator."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def __call__(self, obs: dict[str, Any], env: Any) -> dict[str, NDArray[np.float32]]:
        """One uniform action per live agent."""
        return {a: self.rng.uniform(-1, 1, 5).astype(np.float32) for a in obs}


def hold_policy(obs: dict[str, Any], env: Any) -> dict[str, NDArray[np.float32]]:
    """Hover: the zero action for every agent."""
    return {a: np.zeros(5, np.float32) for a in obs}


def _turn_to(center: NDArray[np.float64], position: NDArray[np.float64], yaw: float, gain: float) -> float:
    """Yaw-rate command (in [-1, 1]) turning from ``yaw`` towards ``center``'s bearing."""
    want = math.atan2(center[1] - position[1], center[0] - position[0])
    err = (want - yaw + math.pi) % (2 * math.pi) - math.pi
    return float(np.clip(gain * err, -1.0, 1.0))


def orbit_policy(obs: dict[str, Any], env: Any, speed: float = 0.5, gain: float = 2.0):
    """Sideways at ``speed`` x the top speed, yaw towards the site centre from the estimated pose."""
    c = np.asarray(env.unwrapped.site.center, dtype=np.float64)
    out = {}
    for a, o in obs.items():
        p = np.asarray(estimated_pose(o, env, a)[:3], dtype=np.float64)
        turn = _turn_to(c, p, float(o["attitude"][2]), gain)
        out[a] = np.array([0.0, speed, 0.0, turn, 0.0], np.float32)
    return out


def _candidate_actions() -> NDArray[np.float64]:
    """Hover, each of the five commands at +-1 and +-0.5, and forward/back combined with a turn."""
    eye = np.eye(5)
    rows = [np.zeros(5)]
    for k in range(5):
        for s in (1.0, -1.0, 0.5, -0.5):
            rows.append(s * eye[k])
    for fwd in (1.0, -1.0):
        for turn in (0.5, -0.5):
            rows.append(np.array([fwd, 0.0, 0.0, turn, 0.0]))
    return np.array(rows)


class GreedyCrbPolicy:
    """One-step greedy minimisation of the predicted Cramér-Rao bound of each agent's own position.

    Args:
        env: the wrapped env (a LocalizationWrapper or a wrapper over one): the landmark set, K
            and pixel noise are the wrapper's, the BIM ``env.unwrapped.site``'s.
        clearance: skip candidates whose predicted camera centre comes within this distance (m)
            of the structure (default 10 m: the bound alone always pays to fly closer, into views
            where the prior's error moves projections by more than the layout's spacing and into
            the structure itself).
        min_landmarks: landmarks in frame for a candidate's bound to count.
        margin_px: a landmark counts as in frame this far inside the image border.
    """

    def __init__(
        self, env: Any, *, clearance: float | None = None, min_landmarks: int = 4, margin_px: float = 8.0
    ) -> None:
        base = env.unwrapped
        poses = _localize_poses(env)
        self.xyz = np.asarray(base.site.landmarks(poses.landmarks).xyz, dtype=np.float64)
        self.K = np.asarray(poses.K, dtype=np.float64)
        self.image_size = poses.image_size
        self.pixel_sigma = float(poses.spec.detector_sigma(self.image_size[0]))
        self.limits = base.config.limits
        self.dt = float(base.config.control_period)
        self.obstacles = base.obstacles
        self.geofence = base.geofence
        self.center = np.asarray(base.site.center, dtype=np.float64)
        self.clearance = 10.0 if clearance is None else float(clearance)
        self.min_landmarks = int(min_landmarks)
        self.margin_px = float(margin_px)
        self.candidates = _candidate_actions()

    def predicted_bound(self, state: UavState) -> float:
        """Position RMS bound (m) at ``state`` from the landmarks predicted in frame; inf if too few."""
        T = invert(state.world_from_cam)
        cam = self.xyz @ T[:3, :3].T + T[:3, 3]
        front = cam[:, 2] > 0.5
        uv = cam[front] @ self.K.T
        uv = uv[:, :2] / uv[:, 2:3]
        w, h = self.image_size
        m = self.margin_px
        inside = (uv[:, 0] >= m - 0.5) & (uv[:, 0] <= w - 0.5 - m) & (uv[:, 1] >= m - 0.5) & (
            uv[:, 1] <= h - 0.5 - m)
        pts = self.xyz[front][inside]
        if len(pts) < self.min_landmarks:
            return math.inf
        return cramer_rao_bound(pts, T, self.K, self.pixel_sigma).position_rms_m

    def _safe(self, state: UavState) -> bool:
        p = state.xyz
        if self.geofence.violation(p, self.center[:2]) is not None:
            return False
        return float(self.obstacles.distances(p[None])[0]) > self.clearance

    def action(self, pose: NDArray[np.floating]) -> NDArray[np.float32]:
        """The greedy action from an estimated pose (7,): camera centre and quaternion (w, x, y, z)."""
        world_from_cam = np.eye(4)
        world_from_cam[:3, :3] = matrix_from_quat_wxyz(np.asarray(pose[3:], dtype=np.float64))
        world_from_cam[:3, 3] = np.asarray(pose[:3], dtype=np.float64)
        position, attitude = attitude_from_world_from_cam(world_from_cam)
        state = UavState.make(position, float(attitude[2]), float(attitude[1]))
        best, best_bound = None, math.inf
        for a in self.candidates:  # in a fixed order: ties go to the first (hover)
            nxt = step_uav(state, a, self.limits, self.dt)
            if not self._safe(nxt):
                continue
            bound = self.predicted_bound(nxt)
            if bound < best_bound:
                best, best_bound = a, bound
        if best is None:  # nothing in view from any candidate: face the building, approach
            turn = _turn_to(self.center, position, state.yaw, 2.0)
            best = np.array([0.5 if abs(turn) < 0.5 else 0.0, 0.0, 0.0, turn, 0.0])
            if not self._safe(step_uav(state, best, self.limits, self.dt)):
                best = np.array([0.0, 0.0, 0.0, turn, 0.0])
        return np.asarray(best, dtype=np.float32)

    def __call__(self, obs: dict[str, Any], env: Any) -> dict[str, NDArray[np.float32]]:
        """The greedy action of every live agent from its estimated pose."""
        return {a: self.action(estimated_pose(o, env, a)) for a, o in obs.items()}


def estimated_pose(obs: dict[str, Any], env: Any, agent: str) -> NDArray[np.floating]:
    """(7,) ``agent``'s estimated pose: its observation's ``pose``, else the wrapper's last one.

    The wrapper's localization layer holds the pose it put in the observation before a
    configuration dropped it (``pixels``): camera centre and quaternion (w, x, y, z), the prior's
    where the localization failed.
    """
    if "pose" in obs:
        return obs["pose"]
    world_from_cam = invert(_localize_poses(env).last_frames[agent].estimate.cam_from_world)
    return np.concatenate([world_from_cam[:3, 3], quat_wxyz_from_matrix(world_from_cam[:3, :3])])


def _localize_poses(env: Any) -> Any:
    """The LocalizePoses layer of a wrapped env (the one holding the landmark set, K and spec)."""
    e = env
    while e is not None:
        poses = getattr(e, "poses", None)
        if poses is not None and hasattr(poses, "spec"):
            return poses
        e = getattr(e, "env", None)
    raise TypeError(
        f"the greedy baseline needs an env wrapped by LocalizationWrapper, got {type(env).__name__}"
    )


def make_baseline(name: str, env: Any, seed: int = 0) -> Any:
    """The scripted policy ``name`` (one of :data:`BASELINES`) for ``env``."""
    if name == "random":
        return RandomPolicy(seed)
    if name == "hold":
        return hold_policy
    if name == "orbit":
        return orbit_policy
    if name == "greedy":
        return GreedyCrbPolicy(env)
    raise ValueError(f"baseline must be one of {BASELINES}, got {name!r}")
