"""Fixtures of the stack's tests."""

import pytest

import uav_struct_env


@pytest.fixture(scope="module")
def slab_view():
    """One 1280 x 720 frame of the paper site's slab stage: (site, image, info of uav_1)."""
    env = uav_struct_env.parallel_env(image_size=(1280, 720), stage="slab", renderer="tiny")
    obs, infos = env.reset(seed=0, options={"viewpoint": 0})
    yield env.site, obs["uav_1"]["image"], infos["uav_1"]
    env.close()
