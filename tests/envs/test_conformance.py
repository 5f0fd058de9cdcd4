"""PettingZoo's public conformance suite on the default (paper, 1280 x 720) and training configs.

Cycle counts are kept low at 1280 x 720 (one step renders four full-size images): two cycles
per episode in the API test still step an episode after its first step and end it by max_cycles
(the test sets ``max_cycles`` to its cycle count); the seed test compares the reset and the first
step, whatever its cycle count (PettingZoo's ``parallel_seed_test`` stops after one step).
"""

import warnings

import pytest
from env_helpers import default_module, small_aec_env, small_module, small_parallel_env
from pettingzoo.test import max_cycles_test, parallel_api_test, parallel_seed_test, render_test

import uav_struct_env

# If SiteWorld's "auto" ever falls back from EGL to TinyRenderer for one of two envs, their
# images differ and the seed test would only say "Incorrect observations": fail with the cause.
pytestmark = pytest.mark.filterwarnings("error:EGL rendering is unavailable")

CONFIGS = {
    "default": (uav_struct_env.parallel_env, uav_struct_env.env, default_module, 2),
    "train": (small_parallel_env, small_aec_env, small_module, 30),
}


@pytest.fixture(params=sorted(CONFIGS))
def config(request):
    return CONFIGS[request.param]


def test_parallel_api(config):
    make_parallel, _, _, cycles = config
    env = make_parallel()
    parallel_api_test(env, num_cycles=cycles)
    env.close()


def test_parallel_seed(config):
    make_parallel, _, _, cycles = config
    parallel_seed_test(make_parallel, num_cycles=cycles)


def test_render_through_aec(config):
    _, make_aec, _, _ = config
    with warnings.catch_warnings():
        # render_test first probes render_mode="human", which we accept with a warning.
        warnings.filterwarnings("ignore", message="render_mode='human' is not supported")
        render_test(lambda render_mode=None: make_aec(render_mode=render_mode))


def test_max_cycles(config):
    _, _, module, _ = config
    max_cycles_test(module)
