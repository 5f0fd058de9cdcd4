"""PettingZoo wrappers that combine the environment with localization.

from uav_struct_env.wrappers import LocalizationWrapper, make_train_env
wenv = LocalizationWrapper(env, landmarks="column_tops")   # env must provide the truth
wenv = make_train_env("state")                             # a documented training config
"""

from uav_struct_env.wrappers.configs import (
    TRAIN_CONFIGS,
    TrainConfig,
    make_localization_env,
    make_train_env,
)
from uav_struct_env.wrappers.frame import FrameLocalization, localize_frame
from uav_struct_env.wrappers.localization import (
    DETECTORS,
    LAYOUT_COMPONENTS,
    REWARDS,
    LocalizationWrapper,
)

__all__ = [
    "DETECTORS",
    "LAYOUT_COMPONENTS",
    "REWARDS",
    "TRAIN_CONFIGS",
    "FrameLocalization",
    "LocalizationWrapper",
    "TrainConfig",
    "localize_frame",
    "make_localization_env",
    "make_train_env",
]
