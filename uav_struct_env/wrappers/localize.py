"""``LocalizePoses``: localize every agent each reset and step; add its pose and quality.

Each agent is localized from its own frame and onboard prior with a localization stack
(:class:`~uav_struct_env.stack.StackSpec`, :func:`~uav_struct_env.stack.build_stack`), and the
wrapper adds to that agent's observation

* ``pose``        float32 (7,): estimated camera position xyz (project frame, m) + orientation
  quaternion wxyz of ``world_from_cam``; the prior's pose where localization failed;
* ``pose_std``    float32 (6,): standard deviations from the estimate's covariance (camera
  centre x, y, z in m, rotation in rad); the localizer's prior sigmas where it failed;
* ``localized``   float32 (1,): 1.0 if localization succeeded, else 0.0;

and to its info ``localization`` (success, translation_error_m, rotation_error_deg,
prior_translation_error_m, n_correspondences, n_detections, n_visible, association_precision,
association_recall, association_f1, reprojection_rmse_px, position_std_m, failure_code,
warm_started). Nothing it adds to the observation needs ground truth; the errors in ``info`` do
(simulation only).

The info holds numbers only, the same for the same seed (what tensor-based RL libraries and
``pettingzoo.test.parallel_seed_test`` need): a quantity without a value (the error of a failed
estimate) is :data:`UNDEFINED` (-1.0), never NaN (:func:`info_number`); ``failure_code`` is 0 on
success, else ``1 + list(localization.FailureCode).index(code)`` (:func:`failure_code_number`).
The wall-clock latency and the failure message, which are not, are in :attr:`last_frames`
(``.latency_s``, ``.estimate.failure_reason``). Its :attr:`last_frames` also feed the layout and
reward wrappers.

Two wrappers above it change what each frame starts from, one job each:
:class:`~uav_struct_env.wrappers.temporal.FilterPoses` gives the pose filter's prediction as
the frame's prior (:attr:`LocalizePoses.prior_source`) and
:class:`~uav_struct_env.wrappers.warm_start.WarmStart` the pose predicted from the previous
estimate and the commanded action as its warm start (:attr:`LocalizePoses.warm_starts`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces

from localization import PriorSigmas
from localization.failure import FailureCode
from localization.geometry.transforms import camera_center, invert, quat_wxyz_from_matrix
from uav_struct_env.errors import ConfigError
from uav_struct_env.stack import FrameLocalization, LocalizationStack, StackSpec, build_stack
from uav_struct_env.wrappers.base import ParallelWrapper

__all__ = [
    "POSE_BOUND",
    "STD_BOUND",
    "UNDEFINED",
    "LocalizePoses",
    "PriorSource",
    "failure_code_number",
    "info_number",
    "set_pose_keys",
]

#: The info value of a quantity that has none (the error of a failed estimate), instead of NaN.
UNDEFINED = -1.0
POSE_BOUND = 1.0e4
STD_BOUND = 100.0

#: ``(agent, obs, info) -> (cam_from_world, PriorSigmas)``: a frame's prior from elsewhere than
#: the env's onboard prior (a pose filter's prediction).
PriorSource = Callable[[str, dict, dict], tuple[np.ndarray, PriorSigmas]]


def info_number(x: float) -> float:
    """``x`` as a float, :data:`UNDEFINED` when it is not finite (NaN, inf)."""
    x = float(x)
    return x if math.isfinite(x) else UNDEFINED


def failure_code_number(code: FailureCode | None) -> int:
    """0 for success (None), else ``1 + list(FailureCode).index(code)``."""
    return 0 if code is None else 1 + list(FailureCode).index(FailureCode(code))


def set_pose_keys(obs: dict, world_from_cam: np.ndarray, std: np.ndarray, localized: bool) -> None:
    """Write ``pose``, ``pose_std`` and ``localized`` into one agent's observation, bounded."""
    pose = np.concatenate([world_from_cam[:3, 3], quat_wxyz_from_matrix(world_from_cam[:3, :3])])
    std = np.where(np.isfinite(std), std, STD_BOUND)
    # np.minimum(np.maximum(...)): np.clip's result at half its cost
    obs["pose"] = np.minimum(np.maximum(pose, -POSE_BOUND), POSE_BOUND).astype(np.float32)
    obs["pose_std"] = np.minimum(np.maximum(std, 0.0), STD_BOUND).astype(np.float32)
    obs["localized"] = np.array([1.0 if localized else 0.0], np.float32)


def _check_env(base: Any, spec: StackSpec) -> Any:
    """``base``'s config, after checking that it can serve ``spec`` (see :class:`LocalizePoses`)."""
    config = getattr(base, "config", None)
    if config is None or not hasattr(base, "site") or not hasattr(base, "camera"):
        raise ConfigError(
            f"LocalizationWrapper needs a uav_struct_v0 environment (with .config, .site and "
            f".camera), got {type(base).__name__}"
        )
    landmarks = spec.landmarks
    if spec.detector == "projection" and landmarks not in config.landmark_sets:
        raise ConfigError(
            f"the wrapped env provides landmark truth for {config.landmark_sets}, but "
            f"landmarks={landmarks!r} needs it: build the env with "
            f"landmark_sets=({landmarks!r},) (the 'train' preset sets ()), e.g. "
            f"uav_struct_env.wrappers.make_localization_env(landmarks={landmarks!r})"
        )
    if not config.observe_image and (spec.detector != "projection" or not spec.structural):
        raise ConfigError(
            f"detector {spec.detector if spec.structural else 'aruco'!r} reads the image, but "
            "the env renders none (observe_image=False): use detector='projection' or an "
            "env with observe_image=True"
        )
    return config


class LocalizePoses(ParallelWrapper):
    """Add ``pose``, ``pose_std``, ``localized`` and ``info["localization"]`` (module docstring).

    Args:
        env: a ``uav_struct_v0`` parallel env (or a wrapper of one). With the projection
            detector its config's ``landmark_sets`` must include the spec's landmark set.
        spec: the :class:`~uav_struct_env.stack.StackSpec` (default ``StackSpec()``);
            keyword arguments override its fields.
        **fields: :class:`~uav_struct_env.stack.StackSpec` fields.

    Attributes:
        prior_source: where each frame's prior comes from (:data:`PriorSource`); None: the
            env's onboard prior. Set by a :class:`~uav_struct_env.wrappers.temporal.FilterPoses`
            above.
        warm_starts: per agent, the ``cam_from_world`` predicted for its coming frame, tried
            before the robust association's search; kept up to date by a
            :class:`~uav_struct_env.wrappers.warm_start.WarmStart` above (empty: none).

    Raises:
        ConfigError: for a bad spec, an env that is not ``uav_struct_v0`` or one that does not
            provide the landmark truth the projection detector needs.
    """

    def __init__(self, env: Any, spec: StackSpec | None = None, **fields: Any) -> None:
        super().__init__(env)
        spec = StackSpec(**fields) if spec is None else dataclasses.replace(spec, **fields)
        base = env.unwrapped
        config = _check_env(base, spec)
        self.spec = spec
        self.landmarks = spec.landmarks
        w, h = config.image_size
        self.image_size = (int(w), int(h))
        self.K = np.asarray(base.camera.K, dtype=np.float64)
        model = base.site.landmarks(self.landmarks)
        self._rng = np.random.default_rng()
        try:
            self.stack: LocalizationStack = build_stack(
                spec,
                self.K,
                self.image_size,
                model_xyz=model.xyz,
                model_ids=model.ids,
                markers=base.site.markers,
                rng=self._rng,
                distortion=np.asarray(config.camera.distortion, dtype=np.float64),
                site=base.site,
            )
        except ConfigError as e:
            if spec.structural and len(model.xyz) < 4:
                raise ConfigError(f"{e} (stage {config.stage!r})") from None
            raise
        self.model_ids = np.asarray(model.ids, dtype=np.int64)
        keys = dict(env.observation_space(env.possible_agents[0]).spaces)
        keys["pose"] = spaces.Box(-POSE_BOUND, POSE_BOUND, (7,), np.float32)
        keys["pose_std"] = spaces.Box(0.0, STD_BOUND, (6,), np.float32)
        keys["localized"] = spaces.Box(0.0, 1.0, (1,), np.float32)
        self._observation_space = spaces.Dict(keys)
        self.last_frames: dict[str, FrameLocalization] = {}
        self.prior_source: PriorSource | None = None
        self.warm_starts: dict[str, np.ndarray] = {}

    @property
    def localizer(self) -> Any:
        """The stack's :class:`localization.Localizer` (None for ArUco)."""
        return self.stack.localizer

    def observation_space(self, agent: str) -> spaces.Dict:
        """The cached observation space shared by all agents: the env's plus the pose keys."""
        self.env.observation_space(agent)  # validates the agent name
        return self._observation_space

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env and localize every agent; ``seed`` also seeds the detector."""
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), 0x10CA1])
            self.stack.seed(self._rng)
        obs, infos = self.env.reset(seed=seed, options=options)
        self.last_frames = {}
        for agent in obs:
            self._localize(agent, obs[agent], infos[agent])
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env and localize every agent that produced an observation."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        for agent in obs:
            self._localize(agent, obs[agent], infos[agent])
        return obs, rewards, terminations, truncations, infos

    def _localize(self, agent: str, obs: dict, info: dict) -> FrameLocalization:
        gt = invert(info["world_from_cam"])
        prior = invert(info["prior_world_from_cam"])
        truth_sets = info.get("landmarks", {})
        sigmas = None
        if self.prior_source is not None:
            prior, sigmas = self.prior_source(agent, obs, info)
        frame = self.stack.localize(
            obs.get("image"), truth_sets, prior, gt, prior_sigmas=sigmas,
            warm_start=self.warm_starts.get(agent),
        )
        est = frame.estimate
        std = est.pose_std if est.success else self.stack.prior_std
        set_pose_keys(obs, invert(est.cam_from_world), std, est.success)
        info["localization"] = self._info(frame, truth_sets.get(self.landmarks))
        self.last_frames[agent] = frame
        return frame

    @staticmethod
    def _info(frame: FrameLocalization, truth: dict | None) -> dict[str, Any]:
        """``info["localization"]`` of one frame (module docstring)."""
        est = frame.estimate
        cov = est.covariance  # the position block's trace, summed as np.trace does (NaN: undefined)
        trace = float(cov[0, 0] + cov[1, 1] + cov[2, 2])
        position_std = math.sqrt(trace) if est.success and trace >= 0.0 else UNDEFINED
        s = frame.scores
        return {
            "success": bool(est.success),
            "translation_error_m": info_number(frame.translation_error_m),
            "rotation_error_deg": info_number(frame.rotation_error_deg),
            "prior_translation_error_m": info_number(frame.prior_translation_error_m),
            "n_correspondences": int(est.n_inliers),
            "n_detections": len(frame.detections),
            "n_visible": int(np.count_nonzero(truth["visible"])) if truth is not None else -1,
            "association_precision": info_number(s.precision),
            "association_recall": info_number(s.recall),
            "association_f1": info_number(s.f1),
            "reprojection_rmse_px": info_number(est.reprojection_rmse_px),
            "position_std_m": info_number(position_std),
            "failure_code": 0 if est.success else failure_code_number(
                est.failure_code or FailureCode.UNKNOWN),
            "warm_started": bool(est.warm_started),
        }

    def estimated_position(self, agent: str) -> np.ndarray:
        """(3,) the last estimated camera centre of ``agent`` (the prior's when localization failed)."""
        return camera_center(self.last_frames[agent].estimate.cam_from_world)
