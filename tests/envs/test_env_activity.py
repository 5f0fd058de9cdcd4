"""Site activity in the env: its own seed, occlusion in info, worker_points / worker_visibility, obstacles."""

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ConfigError, ResetNeededError
from uav_struct_env.site.activity import MAX_EQUIPMENT_HEIGHT, WORKER_HEIGHT

SETS = ("slab_corners", "opening_corners", "column_tops")


def _env(**overrides):
    base = dict(image_size=(320, 180), renderer="tiny", stage="columns", landmark_sets=SETS)
    return uav_struct_env.parallel_env(**{**base, **overrides})


def _visible(info):
    return {a: {s: info[a]["landmarks"][s]["visible"].copy() for s in SETS} for a in info}


def test_activity_key_resolves_and_rejects_bad_values():
    with pytest.raises(ConfigError, match=r"activity must be one of \['busy', 'light', 'none'\]"):
        _env(activity="crowded")
    env = _env(activity="light")
    assert env.config.activity.name == "light"
    with pytest.raises(ResetNeededError):
        env.worker_points()
    env.close()


def test_activity_leaves_every_other_draw_unchanged_and_hides_landmarks():
    """Same seed: the sensors and starts are the same with and without activity; truth differs."""
    plain = _env(observe_image=False, noise="gnss_ins")
    busy = _env(observe_image=False, noise="gnss_ins", activity="busy")
    hidden = 0
    for seed in range(4):
        obs_p, info_p = plain.reset(seed=seed)
        obs_b, info_b = busy.reset(seed=seed)
        for _ in range(3):
            for a in plain.agents:
                np.testing.assert_array_equal(obs_p[a]["gnss"], obs_b[a]["gnss"])
                np.testing.assert_array_equal(obs_p[a]["attitude"], obs_b[a]["attitude"])
                np.testing.assert_array_equal(info_p[a]["world_from_cam"], info_b[a]["world_from_cam"])
                for s in SETS:
                    vp, vb = info_p[a]["landmarks"][s]["visible"], info_b[a]["landmarks"][s]["visible"]
                    assert not np.any(vb & ~vp), "activity made a landmark visible"
                    hidden += int(np.sum(vp & ~vb))
            actions = {a: np.array([0.2, 0.0, 0.0, 0.1, 0.0], np.float32) for a in plain.agents}
            obs_p, _, _, _, info_p = plain.step(actions)
            obs_b, _, _, _, info_b = busy.step(actions)
    assert hidden > 0, "busy activity hid no landmark in 48 views"
    plain.close()
    busy.close()


def test_same_seed_same_layout_and_motion_and_ray_cast_agrees_with_the_render():
    a, b = _env(activity="busy"), _env(activity="busy", observe_image=False)
    _, info_a = a.reset(seed=5, options={"viewpoint": 2})
    _, info_b = b.reset(seed=5, options={"viewpoint": 2})
    agree = total = 0
    for step in range(3):
        pa, pb = a.worker_points(), b.worker_points()
        assert list(pa) == list(pb) and len(pa) >= 12
        for name in pa:
            assert pa[name].shape == (2, 3) and pa[name].dtype == np.float64
            np.testing.assert_array_equal(pa[name], pb[name])
            np.testing.assert_allclose(pa[name][1] - pa[name][0], [0, 0, WORKER_HEIGHT])
        for agent in a.agents:
            va, vb = a.worker_visibility(agent), b.worker_visibility(agent)
            assert va == vb
            assert all(0.0 <= v <= 1.0 for v in va.values())
            for s in SETS:
                x, y = info_a[agent]["landmarks"][s]["visible"], info_b[agent]["landmarks"][s]["visible"]
                agree += int(np.sum(x == y))
                total += len(x)
        if step == 0:
            moved = {n: p.copy() for n, p in pa.items()}
        actions = dict.fromkeys(a.agents, np.zeros(5, np.float32))
        *_, info_a = a.step(actions)
        *_, info_b = b.step(actions)
    after = a.worker_points()
    assert sum(not np.array_equal(moved[n], after[n]) for n in after) >= len(after) - 2
    assert agree / total >= 0.97, f"rendered and ray-cast truth agree on {agree}/{total}"
    # a new seed, a new layout; reset without a seed continues to another
    first = [(w.name, w.waypoints.tobytes()) for w in a.activity_layout.workers]
    a.reset()
    assert [(w.name, w.waypoints.tobytes()) for w in a.activity_layout.workers] != first
    a.reset(seed=5, options={"viewpoint": 2})
    assert [(w.name, w.waypoints.tobytes()) for w in a.activity_layout.workers] == first
    a.close()
    b.close()


def test_no_activity_no_workers_and_no_extra_bodies():
    env = _env()
    env.reset(seed=0)
    assert env.worker_points() == {} and env.worker_visibility("uav_0") == {}
    assert len(env.world._extra_bodies) == len(env.possible_agents)  # the airframes only
    env.close()


@pytest.mark.parametrize("site", ["paper", "random"])
def test_static_activity_is_an_obstacle_and_no_viewpoint_starts_inside_it(site):
    env = _env(activity="busy", site=site, texture_seed=3)
    for seed in range(3):
        env.reset(seed=seed)
        names = [n for n in env.obstacles.names if "/" in n or n.startswith(("formwork", "scaffold"))]
        assert len(names) == len(env.activity_layout.static)
        assert env.obstacles.hi[len(env._site_obstacles.names):, 2].max() <= max(
            MAX_EQUIPMENT_HEIGHT, max(s.z_top for s in env.built_site.floor) + 1.1)
        sched = env.viewpoint_schedule
        eyes = np.array([sched.state(i, k).xyz
                         for i in range(sched.n_agents) for k in range(sched.n_viewpoints)])
        assert env.obstacles.distances(eyes).min() > env.config.uav_radius
    env.close()


def test_pettingzoo_api_and_seed_tests_pass_with_a_busy_site():
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    def make():
        return uav_struct_env.parallel_env("train", activity="busy", renderer="tiny")

    env = make()
    parallel_api_test(env, num_cycles=5)
    env.close()
    parallel_seed_test(make, num_cycles=5)
