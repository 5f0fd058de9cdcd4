"""Env config and reset under hostile input: every key type-checked, refused with our message."""

from __future__ import annotations

import time

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.envs.uav_struct import RESET_OPTIONS
from uav_struct_env.errors import ConfigError, ResetNeededError


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"show_uavs": "no"}, r"show_uavs must be True or False, got 'no'"),
        ({"observe_depth": "no"}, r"observe_depth must be True or False, got 'no'"),
        ({"observe_depth": 1}, r"observe_depth must be True or False, got 1"),
        ({"image_size": (100_000, 100_000)},
         r"image_size\[0\] \(width\) must be an int in \[16, 8192\], got 100000"),
        ({"image_size": (8000, 8000)}, r"image_size 8000 x 8000 has 64000000 pixels, more than the 19961856"),
        ({"image_size": (64.0, 48)}, r"image_size\[0\] \(width\) must be an int in \[16, 8192\], got 64.0"),
        ({"image_size": "64x48"}, r"image_size must be \(width, height\) in pixels, got '64x48'"),
        ({"uav_radius": 1e9}, r"uav_radius must be a number in \(0, 10\], got 1000000000.0"),
        ({"uav_radius": float("nan")}, r"uav_radius must be a number in \(0, 10\], got nan"),
        ({"control_period": True}, r"control_period must be a number, got True"),
        ({"texture_seed": -1}, r"texture_seed must be an int >= 0, got -1"),
        ({"texture_seed": 1.5}, r"texture_seed must be an int >= 0, got 1.5"),
        ({"n_agents": 1000}, r"n_agents must be an int in \[1, 64\], got 1000"),
        ({"max_cycles": "100"}, r"max_cycles must be an int >= 1, got '100'"),
        ({"marker_size": float("inf")}, r"marker_size must be a number in \(0, 10\], got inf"),
        ({"renderer": 3}, r"renderer must be one of \('auto', 'tiny', 'egl', 'batch'\), got 3"),
        ({"on_crash": "everyone"}, r"on_crash must be one of \('agent', 'all'\), got 'everyone'"),
        ({"landmark_sets": "all"}, r"landmark_sets must be a tuple of set names, got 'all'"),
        ({"start_yaw_jitter": 4.0}, r"start_yaw_jitter must be a number in \[0, 3.14159"),
    ],
)
def test_every_config_key_is_type_and_range_checked(overrides, message):
    t0 = time.perf_counter()
    with pytest.raises(ConfigError, match=message):
        uav_struct_env.parallel_env(**overrides)
    assert time.perf_counter() - t0 < 1.0  # refused before anything is allocated


def test_bools_and_numpy_ints_are_accepted():
    env = uav_struct_env.parallel_env(show_uavs=np.bool_(False), image_size=(np.int64(64), 48),
                                      texture_seed=np.int32(3))
    assert env.config.show_uavs is False and env.config.image_size == (64, 48)
    env.close()


@pytest.fixture
def env():
    env = uav_struct_env.parallel_env(image_size=(64, 48), renderer="tiny")
    yield env
    env.close()


def test_step_before_reset_is_refused(env):
    with pytest.raises(ResetNeededError, match=r"step\(\) before reset\(\)"):
        env.step({})


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"seed": -1}, r"seed must be an int >= 0, got -1"),
        ({"seed": 1.5}, r"seed must be an int >= 0, got 1.5"),
        ({"options": "x"}, r"options must be a dict \(keys \('viewpoint',\)\) or None, got 'x'"),
        ({"options": {"viewpont": 3}},
         r"unknown reset options \['viewpont'\]; valid keys are \['viewpoint'\]"),
    ],
)
def test_bad_reset_arguments_are_refused_listing_what_is_valid(env, kwargs, message):
    with pytest.raises(ValueError, match=message):
        env.reset(**kwargs)


def test_pettingzoo_signature_probe_is_accepted(env):
    assert RESET_OPTIONS == ("viewpoint",)
    obs, _ = env.reset(seed=0, options={"options": 1})  # what pettingzoo's api tests pass
    assert set(obs) == set(env.possible_agents)
