"""Semantics of the parallel env: spaces, observations, infos, noise, schedule, episodes, render."""

import math
import warnings

import numpy as np
import pytest
from env_helpers import small_parallel_env

import uav_struct_env
from uav_struct_env.envs import PRESETS, UavStructParallelEnv, make_config
from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.attitude import world_from_cam_from_attitude
from uav_struct_env.sim.uav import UavState


@pytest.fixture(scope="module")
def env():
    env = small_parallel_env(noise="paper", render_mode="rgb_array")
    yield env
    env.close()


def test_metadata_agents_and_cached_identical_spaces(env):
    assert env.metadata["name"] == "uav_struct_v0"
    assert env.metadata["render_modes"] == ["rgb_array"]
    assert env.metadata["is_parallelizable"] is True and env.metadata["render_fps"] > 0
    assert env.possible_agents == ["uav_0", "uav_1", "uav_2", "uav_3"]
    assert env.render_mode == "rgb_array"
    first = env.observation_space("uav_0")
    assert all(env.observation_space(a) is first for a in env.possible_agents)
    assert env.action_space("uav_0") is env.action_space("uav_2")
    assert env.action_space("uav_0").shape == (5,) and env.action_space("uav_0").dtype == np.float32
    with pytest.raises(ValueError, match="unknown agent 'uav_9'"):
        env.observation_space("uav_9")


def test_render_mode_is_set_even_when_none():
    env = small_parallel_env()
    assert env.render_mode is None
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode=None"):
        assert env.render() is None
    env.close()


def test_observation_and_info_contract(env):
    obs, infos = env.reset(seed=0)
    K = env.camera.K
    for a in env.possible_agents:
        o, i = obs[a], infos[a]
        assert env.observation_space(a).contains(o)
        assert o["image"].dtype == np.uint8 and o["image"].shape == (72, 128, 3)
        assert o["gnss"].dtype == np.float32 and o["gnss"].shape == (3,)
        assert o["attitude"].dtype == np.float32 and o["attitude"].shape == (3,)
        for key in ("world_from_cam", "prior_world_from_cam"):
            assert i[key].dtype == np.float64 and i[key].shape == (4, 4)
        np.testing.assert_array_equal(i["intrinsics"], K)
        # the prior is exactly what gnss + attitude imply
        np.testing.assert_array_equal(
            i["prior_world_from_cam"],
            world_from_cam_from_attitude(
                o["gnss"].astype(np.float64), o["attitude"].astype(np.float64)
            ),
        )
        for name in ("slab_corners", "opening_corners", "column_tops", "aruco", "all"):
            lm = i["landmarks"][name]
            assert set(lm) >= {"ids", "xyz", "uv", "in_frame", "visible"}
            m = len(lm["ids"])
            assert lm["xyz"].shape == (m, 3) and lm["uv"].shape == (m, 2)
        assert i["termination_reason"] is None
    assert obs["uav_0"]["image"].std() > 5  # not blank


def test_paper_noise_offsets_follow_documented_signs(env):
    for k in (0, 1):
        obs, infos = env.reset(seed=0, options={"viewpoint": k})
        for idx, a in enumerate(env.possible_agents):
            s = (-1) ** (idx + k)
            truth = infos[a]["world_from_cam"][:3, 3]
            np.testing.assert_allclose(obs[a]["gnss"] - truth, s * np.array([3, -3, 3]), atol=1e-4)
            st = env.uav_state(a)
            d = np.degrees(obs[a]["attitude"] - st.attitude)
            d[2] = (d[2] + 180) % 360 - 180
            np.testing.assert_allclose(d, s * np.array([2, -2, 5]), atol=1e-4)
            assert infos[a]["viewpoint"] == k and infos[a]["noise_index"] == k
    # each step counts as the next viewpoint for the sign
    _, _, _, _, infos = env.step({})
    assert infos["uav_0"]["noise_index"] == 2 and infos["uav_0"]["viewpoint"] == -1


def test_scripted_viewpoints_place_uavs_and_keep_landmarks_in_frame(env):
    sched = env.viewpoint_schedule
    assert sched.n_agents == 4 and sched.n_viewpoints == 10
    for k in (0, 9):
        _, infos = env.reset(options={"viewpoint": k})
        for idx, a in enumerate(env.possible_agents):
            np.testing.assert_allclose(infos[a]["world_from_cam"], sched.world_from_cam(idx, k))
            for name in ("slab_corners", "opening_corners", "column_tops"):
                assert infos[a]["landmarks"][name]["in_frame"].all(), (k, a, name)
    with pytest.raises(
        ValueError, match=r"options\['viewpoint'\] must be an int in \[0, 10\), got 10"
    ):
        env.reset(options={"viewpoint": 10})


def test_default_reset_starts_each_uav_on_its_own_side(env):
    env.reset(seed=5)
    c = env.site.center
    for idx, a in enumerate(env.possible_agents):
        p = env.uav_state(a).xyz
        az = math.degrees(math.atan2(p[1] - c[1], p[0] - c[0]))
        expected = -90 + 90 * idx
        assert abs((az - expected + 180) % 360 - 180) <= 20 + 1e-9


def test_geofence_structure_and_uav_collisions_terminate_only_that_agent(env):
    env.reset(seed=1)
    col = env.site.columns[0]
    env._states["uav_0"] = UavState.make([col.x, col.y - 0.6, 2.5], 0.0, 0.3)  # 0.425 m from it
    env._states["uav_1"] = UavState.make([0.0, -30.0, 1.0], 0.0, 0.3)
    env._states["uav_2"] = UavState.make([20.0, 20.0, 20.0], 0.0, 0.3)
    env._states["uav_3"] = UavState.make([20.0, 20.6, 20.0], 0.0, 0.3)
    _, rewards, term, trunc, infos = env.step({})
    assert {a: infos[a]["termination_reason"] for a in infos} == {
        "uav_0": "collision_structure",
        "uav_1": "below_min_altitude",
        "uav_2": "collision_uav",
        "uav_3": "collision_uav",
    }
    assert all(term.values()) and not any(trunc.values())
    assert env.agents == []
    assert rewards == dict.fromkeys(env.possible_agents, 0.0)
    assert env.step({}) == ({}, {}, {}, {}, {})


def test_beyond_max_distance():
    env = small_parallel_env(landmark_sets=(), on_crash="agent")
    env.reset(seed=0)
    env._states["uav_1"] = UavState.make([100.0, 0.0, 20.0], 0.0, 0.3)
    _, _, term, _, infos = env.step({})
    assert term == {"uav_0": False, "uav_1": True, "uav_2": False, "uav_3": False}
    assert infos["uav_1"]["termination_reason"] == "beyond_max_distance"
    assert env.agents == ["uav_0", "uav_2", "uav_3"]
    env.close()


def test_max_cycles_truncates_everyone():
    env = small_parallel_env(max_cycles=3, landmark_sets=())
    env.reset(seed=0)
    for t in range(3):
        _, _, term, trunc, infos = env.step({})
        assert not any(term.values())
        assert all(trunc.values()) == (t == 2)
        assert {i["truncation_reason"] for i in infos.values()} == {
            "max_cycles" if t == 2 else None
        }
    assert env.agents == []
    env.close()


def test_render_frame(env):
    env.reset(seed=0, options={"viewpoint": 0})
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    h = 2 * env.config.render_view_height
    assert frame.shape[0] == h and frame.shape[1] == 2 * round(h / 2 * 16 / 9) + h


def test_config_presets_and_errors():
    assert PRESETS["paper"].image_size == (1280, 720)
    assert PRESETS["train"].image_size == (128, 72)
    cfg = make_config("train", stage="slab", marker_size=None, image_size=[160, 90])
    assert cfg.image_size == (160, 90) and cfg.noise.name == "gnss_ins"
    env = UavStructParallelEnv(cfg)
    assert env.site.stage == "slab" and env.site.markers == ()
    with pytest.raises(ConfigError, match="unknown config keys \\['colour'\\]"):
        uav_struct_env.parallel_env(colour="red")
    with pytest.raises(ConfigError, match="stage must be one of"):
        uav_struct_env.parallel_env(stage="roof")
    with pytest.raises(ConfigError, match="noise must be one of"):
        uav_struct_env.parallel_env(noise="rtk")
    with pytest.raises(ConfigError, match="render_mode must be None or one of \\['rgb_array'\\]"):
        uav_struct_env.parallel_env(render_mode="ansi")
    with pytest.raises(ConfigError, match="image_size"):
        uav_struct_env.parallel_env(image_size=(0, 10))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        uav_struct_env.parallel_env(render_mode="human")
    assert any("not supported" in str(x.message) for x in w)


def test_n_agents_and_gnss_ins_noise():
    env = small_parallel_env(n_agents=2, noise="gnss_ins", landmark_sets=())
    assert env.possible_agents == ["uav_0", "uav_1"]
    obs, infos = env.reset(seed=0)
    err = obs["uav_0"]["gnss"] - infos["uav_0"]["world_from_cam"][:3, 3]
    assert 0 < np.linalg.norm(err) < 20
    env.close()


def test_optional_depth_observation():
    env = small_parallel_env(observe_depth=True, landmark_sets=())
    obs, _ = env.reset(seed=0)
    d = obs["uav_0"]["depth"]
    assert d.dtype == np.float32 and d.shape == (72, 128)
    assert env.observation_space("uav_0").contains(obs["uav_0"])
    env.close()


def test_world_built_once_and_reused(env):
    env.reset(seed=0)
    world = env.world
    env.reset(seed=1)
    assert env.world is world


def test_several_envs_in_one_process_do_not_interfere():
    a, b = small_parallel_env(landmark_sets=()), small_parallel_env(landmark_sets=())
    oa, _ = a.reset(seed=0)
    ob, _ = b.reset(seed=0)
    assert a.world.client_id != b.world.client_id
    act = {x: np.full(5, 0.3, np.float32) for x in a.possible_agents}
    for _ in range(3):
        oa, *_ = a.step(act)
        ob, *_ = b.step(act)
        for x in a.possible_agents:
            np.testing.assert_array_equal(oa[x]["image"], ob[x]["image"])
    a.close()
    b.close()


def test_on_crash_all_ends_the_episode_for_everyone():
    env = small_parallel_env(on_crash="all", landmark_sets=())
    env.reset(seed=0)
    env._states["uav_1"] = UavState.make([0.0, -30.0, 1.0], 0.0, 0.3)
    _, _, term, trunc, infos = env.step({})
    # Everyone is terminated (a terminal state for the team, not a time limit), so that a
    # wrapper that ends the episode when all agents are terminated sees it end.
    assert term == dict.fromkeys(env.possible_agents, True)
    assert trunc == dict.fromkeys(env.possible_agents, False)
    assert infos["uav_1"]["termination_reason"] == "below_min_altitude"
    assert infos["uav_0"]["termination_reason"] == "teammate_crash"
    assert infos["uav_0"]["truncation_reason"] is None
    assert env.agents == []
    env.close()


def test_other_uavs_are_drawn_but_not_the_own_airframe():
    small = {"landmark_sets": (), "image_size": (160, 90), "renderer": "tiny", "on_crash": "agent"}
    env = small_parallel_env(**small)
    plain = small_parallel_env(show_uavs=False, **small)
    obs, _ = env.reset(seed=0, options={"viewpoint": 3})
    p_obs, _ = plain.reset(seed=0, options={"viewpoint": 3})
    # at the scripted viewpoints the others are far off and the own airframe is not drawn
    diff = np.abs(p_obs["uav_0"]["image"].astype(int) - obs["uav_0"]["image"].astype(int))
    assert (diff.max(axis=2) > 0).mean() < 0.001
    plain.close()
    s0 = env.uav_state("uav_0")
    env._states["uav_1"] = UavState.make(s0.xyz + 3.0 * s0.world_from_cam[:3, 2], 0.0, 0.5)
    after, *_ = env.step({})
    window = np.s_[30:60, 65:95]  # around the image centre (80, 45)
    dark_after = (after["uav_0"]["image"][window].max(axis=2) < 60).mean()
    dark_before = (obs["uav_0"]["image"][window].max(axis=2) < 60).mean()
    assert dark_after > 0.1 and dark_before < 0.01  # a dark airframe appeared ahead
    env.close()


def test_closed_env_raises_a_clear_closed_error():
    from uav_struct_env.errors import ClosedError

    env = uav_struct_env.parallel_env("train", max_cycles=3, render_mode="rgb_array")
    env.reset(seed=0)
    env.close()
    env.close()  # twice is harmless
    for call in (
        lambda: env.reset(seed=0),
        lambda: env.step({a: np.zeros(5, np.float32) for a in env.possible_agents}),
        env.render,
    ):
        with pytest.raises(ClosedError, match="environment is closed.*create a new one"):
            call()
    assert issubclass(ClosedError, RuntimeError)


def test_random_lighting_draws_a_sun_per_episode_from_the_seed():
    env = uav_struct_env.parallel_env(lighting="random", renderer="tiny", image_size=(64, 36))
    fixed = uav_struct_env.parallel_env(renderer="tiny", image_size=(64, 36))
    try:
        env.reset(seed=1)
        first = env.world.light
        env.reset(seed=2)
        assert env.world.light != first
        env.reset(seed=1)
        assert env.world.light == first
        elevation = np.degrees(np.arcsin(first["lightDirection"][2]))
        assert 25 <= elevation <= 85
        fixed.reset(seed=1)
        from uav_struct_env.sim.world import DEFAULT_LIGHT

        assert fixed.world.light == DEFAULT_LIGHT
    finally:
        env.close()
        fixed.close()
    with pytest.raises(ConfigError, match=r"lighting must be one of \('fixed', 'random'\), got 'sunny'"):
        uav_struct_env.parallel_env(lighting="sunny")
