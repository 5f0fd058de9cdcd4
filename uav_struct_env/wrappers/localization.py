"""``LocalizationWrapper``: BIM-landmark localization of every UAV, its quality and a reward.

A thin composition of the one-job wrappers, kept for its keyword arguments::

    LocalizePoses(env, spec)        pose, pose_std, localized; info["localization"]
    -> WarmStart                    with warm_start=True: each frame starts from the predicted pose
    -> FilterPoses(filter_noise)    with temporal=True: pose, pose_std, localized filtered over time
    -> LayoutObservation            layout (privileged=True: component 0 is the true visible fraction)
    -> RewardWrapper(reward)        reward = sum of the reward object's terms; info["reward_terms"]
    -> DropKeys(...)                ``image`` with drop_image=True (state-only training), and drop_keys

Its ``env`` is the outermost of them (so :func:`~uav_struct_env.wrappers.base.find_wrapper` finds
each one); the env it was given is the innermost one's. See
:mod:`~uav_struct_env.wrappers.localize`, :mod:`~uav_struct_env.wrappers.warm_start`,
:mod:`~uav_struct_env.wrappers.temporal`, :mod:`~uav_struct_env.wrappers.layout`,
:mod:`~uav_struct_env.wrappers.rewards` and :mod:`~uav_struct_env.wrappers.keys` for each key,
term and feature. Compose them directly for another mix (a user's own reward object, no layout).
By default no observation needs ground truth; only ``privileged=True`` puts the simulator's true
visible fraction in ``layout[0]``.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from localization.checks import check_choice
from uav_struct_env.errors import ConfigError
from uav_struct_env.stack import ASSOCIATIONS, DETECTORS, PAPER_WIDTH_PX, StackSpec
from uav_struct_env.wrappers.base import ParallelWrapper
from uav_struct_env.wrappers.keys import DropKeys
from uav_struct_env.wrappers.layout import LAYOUT_COMPONENTS, LayoutObservation
from uav_struct_env.wrappers.localize import LocalizePoses
from uav_struct_env.wrappers.rewards import REWARDS, Reward, RewardWrapper, make_reward
from uav_struct_env.wrappers.temporal import FilterPoses
from uav_struct_env.wrappers.warm_start import WarmStart

__all__ = ["DETECTORS", "LAYOUT_COMPONENTS", "PAPER_WIDTH_PX", "REWARDS", "LocalizationWrapper"]

#: Association modes (the stack's :data:`~uav_struct_env.stack.ASSOCIATIONS`).
MODES = ASSOCIATIONS


def renamed_mode(association: str | None, mode: str | None, default: str = "robust") -> str:
    """The association asked for as ``association=`` or, for one release, as ``mode=``.

    Raises:
        ConfigError: when both are given.
    """
    if mode is None:
        return default if association is None else association
    if association is not None:
        raise ConfigError(f"give association= only (got association={association!r} and mode={mode!r})")
    warnings.warn(
        "the keyword mode= is renamed association= (as in StackSpec and Localizer); mode= will be "
        "removed in the next release", FutureWarning, stacklevel=3,
    )
    return mode


class LocalizationWrapper(ParallelWrapper):
    """Localize every agent each step; add pose, its quality, layout features and a reward.

    Args:
        env: a ``uav_struct_v0`` parallel env (or a wrapper of one) whose config's
            ``landmark_sets`` includes ``landmarks`` (the projection detector needs the truth);
            build one with :func:`uav_struct_env.wrappers.make_localization_env`.
        landmarks: landmark set: ``slab_corners``, ``opening_corners``, ``column_tops``,
            ``aruco`` or ``all``.
        detector: ``"projection"`` (simulated: true projections + noise, misses, clutter),
            ``"aruco"`` (OpenCV markers; only with ``landmarks="aruco"``), ``"learned"`` (the
            trained detector of :mod:`localization.detect.learned` on the image, at the operating
            point that suits ``association``; its ``true_ids`` -- for the association scores only --
            come from matching to the env's truth within 3 px), ``"learned:NAME"`` (the same with
            the weight set ``NAME`` of :mod:`localization.detect.weights`, e.g.
            ``"learned:active"``), or any object following :class:`localization.Detector`.
        association: ``"robust"`` (default) or ``"paper"``.
        reward: ``"error"``, ``"log_error"``, ``"uncertainty"``
            (:mod:`~uav_struct_env.wrappers.rewards`) or a reward object with ``terms(frame, crashed)``.
        pixel_sigma: detector noise, px of the env's images; default 1 px at the paper's
            1280-px-wide camera scaled to the env's width (0.1 px at 128 x 72), so a
            low-resolution env scores poses as the paper's camera would.
        miss_rate: probability that a visible landmark is not detected.
        false_positives: mean clutter detections per image.
        drop_image: remove ``image`` from the observation after localizing (nothing to drop
            when the env renders none, ``observe_image=False``).
        drop_keys: more observation keys to remove after the reward is computed, e.g.
            ``("pose", "pose_std", "localized", "layout")`` for a policy that sees only its camera,
            GNSS and attitude (the ``pixels`` training configuration); the reward still scores
            the localization.
        rotation_weight: metres of reward per degree of rotation error (``error`` reward).
        failure_penalty: reward term of a failed localization (>= 0, subtracted).
        error_cap: cap (m) on the translation, rotation and uncertainty terms; default
            ``failure_penalty`` (a wrong fix never scores below a failure).
        alive_bonus: constant term per step; default ``failure_penalty``.
        crash_penalty: subtracted when an agent is terminated (geofence/collision).
        localizer_kwargs: extra :class:`~localization.Localizer` arguments. By default the
            robust gates given in px at the paper's resolution are scaled to the env's width.
        detector_model: with ``detector="learned"``, another keypoint network (ONNX file; None:
            the committed one), e.g. retrained with
            ``python -m uav_struct_env.training.train_detector``.
        refiner_model: with ``detector="learned"``, another patch refiner (ONNX file; None: the
            committed one).
        privileged: put the simulator's true visible fraction in ``layout[0]`` (privileged
            information a real UAV does not have; default: the deployable inlier fraction).
        temporal: filter each agent's pose over time (GNSS, attitude, commanded motion and the
            visual fixes; :class:`~uav_struct_env.wrappers.temporal.FilterPoses`): ``pose`` is the filtered
            pose at every step and its prediction is the next frame's association prior.
        filter_noise: with ``temporal``, the filters' :class:`~localization.temporal.FilterNoise`
            (default: matched to the env's sensor model).
        warm_start: ``robust`` association: start each frame's association from the pose that
            the agent's previous estimate and its commanded action predict, and search
            hypotheses only when that pose does not explain the whole frame
            (:class:`~uav_struct_env.wrappers.warm_start.WarmStart`); the training
            configurations set it. Default False: every frame searched on its own.
        mode: the former name of ``association``, accepted for one release with a FutureWarning.

    Raises:
        ConfigError: for an unknown option or when the env does not provide the landmark truth.
    """

    #: the reward object (set by ``__init__``; None on the class, for :meth:`__getattr__`)
    reward: Reward | None = None

    def __init__(
        self,
        env: Any,
        landmarks: str = "column_tops",
        detector: Any = "projection",
        association: str | None = None,
        reward: str | Reward = "error",
        *,
        pixel_sigma: float | None = None,
        miss_rate: float = 0.0,
        false_positives: float = 0.0,
        drop_image: bool = False,
        drop_keys: Sequence[str] = (),
        rotation_weight: float = 0.1,
        failure_penalty: float = 1.0,
        error_cap: float | None = None,
        alive_bonus: float | None = None,
        crash_penalty: float = 1.0,
        localizer_kwargs: dict[str, Any] | None = None,
        detector_model: str | Path | None = None,
        refiner_model: str | Path | None = None,
        privileged: bool = False,
        temporal: bool = False,
        filter_noise: Any = None,
        warm_start: bool = False,
        mode: str | None = None,
    ) -> None:
        association = renamed_mode(association, mode)
        check_choice("association", association, MODES, error=ConfigError)
        if not isinstance(warm_start, (bool, np.bool_)):
            raise ConfigError(f"warm_start must be True or False, got {warm_start!r}")
        self.reward = make_reward(
            reward,
            rotation_weight=rotation_weight,
            failure_penalty=failure_penalty,
            error_cap=error_cap,
            alive_bonus=alive_bonus,
            crash_penalty=crash_penalty,
        )
        spec = StackSpec(
            landmarks=landmarks,
            detector=detector,
            association=association,
            pixel_sigma=pixel_sigma,
            miss_rate=miss_rate,
            false_positives=false_positives,
            detector_model=detector_model,
            refiner_model=refiner_model,
            localizer_kwargs=localizer_kwargs or {},
        )
        self.poses = LocalizePoses(env, spec)
        chain: Any = WarmStart(self.poses) if warm_start else self.poses
        self.tracks = None
        if temporal:
            chain = FilterPoses(chain, filter_noise)
            self.tracks = chain.tracks
        chain = RewardWrapper(LayoutObservation(chain, privileged=privileged), self.reward)
        self.drop_image = bool(drop_image)
        if isinstance(drop_keys, str):
            raise ConfigError(f"drop_keys must be a sequence of observation keys, not {drop_keys!r}")
        self.drop_keys = tuple(drop_keys)
        rendered = "image" in env.observation_space(env.possible_agents[0]).spaces
        dropped = (("image",) if self.drop_image and rendered else ()) + self.drop_keys
        if dropped:
            chain = DropKeys(chain, dropped)
        super().__init__(chain)
        self.detector_name = detector if isinstance(detector, str) else type(detector).__name__
        self.association = association
        self.reward_name = reward if isinstance(reward, str) else type(reward).__name__
        self.privileged = bool(privileged)
        self.temporal = bool(temporal)
        self.warm_start = bool(warm_start)
        self.pixel_sigma = spec.detector_sigma(self.poses.image_size[0])
        self.miss_rate = spec.miss_rate
        self.false_positives = spec.false_positives

    def __getattr__(self, name: str) -> Any:
        """Public attributes of the reward object (``failure_penalty``, ...), then the chain's."""
        if not name.startswith("_") and hasattr(self.reward, name):
            return getattr(self.reward, name)
        return super().__getattr__(name)

    def __repr__(self) -> str:
        return (
            f"LocalizationWrapper({self.poses.env!r}, landmarks={self.poses.landmarks!r}, "
            f"detector={self.detector_name!r}, association={self.association!r}, "
            f"reward={self.reward_name!r}, drop_image={self.drop_image}, drop_keys={self.drop_keys}, "
            f"temporal={self.temporal}, "
            f"warm_start={self.warm_start})"
        )
