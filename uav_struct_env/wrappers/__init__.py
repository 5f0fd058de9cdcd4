"""PettingZoo wrappers that combine the environment with localization, one job each.

from uav_struct_env.wrappers import LocalizationWrapper, make_train_env
wenv = LocalizationWrapper(env, landmarks="column_tops")   # env must provide the truth
wenv = make_train_env("state")                             # a documented training config

``LocalizationWrapper`` composes :class:`LocalizePoses` (pose, pose_std, localized, info),
:class:`WarmStart` (each frame started from the predicted pose), :class:`FilterPoses` (the pose
filtered over time), :class:`LayoutObservation` (layout), :class:`RewardWrapper` (a reward
object's terms) and :class:`DropKeys` (drop the image); :func:`find_wrapper` finds a layer of a
chain, :func:`iter_chain` walks it; :class:`FlattenObservation` turns the Dict into one vector;
:class:`WorkerTracking` tracks the site's workers from all cameras (info and a reward option);
:class:`TensorInfo` keeps only numeric, fixed-shape info entries (TorchRL);
:class:`StepInfos` keeps the named entries of step infos only (SuperSuit's vector envs);
the stack itself is :mod:`uav_struct_env.stack`.
"""

from uav_struct_env.stack import FrameLocalization, localize_frame
from uav_struct_env.wrappers.base import find_wrapper, iter_chain
from uav_struct_env.wrappers.configs import (
    TRAIN_CONFIGS,
    TrainConfig,
    make_localization_env,
    make_train_env,
)
from uav_struct_env.wrappers.flatten import FlattenObservation
from uav_struct_env.wrappers.keys import DropKeys
from uav_struct_env.wrappers.layout import (
    LAYOUT_COMPONENTS,
    PRIVILEGED_LAYOUT_COMPONENTS,
    LayoutObservation,
)
from uav_struct_env.wrappers.localization import DETECTORS, LocalizationWrapper
from uav_struct_env.wrappers.localize import LocalizePoses
from uav_struct_env.wrappers.rewards import (
    REWARDS,
    AnchorReward,
    ErrorReward,
    Reward,
    RewardWrapper,
    UncertaintyReward,
    make_reward,
)
from uav_struct_env.wrappers.step_infos import StepInfos
from uav_struct_env.wrappers.temporal import FilterPoses
from uav_struct_env.wrappers.tensor_info import TensorInfo
from uav_struct_env.wrappers.tracking import TRACKING_INFO_KEYS, TrackingReward, WorkerTracking
from uav_struct_env.wrappers.warm_start import WarmStart

__all__ = [
    "DETECTORS",
    "LAYOUT_COMPONENTS",
    "PRIVILEGED_LAYOUT_COMPONENTS",
    "REWARDS",
    "TRACKING_INFO_KEYS",
    "TRAIN_CONFIGS",
    "AnchorReward",
    "DropKeys",
    "ErrorReward",
    "FilterPoses",
    "FlattenObservation",
    "FrameLocalization",
    "LayoutObservation",
    "LocalizationWrapper",
    "LocalizePoses",
    "Reward",
    "RewardWrapper",
    "StepInfos",
    "TensorInfo",
    "TrackingReward",
    "TrainConfig",
    "UncertaintyReward",
    "WarmStart",
    "WorkerTracking",
    "find_wrapper",
    "iter_chain",
    "localize_frame",
    "make_localization_env",
    "make_reward",
    "make_train_env",
]
