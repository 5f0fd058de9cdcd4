"""``LocalizationWrapper``: BIM-landmark localization of every UAV, its quality and a reward.

Each reset and step, every agent is localized from its own frame and onboard prior (detector ->
association with the BIM landmarks -> PnP, :func:`~uav_struct_env.wrappers.frame.localize_frame`)
and the wrapper adds to that agent's observation

* ``pose``        float32 (7,): estimated camera position xyz (project frame, m) + orientation
  quaternion wxyz of ``world_from_cam``; the prior's pose where localization failed;
* ``pose_std``    float32 (6,): standard deviations from the estimate's covariance (camera
  centre x, y, z in m, rotation in rad); the localizer's prior sigmas where it failed;
* ``localized``   float32 (1,): 1.0 if localization succeeded, else 0.0;
* ``layout``      float32 (10,): landmark-layout features (:data:`LAYOUT_COMPONENTS`): visible
  landmarks / M, detections / M, the detections' centroid (u, v) scaled to [-1, 1] and their
  spread (std of u, v) scaled by the half image size (zeros when nothing is detected), then the
  unit direction to the site centre in the camera frame (x right, y down, z forward) and its
  distance in hectometres, both from the estimated pose (the prior's where localization failed)
  and the BIM, so they need no ground truth;

and to its info ``localization`` (success, translation_error_m, rotation_error_deg,
prior_translation_error_m, n_correspondences, n_detections, n_visible, association_precision,
association_recall, association_f1, reprojection_rmse_px, position_std_m, latency_s,
failure_reason). With ``drop_image=True`` the image is removed from the observation after
localizing (state-only training).

Reward (per agent and step; ``info["reward_terms"]`` holds the terms, which sum to it):

* ``"error"`` (needs ground truth, simulation only): ``alive`` (+``alive_bonus``),
  ``translation`` (-min(translation error, ``error_cap``)), ``rotation``
  (-min(``rotation_weight`` x rotation error in deg, ``error_cap``)) when localized, else
  ``failure`` (-``failure_penalty``);
* ``"uncertainty"`` (deployable, no ground truth): ``alive``, ``uncertainty``
  (-min(predicted position RMS std = sqrt(trace of the covariance's position block), cap))
  when localized, else ``failure``;
* both: ``crash`` (-``crash_penalty``) when the agent is terminated (geofence or collision).

``alive_bonus`` defaults to ``failure_penalty`` so a failed step scores 0 and a good fix scores
close to ``alive_bonus``: every step is worth at least as much as ending the episode, so a
policy never learns to crash to stop a negative reward stream (with ``on_crash="all"`` a crash
ends everyone's episode). Set ``alive_bonus=0`` for the bare "minus error" reward.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo.utils import BaseParallelWrapper

from localization import Localizer, ProjectionDetector
from localization.geometry import camera_center, invert, quat_wxyz_from_matrix
from uav_struct_env.errors import ConfigError
from uav_struct_env.site import LANDMARK_SETS
from uav_struct_env.wrappers.frame import FrameLocalization, localize_aruco_frame, localize_frame

__all__ = ["DETECTORS", "REWARDS", "LocalizationWrapper"]

DETECTORS = ("projection", "aruco", "learned")
REWARDS = ("error", "uncertainty")
MODES = ("paper", "robust")
#: Width of the paper's camera; pixel quantities "at the paper's resolution" scale by W / this.
PAPER_WIDTH_PX = 1280
POSE_BOUND = 1.0e4
STD_BOUND = 100.0
LAYOUT_COMPONENTS = (
    "visible_frac",
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


def _number(name: str, value: Any, minimum: float = 0.0) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    if not np.isfinite(value) or value < minimum:
        raise ConfigError(f"{name} must be finite and >= {minimum}, got {value!r}")
    return float(value)


class LocalizationWrapper(BaseParallelWrapper):
    """Localize every agent each step; add pose, its quality and an anchor-quality reward.

    Args:
        env: a ``uav_struct_v0`` parallel env (or a wrapper of one) whose config's
            ``landmark_sets`` includes ``landmarks`` (the projection detector needs the truth);
            build one with :func:`uav_struct_env.wrappers.make_localization_env`.
        landmarks: landmark set: ``slab_corners``, ``opening_corners``, ``column_tops``,
            ``aruco`` or ``all``.
        detector: ``"projection"`` (simulated: true projections + noise, misses, clutter),
            ``"aruco"`` (OpenCV markers; only with ``landmarks="aruco"`` and when
            :mod:`localization.aruco` is installed) or ``"learned"`` (the trained detector of
            :mod:`localization.learned` -- keypoint network + patch refiner -- on the image, for
            the structural sets and ``all``, at the operating point that suits ``mode``; when
            the env provides the set's truth, its ``true_ids`` -- used for the association
            scores only -- come from matching to it within 3 px).
        mode: association, ``"robust"`` or ``"paper"``.
        reward: ``"error"`` or ``"uncertainty"`` (module docstring).
        pixel_sigma: detector noise, px of the env's images; default 1 px at the paper's
            1280-px-wide camera scaled to the env's width (0.1 px at 128 x 72), so a
            low-resolution env scores poses as the paper's camera would.
        miss_rate: probability that a visible landmark is not detected.
        false_positives: mean clutter detections per image.
        drop_image: remove ``image`` from the observation after localizing.
        rotation_weight: metres of reward per degree of rotation error (``error`` reward).
        failure_penalty: reward term of a failed localization (>= 0, subtracted).
        error_cap: cap (m) on the translation, rotation and uncertainty terms; default
            ``failure_penalty`` (a wrong fix never scores below a failure).
        alive_bonus: constant term per step; default ``failure_penalty``.
        crash_penalty: subtracted when an agent is terminated (geofence/collision).
        localizer_kwargs: extra :class:`~localization.Localizer` arguments. By default the
            robust gates given in px at the paper's resolution are scaled to the env's width.
        detector_model: with ``detector="learned"``, another keypoint network (ONNX file; None:
            the committed one), e.g. retrained with ``python -m uav_struct_env.train_detector``.
        refiner_model: with ``detector="learned"``, another patch refiner (ONNX file; None: the
            committed one).

    Raises:
        ConfigError: for an unknown option or when the env does not provide the landmark truth.
    """

    def __init__(
        self,
        env: Any,
        landmarks: str = "column_tops",
        detector: str = "projection",
        mode: str = "robust",
        reward: str = "error",
        *,
        pixel_sigma: float | None = None,
        miss_rate: float = 0.0,
        false_positives: float = 0.0,
        drop_image: bool = False,
        rotation_weight: float = 0.1,
        failure_penalty: float = 1.0,
        error_cap: float | None = None,
        alive_bonus: float | None = None,
        crash_penalty: float = 1.0,
        localizer_kwargs: dict[str, Any] | None = None,
        detector_model: str | Path | None = None,
        refiner_model: str | Path | None = None,
    ) -> None:
        super().__init__(env)
        for name, path in (("detector_model", detector_model), ("refiner_model", refiner_model)):
            if path is None:
                continue
            if detector != "learned":
                raise ConfigError(f"{name} applies to detector='learned' only, got detector={detector!r}")
            if not isinstance(path, (str, Path)) or not Path(path).is_file():
                raise ConfigError(f"{name} must be an existing ONNX file, got {path!r}")
        if landmarks not in LANDMARK_SETS:
            raise ConfigError(f"landmarks must be one of {LANDMARK_SETS}, got {landmarks!r}")
        if detector not in DETECTORS:
            raise ConfigError(f"detector must be one of {DETECTORS}, got {detector!r}")
        if detector == "learned" and landmarks == "aruco":
            raise ConfigError("detector='learned' detects structural landmarks, not 'aruco'")
        if mode not in MODES:
            raise ConfigError(f"mode must be one of {MODES}, got {mode!r}")
        if reward not in REWARDS:
            raise ConfigError(f"reward must be one of {REWARDS}, got {reward!r}")
        base = env.unwrapped
        config = getattr(base, "config", None)
        if config is None or not hasattr(base, "site") or not hasattr(base, "camera"):
            raise ConfigError(
                f"LocalizationWrapper needs a uav_struct_v0 environment (with .config, .site and "
                f".camera), got {type(base).__name__}"
            )
        if detector == "projection" and landmarks not in config.landmark_sets:
            raise ConfigError(
                f"the wrapped env provides landmark truth for {config.landmark_sets}, but "
                f"landmarks={landmarks!r} needs it: build the env with "
                f"landmark_sets=({landmarks!r},) (the 'train' preset sets ()), e.g. "
                f"uav_struct_env.wrappers.make_localization_env(landmarks={landmarks!r})"
            )
        self.landmarks = landmarks
        self.detector_name = detector
        self.mode = mode
        self.reward_name = reward
        self.drop_image = bool(drop_image)
        self.rotation_weight = _number("rotation_weight", rotation_weight)
        self.failure_penalty = _number("failure_penalty", failure_penalty)
        self.error_cap = _number("error_cap", failure_penalty if error_cap is None else error_cap)
        self.alive_bonus = _number("alive_bonus", failure_penalty if alive_bonus is None else alive_bonus)
        self.crash_penalty = _number("crash_penalty", crash_penalty)

        w, h = config.image_size
        self.image_size = (int(w), int(h))
        scale = w / PAPER_WIDTH_PX
        self.pixel_sigma = _number("pixel_sigma", scale if pixel_sigma is None else pixel_sigma)
        self.miss_rate = _number("miss_rate", miss_rate)
        self.false_positives = _number("false_positives", false_positives)
        model = base.site.landmarks(landmarks)
        self.model_ids = np.asarray(model.ids, dtype=np.int64)
        self.K = np.asarray(base.camera.K, dtype=np.float64)
        self._site_center = np.asarray(base.site.center, dtype=np.float64).reshape(3)
        self._aruco = None
        if detector == "aruco":
            if landmarks != "aruco":
                raise ConfigError(f"detector='aruco' needs landmarks='aruco', got {landmarks!r}")
            try:
                from localization.aruco import ArucoLocalizer
            except ImportError as e:
                raise ConfigError(f"detector='aruco' is not available: {e}") from None
            if not base.site.markers:
                raise ConfigError("detector='aruco' needs markers: build the env with marker_size set")
            self._aruco = ArucoLocalizer(base.site.markers, self.K)
            self.localizer = None
        else:
            if len(model.xyz) < 4:
                raise ConfigError(
                    f"landmark set {landmarks!r} has {len(model.xyz)} landmarks at stage "
                    f"{config.stage!r}; at least 4 are needed to localize"
                )
            kwargs = {
                "pixel_sigma": self.pixel_sigma,
                "image_size": self.image_size,
                "gate_px": max(5.0 * self.pixel_sigma, 3.0 * scale),
                "coarse_gate_px": 40.0 * scale,
                **(localizer_kwargs or {}),
            }
            self.localizer = Localizer(model.xyz, self.K, association=mode, **kwargs)
        self._prior_std = (
            self.localizer.prior_sigmas.as_array()
            if self.localizer is not None
            else np.concatenate([np.full(3, 3.0), np.radians([2.0, 2.0, 5.0])])
        )
        self._rng = np.random.default_rng()
        if detector == "learned":
            from localization.learned import LearnedDetector

            self._detector = LearnedDetector.for_localizer(
                landmarks, w, mode, model=detector_model, refiner=refiner_model or True
            )
        else:
            self._detector = ProjectionDetector(
                landmarks, self.pixel_sigma, self.miss_rate, self.false_positives, rng=self._rng
            )
        inner = env.observation_space(env.possible_agents[0])
        keys = {k: v for k, v in inner.spaces.items() if not (self.drop_image and k == "image")}
        keys["pose"] = spaces.Box(-POSE_BOUND, POSE_BOUND, (7,), np.float32)
        keys["pose_std"] = spaces.Box(0.0, STD_BOUND, (6,), np.float32)
        keys["localized"] = spaces.Box(0.0, 1.0, (1,), np.float32)
        keys["layout"] = spaces.Box(-1.0, 2.0, (len(LAYOUT_COMPONENTS),), np.float32)
        self._observation_space = spaces.Dict(keys)
        self.last_frames: dict[str, FrameLocalization] = {}

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> spaces.Dict:
        """The cached observation space shared by all agents: the env's plus the pose keys."""
        self.env.observation_space(agent)  # validates the agent name
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Space:
        """The env's action space."""
        return self.env.action_space(agent)

    # ------------------------------------------------------------------ API
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env and localize every agent; ``seed`` also seeds the detector."""
        if seed is not None:
            self._rng = np.random.default_rng([int(seed), 0x10CA1])
            if isinstance(self._detector, ProjectionDetector):
                self._detector.rng = self._rng
        obs, infos = self.env.reset(seed=seed, options=options)
        self.last_frames = {}
        for agent in obs:
            self._localize(agent, obs[agent], infos[agent])
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env, localize every agent that produced an observation, compute the reward."""
        obs, rewards, terminations, truncations, infos = self.env.step(actions)
        for agent in obs:
            frame = self._localize(agent, obs[agent], infos[agent])
            terms = dict(infos[agent].get("reward_terms", {}))
            terms.update(self._reward_terms(frame, bool(terminations.get(agent, False))))
            infos[agent]["reward_terms"] = terms
            rewards[agent] = float(sum(terms.values()))
        return obs, rewards, terminations, truncations, infos

    # ------------------------------------------------------------------ internals
    def _localize(self, agent: str, obs: dict, info: dict) -> FrameLocalization:
        gt = invert(info["world_from_cam"])
        prior = invert(info["prior_world_from_cam"])
        truth = info.get("landmarks", {}).get(self.landmarks)
        image = obs["image"]
        if self._aruco is not None:
            frame = localize_aruco_frame(self._aruco, image, prior, gt)
        else:
            context = {"landmarks": info["landmarks"], "image_size": self.image_size}
            frame = localize_frame(self._detector, self.localizer, image, context, prior, gt, self.model_ids)
        est = frame.estimate
        world_from_cam = invert(est.cam_from_world)
        pose = np.concatenate([world_from_cam[:3, 3], quat_wxyz_from_matrix(world_from_cam[:3, :3])])
        std = est.pose_std if est.success else self._prior_std
        std = np.where(np.isfinite(std), std, STD_BOUND)
        obs["pose"] = np.clip(pose, -POSE_BOUND, POSE_BOUND).astype(np.float32)
        obs["pose_std"] = np.clip(std, 0.0, STD_BOUND).astype(np.float32)
        obs["localized"] = np.array([1.0 if est.success else 0.0], np.float32)
        obs["layout"] = self._layout(frame, truth)
        if self.drop_image:
            del obs["image"]
        position_std = float(np.sqrt(np.trace(est.covariance[:3, :3]))) if est.success else float("inf")
        s = frame.scores
        info["localization"] = {
            "success": bool(est.success),
            "translation_error_m": frame.translation_error_m,
            "rotation_error_deg": frame.rotation_error_deg,
            "prior_translation_error_m": frame.prior_translation_error_m,
            "n_correspondences": int(est.n_inliers),
            "n_detections": len(frame.detections),
            "n_visible": int(np.sum(truth["visible"])) if truth is not None else -1,
            "association_precision": float(s.precision),
            "association_recall": float(s.recall),
            "association_f1": float(s.f1),
            "reprojection_rmse_px": float(est.reprojection_rmse_px),
            "position_std_m": position_std,
            "latency_s": float(frame.latency_s),
            "failure_reason": est.failure_reason,
        }
        self.last_frames[agent] = frame
        return frame

    def _layout(self, frame: FrameLocalization, truth: dict | None) -> np.ndarray:
        m = max(len(self.model_ids), 1)
        w, h = self.image_size
        out = np.zeros(len(LAYOUT_COMPONENTS), np.float32)
        cam_from_world = frame.estimate.cam_from_world
        to_site = cam_from_world[:3, :3] @ self._site_center + cam_from_world[:3, 3]
        dist = float(np.linalg.norm(to_site))
        out[6:9] = to_site / dist if dist > 0 else 0.0
        out[9] = min(dist / 100.0, 2.0)
        out[0] = float(np.sum(truth["visible"])) / m if truth is not None else 0.0
        uv = frame.detections.uv
        out[1] = min(len(uv) / m, 2.0)
        if len(uv):
            half = np.array([w / 2.0, h / 2.0])
            c = (uv.mean(axis=0) - (half - 0.5)) / half
            out[2:4] = np.clip(c, -1.0, 1.0)
            out[4:6] = np.clip(uv.std(axis=0) / half, 0.0, 2.0)
        return out

    def _reward_terms(self, frame: FrameLocalization, crashed: bool) -> dict[str, float]:
        est = frame.estimate
        terms = {"alive": self.alive_bonus}
        if not est.success:
            terms["failure"] = -self.failure_penalty
        elif self.reward_name == "error":
            terms["translation"] = -min(frame.translation_error_m, self.error_cap)
            terms["rotation"] = -min(self.rotation_weight * frame.rotation_error_deg, self.error_cap)
        else:
            std = float(np.sqrt(max(np.trace(est.covariance[:3, :3]), 0.0)))
            terms["uncertainty"] = -min(std if np.isfinite(std) else self.error_cap, self.error_cap)
        if crashed:
            terms["crash"] = -self.crash_penalty
        return terms

    def estimated_position(self, agent: str) -> np.ndarray:
        """(3,) the last estimated camera centre of ``agent`` (the prior's when failed)."""
        return camera_center(self.last_frames[agent].estimate.cam_from_world)

    def __repr__(self) -> str:
        return (
            f"LocalizationWrapper({self.env!r}, landmarks={self.landmarks!r}, "
            f"detector={self.detector_name!r}, mode={self.mode!r}, reward={self.reward_name!r}, "
            f"drop_image={self.drop_image})"
        )
