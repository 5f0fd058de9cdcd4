"""Shared small configurations for the environment tests (imported as a plain module)."""

import types

import uav_struct_env
from uav_struct_env.envs import env as aec_env
from uav_struct_env.envs import parallel_env

#: The training preset (128 x 72) with every landmark set in the infos, so infos are exercised.
SMALL = {
    "image_size": (128, 72),
    "landmark_sets": ("slab_corners", "opening_corners", "column_tops", "aruco", "all"),
}


def small_parallel_env(**overrides):
    return parallel_env("train", **{**SMALL, **overrides})


def small_aec_env(**overrides):
    return aec_env("train", **{**SMALL, **overrides})


#: A module-like object for pettingzoo.test.max_cycles_test at the training resolution.
small_module = types.SimpleNamespace(parallel_env=small_parallel_env, env=small_aec_env)
#: The default (paper, 1280 x 720) configuration, exactly as outside scripts get it.
default_module = uav_struct_env
