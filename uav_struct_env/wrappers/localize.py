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
warm_started). Nothing
it adds to the observation needs ground truth; the errors in ``info`` do (simulation only).

The info holds numbers only, the same for the same seed (what tensor-based RL libraries and
``pettingzoo.test.parallel_seed_test`` need): a quantity without a value (the error of a failed
estimate) is :data:`UNDEFINED` (-1.0), never NaN; ``failure_code`` is 0 on success, else
``1 + list(localization.FailureCode).index(code)`` (:func:`failure_code_number`). The wall-clock
latency and the failure message, which are not, are in :attr:`last_frames` (``.latency_s``,
``.estimate.failure_reason``). Its :attr:`last_frames` also feed the layout and reward wrappers.

With ``temporal=True`` each agent's pose is filtered over time (:mod:`~uav_struct_env.wrappers.temporal`):
the filter's prediction and sigmas are each frame's association prior, ``pose`` / ``pose_std``
are the filtered pose and its sigmas at every step (also when the frame fails), ``localized``
is 1 when the frame's fix was accepted by the filter's gate, and ``info["localization"]`` gains
``filtered_translation_error_m``, ``filtered_rotation_error_deg``, ``filtered_position_std_m``,
``fix_accepted``, ``fix_nis`` (UNDEFINED without a fix) and ``gnss_fix``; its
``prior_translation_error_m`` is then the prediction's.

With ``warm_start=True`` each agent's robust association first tries the pose predicted from its
previous successful estimate and the action it was commanded (the env's kinematics,
:func:`~uav_struct_env.sim.uav.step_uav`, applied to the estimate: what a real UAV's flight
controller knows), and searches hypotheses only when that prediction does not explain the whole
frame (:mod:`localization.associate`, *Warm start*). ``info["localization"]["warm_started"]`` says
which frames it answered. The training configurations use it (the same poses at a fraction of
the cost: docs/benchmarks.md).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
from gymnasium import spaces

from localization.failure import FailureCode
from localization.geometry.transforms import camera_center, invert, quat_wxyz_from_matrix
from localization.metrics import pose_errors
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.uav import UavState, step_uav
from uav_struct_env.stack import FrameLocalization, LocalizationStack, StackSpec, build_stack
from uav_struct_env.wrappers.base import ParallelWrapper
from uav_struct_env.wrappers.temporal import PoseTracks

__all__ = ["POSE_BOUND", "STD_BOUND", "UNDEFINED", "LocalizePoses", "failure_code_number", "find_wrapper"]

#: The info value of a quantity that has none (the error of a failed estimate), instead of NaN.
UNDEFINED = -1.0


def _number(x: float) -> float:
    x = float(x)
    return x if math.isfinite(x) else UNDEFINED


def failure_code_number(code: FailureCode | None) -> int:
    """0 for success (None), else ``1 + list(FailureCode).index(code)``."""
    return 0 if code is None else 1 + list(FailureCode).index(FailureCode(code))

POSE_BOUND = 1.0e4
STD_BOUND = 100.0


def find_wrapper(env: Any, cls: type) -> Any:
    """The outermost wrapper of type ``cls`` in ``env``'s wrapper chain, or None."""
    while env is not None:
        if isinstance(env, cls):
            return env
        env = env.__dict__.get("env")
    return None


class LocalizePoses(ParallelWrapper):
    """Add ``pose``, ``pose_std``, ``localized`` and ``info["localization"]`` (module docstring).

    Args:
        env: a ``uav_struct_v0`` parallel env (or a wrapper of one). With the projection
            detector its config's ``landmark_sets`` must include the spec's landmark set.
        spec: the :class:`~uav_struct_env.stack.StackSpec` (default ``StackSpec()``);
            keyword arguments override its fields.
        temporal: filter each agent's pose over time (module docstring).
        filter_noise: with ``temporal``, the filters' :class:`~localization.temporal.FilterNoise`
            (default: matched to the env's sensor model).
        warm_start: start each frame's robust association from the pose predicted by the
            previous estimate and the commanded action (module docstring).
        **fields: :class:`~uav_struct_env.stack.StackSpec` fields.

    Raises:
        ConfigError: for a bad spec, an env that is not ``uav_struct_v0`` or one that does not
            provide the landmark truth the projection detector needs.
    """

    def __init__(
        self,
        env: Any,
        spec: StackSpec | None = None,
        *,
        temporal: bool = False,
        filter_noise: Any = None,
        warm_start: bool = False,
        **fields: Any,
    ) -> None:
        super().__init__(env)
        spec = StackSpec(**fields) if spec is None else dataclasses.replace(spec, **fields)
        base = env.unwrapped
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
        self.spec = spec
        self.landmarks = landmarks
        w, h = config.image_size
        self.image_size = (int(w), int(h))
        self.K = np.asarray(base.camera.K, dtype=np.float64)
        model = base.site.landmarks(landmarks)
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
            )
        except ConfigError as e:
            if spec.structural and len(model.xyz) < 4:
                raise ConfigError(f"{e} (stage {config.stage!r})") from None
            raise
        self.model_ids = np.asarray(model.ids, dtype=np.int64)
        inner = env.observation_space(env.possible_agents[0])
        keys = dict(inner.spaces)
        keys["pose"] = spaces.Box(-POSE_BOUND, POSE_BOUND, (7,), np.float32)
        keys["pose_std"] = spaces.Box(0.0, STD_BOUND, (6,), np.float32)
        keys["localized"] = spaces.Box(0.0, 1.0, (1,), np.float32)
        self._observation_space = spaces.Dict(keys)
        self.last_frames: dict[str, FrameLocalization] = {}
        self.tracks = PoseTracks(base, filter_noise) if temporal else None
        if not isinstance(warm_start, (bool, np.bool_)):
            raise ConfigError(f"warm_start must be True or False, got {warm_start!r}")
        self.warm_start = bool(warm_start)
        self._limits, self._dt = config.limits, float(config.control_period)
        #: per agent, the last successful estimate's ``world_from_cam`` (warm start), then the
        #: pose it predicts for the coming frame (``cam_from_world``)
        self._estimated: dict[str, np.ndarray] = {}
        self._predicted: dict[str, np.ndarray] = {}

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
        self._estimated, self._predicted = {}, {}
        if self.tracks is not None:
            self.tracks.reset()
        for agent in obs:
            self._localize(agent, obs[agent], infos[agent])
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env and localize every agent that produced an observation."""
        if self.tracks is not None:
            self.tracks.command(actions)
        self._predicted = {a: self._predict(T, actions.get(a)) for a, T in self._estimated.items()}
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        for agent in obs:
            self._localize(agent, obs[agent], infos[agent])
        return obs, rewards, terminations, truncations, infos

    def _predict(self, world_from_cam: np.ndarray, action: Any) -> np.ndarray:
        """``cam_from_world`` after ``action`` (None: hover, as the env) from an estimated pose."""
        a = np.zeros(5)
        if action is not None:  # clipped to [-1, 1] as the env does (np.clip's result, cheaper)
            a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), -1.0), 1.0)
        state = step_uav(UavState.from_world_from_cam(world_from_cam), a, self._limits, self._dt)
        return invert(state.world_from_cam)

    def _localize(self, agent: str, obs: dict, info: dict) -> FrameLocalization:
        gt = invert(info["world_from_cam"])
        prior = invert(info["prior_world_from_cam"])
        truth_sets = info.get("landmarks", {})
        truth = truth_sets.get(self.landmarks)
        sigmas = None
        if self.tracks is not None:
            prior, sigmas = self.tracks.prior(agent, obs, info)
        frame = self.stack.localize(
            obs.get("image"), truth_sets, prior, gt, prior_sigmas=sigmas,
            warm_start=self._predicted.get(agent),
        )
        est = frame.estimate
        world_from_cam = invert(est.cam_from_world)
        if self.warm_start and est.success:
            self._estimated[agent] = world_from_cam
        else:
            self._estimated.pop(agent, None)
        std = est.pose_std if est.success else self.stack.prior_std
        localized = est.success
        if self.tracks is not None:
            fix = self.tracks.fuse(agent, est)
            localized = fix is not None and fix.accepted
            filt = self.tracks.filters[agent]
            world_from_cam, std = filt.world_from_cam, filt.pose_std
        pose = np.concatenate([world_from_cam[:3, 3], quat_wxyz_from_matrix(world_from_cam[:3, :3])])
        std = np.where(np.isfinite(std), std, STD_BOUND)
        # np.minimum(np.maximum(...)): np.clip's result at half its cost
        obs["pose"] = np.minimum(np.maximum(pose, -POSE_BOUND), POSE_BOUND).astype(np.float32)
        obs["pose_std"] = np.minimum(np.maximum(std, 0.0), STD_BOUND).astype(np.float32)
        obs["localized"] = np.array([1.0 if localized else 0.0], np.float32)
        cov = est.covariance  # the position block's trace, summed as np.trace does (NaN: undefined)
        trace = float(cov[0, 0] + cov[1, 1] + cov[2, 2])
        position_std = math.sqrt(trace) if est.success and trace >= 0.0 else UNDEFINED
        s = frame.scores
        info["localization"] = {
            "success": bool(est.success),
            "translation_error_m": _number(frame.translation_error_m),
            "rotation_error_deg": _number(frame.rotation_error_deg),
            "prior_translation_error_m": _number(frame.prior_translation_error_m),
            "n_correspondences": int(est.n_inliers),
            "n_detections": len(frame.detections),
            "n_visible": int(np.count_nonzero(truth["visible"])) if truth is not None else -1,
            "association_precision": _number(s.precision),
            "association_recall": _number(s.recall),
            "association_f1": _number(s.f1),
            "reprojection_rmse_px": _number(est.reprojection_rmse_px),
            "position_std_m": _number(position_std),
            "failure_code": 0 if est.success else failure_code_number(
                est.failure_code or FailureCode.UNKNOWN),
            "warm_started": bool(est.warm_started),
        }
        if self.tracks is not None:
            info["localization"].update(self._temporal_info(agent, info, gt))
        self.last_frames[agent] = frame
        return frame

    def _temporal_info(self, agent: str, info: dict, gt: np.ndarray) -> dict[str, Any]:
        """The filter's keys of ``info["localization"]`` (module docstring)."""
        filt = self.tracks.filters[agent]
        t_err, r_err = pose_errors(filt.cam_from_world, gt)
        fix = self.tracks.last_updates[agent].get("pose")
        return {
            "filtered_translation_error_m": _number(t_err),
            "filtered_rotation_error_deg": _number(r_err),
            "filtered_position_std_m": _number(np.sqrt(np.sum(filt.pose_std[:3] ** 2))),
            "fix_accepted": bool(fix is not None and fix.accepted),
            "fix_nis": UNDEFINED if fix is None else _number(fix.nis),
            "gnss_fix": bool(info.get("gnss_fix", True)),
        }

    def estimated_position(self, agent: str) -> np.ndarray:
        """(3,) the last estimated camera centre of ``agent`` (filtered with ``temporal``).

        Without ``temporal``, the prior's when localization failed.
        """
        if self.tracks is not None:
            return self.tracks.filters[agent].position.copy()
        return camera_center(self.last_frames[agent].estimate.cam_from_world)
