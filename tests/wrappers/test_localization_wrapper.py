"""LocalizationWrapper: spaces, observations, infos, reward terms, errors, composition."""

import numpy as np
import pytest

import uav_struct_env
from localization import Detections
from uav_struct_env.errors import ConfigError
from uav_struct_env.wrappers import (
    PRIVILEGED_LAYOUT_COMPONENTS,
    TRAIN_CONFIGS,
    FilterPoses,
    LayoutObservation,
    LocalizationWrapper,
    LocalizePoses,
    RewardWrapper,
    TrainConfig,
    WarmStart,
    find_wrapper,
    iter_chain,
    make_localization_env,
    make_train_env,
)
from uav_struct_env.wrappers.rewards import LogErrorReward

SMALL = {"max_cycles": 8}
HOLD = np.zeros(5, np.float32)


def hold(env):
    return {a: HOLD for a in env.agents}


def test_spaces_cached_identical_and_observations_inside():
    env = make_train_env("state", **SMALL)
    spaces = [env.observation_space(a) for a in env.possible_agents]
    assert all(s is spaces[0] for s in spaces)
    assert "image" not in spaces[0].spaces
    for key in ("pose", "pose_std", "localized", "layout", "gnss", "attitude"):
        assert key in spaces[0].spaces
    obs, infos = env.reset(seed=1)
    for _ in range(2):
        for a in obs:
            assert spaces[0].contains(obs[a]), a
            assert obs[a]["pose"].shape == (7,) and obs[a]["pose"].dtype == np.float32
            assert obs[a]["pose_std"].shape == (6,)
            assert obs[a]["localized"][0] in (0.0, 1.0)
        obs, *_ = env.step(hold(env))
    env.close()


def test_scripted_view_localizes_accurately_and_reports_quality():
    env = make_localization_env(
        "column_tops", env_overrides={"image_size": (128, 72), **SMALL}, privileged=True
    )
    obs, infos = env.reset(seed=0, options={"viewpoint": 3})
    assert "image" in obs["uav_0"]
    for a in env.possible_agents:
        loc = infos[a]["localization"]
        assert loc["success"], env.last_frames[a].estimate.failure_reason
        assert loc["failure_code"] == 0
        assert loc["translation_error_m"] < 1.0 and loc["rotation_error_deg"] < 2.0
        assert loc["translation_error_m"] < loc["prior_translation_error_m"]
        assert loc["n_correspondences"] >= 4 and loc["association_f1"] > 0.9
        assert env.last_frames[a].latency_s > 0 and 0 < loc["position_std_m"] < 1.0
        est = obs[a]["pose"][:3]
        truth = infos[a]["world_from_cam"][:3, 3]
        assert np.linalg.norm(est - truth) == pytest.approx(loc["translation_error_m"], abs=1e-3)
        q = obs[a]["pose"][3:]
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-5)
        assert np.all(obs[a]["pose_std"] < 1.0) and obs[a]["localized"][0] == 1.0
        layout = dict(zip(PRIVILEGED_LAYOUT_COMPONENTS, obs[a]["layout"], strict=True))
        assert layout["visible_frac"] > 0.5 and abs(layout["centroid_u"]) < 0.5
        assert layout["site_dir_z"] > 0.9  # the scripted views aim at the building
        assert 0.1 < layout["site_distance_hm"] < 0.6
    env.close()


def test_failed_localization_falls_back_to_the_prior():
    env = make_train_env("state", **SMALL)
    env.reset(seed=0)
    # turn every camera to face away from the building: nothing to detect
    for _ in range(4):
        obs, rew, term, trunc, infos = env.step(
            {a: np.array([0, 0, 0, 1, 0], np.float32) for a in env.agents}
        )
    failed = [a for a in obs if not infos[a]["localization"]["success"]]
    assert failed
    for a in failed:
        prior = infos[a]["prior_world_from_cam"][:3, 3]
        np.testing.assert_allclose(obs[a]["pose"][:3], prior, atol=1e-3)
        assert obs[a]["localized"][0] == 0.0
        assert infos[a]["reward_terms"]["failure"] == -env.failure_penalty
    env.close()


@pytest.mark.parametrize("reward", ["error", "log_error", "uncertainty"])
def test_reward_terms_sum_to_the_reward_including_crashes(reward):
    env = make_train_env("state", max_cycles=12)
    env = LocalizationWrapper(env.unwrapped, reward=reward, association="paper", drop_image=True)
    env.reset(seed=2)
    seen_crash = False
    while env.agents:
        # fly backwards, away from the building: leaves the geofence within the episode
        obs, rew, term, trunc, infos = env.step(
            {a: np.array([-1, 0, 0, 0, 0], np.float32) for a in env.agents}
        )
        for a in rew:
            terms = infos[a]["reward_terms"]
            assert rew[a] == pytest.approx(sum(terms.values()), abs=1e-12)
            assert terms["alive"] == env.alive_bonus
            if term[a] and infos[a]["termination_reason"] != "teammate_crash":
                seen_crash = True
                assert terms["crash"] == -env.crash_penalty
            else:  # flying on, or terminated by a teammate's crash (on_crash="all"): no penalty
                assert "crash" not in terms
            if infos[a]["localization"]["success"]:
                assert ("translation" in terms) == (reward in ("error", "log_error"))
                assert ("uncertainty" in terms) == (reward == "uncertainty")
    assert seen_crash
    env.close()


def test_log_error_terms_are_the_errors_on_a_log_scale_with_the_linear_endpoints():
    env = make_train_env("state", max_cycles=6)
    env = LocalizationWrapper(env.unwrapped, reward="log_error", drop_image=True, warm_start=True)
    env.reset(seed=5)
    cap, s = env.error_cap, env.scale_m
    assert (cap, s) == (1.0, 0.01)
    seen = []
    while env.agents:
        _, rew, _, _, infos = env.step(hold(env))
        for a in rew:
            loc, terms = infos[a]["localization"], infos[a]["reward_terms"]
            if loc["success"]:
                for key, x in (("translation", loc["translation_error_m"]),
                               ("rotation", 0.1 * loc["rotation_error_deg"])):
                    expected = -min(np.log1p(x / s) / np.log1p(cap / s), 1.0)
                    assert terms[key] == pytest.approx(expected, abs=1e-12)
                seen.append(loc["translation_error_m"])
    assert len(seen) >= 10 and max(seen) < 0.5  # centimetre fixes: the steep part of the scale
    env.close()
    term = LocalizationWrapper(make_train_env("state").unwrapped, reward="log_error").reward.error_term
    assert term(0.0) == 0.0 and term(1.0) == -1.0 and term(7.0) == -1.0
    # near zero ~22x the linear slope: 1.5 cm -> 3 cm costs 0.10 a step (linear: 0.015)
    assert term(0.015) - term(0.030) == pytest.approx(0.102, abs=0.001)
    with pytest.raises(ConfigError, match="scale_m must be finite and > 0, got -1"):
        LogErrorReward(scale_m=-1)


def test_seeded_resets_repeat_with_a_noisy_detector():
    def rollout():
        env = make_train_env("state", **SMALL)
        env = LocalizationWrapper(
            env.unwrapped, association="paper", drop_image=True, miss_rate=0.2, false_positives=1.0
        )
        out = []
        obs, _ = env.reset(seed=5)
        out.append(obs["uav_1"]["pose"].copy())
        for _ in range(3):
            obs, *_ = env.step(hold(env))
            out.append(obs["uav_1"]["layout"].copy())
        env.close()
        return out

    for x, y in zip(rollout(), rollout(), strict=True):
        np.testing.assert_array_equal(x, y)


def test_robust_mode_and_other_landmark_sets():
    env = make_localization_env(
        "all", env_overrides={"image_size": (128, 72), **SMALL}, association="robust", drop_image=True
    )
    obs, infos = env.reset(seed=0, options={"viewpoint": 0})
    assert infos["uav_0"]["localization"]["success"]
    assert infos["uav_0"]["localization"]["translation_error_m"] < 1.0
    env.close()


def test_clear_errors():
    env = uav_struct_env.parallel_env("train", **SMALL)  # landmark_sets=()
    with pytest.raises(ConfigError, match="landmark_sets=\\('column_tops',\\)"):
        LocalizationWrapper(env)
    env2 = uav_struct_env.parallel_env("train", landmark_sets=("column_tops",), **SMALL)
    with pytest.raises(ConfigError, match="detector='learned' detects structural landmarks"):
        LocalizationWrapper(env2, landmarks="aruco", detector="learned")
    with pytest.raises(ConfigError, match="landmarks must be one of"):
        LocalizationWrapper(env2, landmarks="roof")
    with pytest.raises(ConfigError, match="association must be one of"):
        LocalizationWrapper(env2, association="fast")
    with pytest.raises(ConfigError, match="reward must be one of"):
        LocalizationWrapper(env2, reward="distance")
    with pytest.raises(ConfigError, match="failure_penalty must be finite and >= 0"):
        LocalizationWrapper(env2, failure_penalty=-1)
    with pytest.raises(ConfigError, match="config must be one of"):
        make_train_env("camera")
    with pytest.raises(ValueError, match="unknown agent"):
        LocalizationWrapper(env2).observation_space("uav_9")


def test_parallel_api_conformance():
    from pettingzoo.test import parallel_api_test

    env = make_train_env("state", max_cycles=5)
    parallel_api_test(env, num_cycles=6)
    env.close()


@pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")
def test_composes_with_supersuit_vector_envs():
    ss = pytest.importorskip("supersuit")
    env = make_train_env("state", **SMALL)
    vec = ss.concat_vec_envs_v1(
        ss.pettingzoo_env_to_vec_env_v1(env), 1, num_cpus=0, base_class="stable_baselines3"
    )
    assert vec.num_envs == 4
    obs = vec.reset()
    assert obs["pose"].shape == (4, 7) and "image" not in obs
    obs, rew, done, info = vec.step(np.zeros((4, 5), np.float32))
    assert rew.shape == (4,) and np.all(rew >= -env.crash_penalty - 1e-9)
    assert "localization" in info[0]
    vec.close()


def test_aruco_detector_localizes_from_the_rendered_markers():
    import uav_struct_env
    from uav_struct_env.wrappers import LocalizationWrapper

    wenv = LocalizationWrapper(uav_struct_env.parallel_env(stage="slab"), landmarks="aruco", detector="aruco")
    try:
        _, infos = wenv.reset(seed=0, options={"viewpoint": 0})
        loc = infos["uav_0"]["localization"]
        assert loc["success"] and loc["n_correspondences"] >= 4
        assert loc["translation_error_m"] < 0.5 < loc["prior_translation_error_m"]
    finally:
        wenv.close()



class InFrameDetector:
    """A user's detector (the Detector protocol): every landmark projecting into the frame,
    whether or not the simulator's truth calls it visible."""

    def detect(self, image, context):
        t = context["landmarks"]["column_tops"]
        keep = np.asarray(t["in_frame"], bool)
        return Detections(np.asarray(t["uv"])[keep], true_ids=np.asarray(t["ids"])[keep])


def _perturb_truth(base):
    """Change only ground truth in the env's infos: the true pose by 5 m, every landmark invisible."""
    reset, step = base.reset, base.step

    def patch(infos):
        for info in infos.values():
            info["world_from_cam"] = info["world_from_cam"].copy()
            info["world_from_cam"][:3, 3] += 5.0
            info["landmarks"]["column_tops"]["visible"] = np.zeros_like(
                info["landmarks"]["column_tops"]["visible"]
            )

    def new_reset(*a, **k):
        obs, infos = reset(*a, **k)
        patch(infos)
        return obs, infos

    def new_step(*a, **k):
        out = step(*a, **k)
        patch(out[-1])
        return out

    base.reset, base.step = new_reset, new_step


def test_default_observations_identical_when_only_ground_truth_changes():
    outs, infos = {}, {}
    for privileged in (False, True):
        for perturbed in (False, True):
            env = make_localization_env(
                "column_tops",
                env_overrides={"image_size": (128, 72), **SMALL},
                detector=InFrameDetector(),
                privileged=privileged,
            )
            if perturbed:
                _perturb_truth(env.unwrapped)
            obs, info = env.reset(seed=3, options={"viewpoint": 2})
            obs2, _, _, _, info2 = env.step(hold(env))
            outs[privileged, perturbed], infos[privileged, perturbed] = [obs, obs2], [info, info2]
            env.close()
    for step in range(2):
        for a, plain in outs[False, False][step].items():
            changed = outs[False, True][step][a]
            assert set(plain) == set(changed)
            for k in plain:
                np.testing.assert_array_equal(plain[k], changed[k], err_msg=k)
            assert plain["localized"][0] == 1.0 and plain["layout"][0] > 0.3  # inlier fraction
            # the truth did change: the scored error and the privileged feature see it
            e0 = infos[False, False][step][a]["localization"]["translation_error_m"]
            e1 = infos[False, True][step][a]["localization"]["translation_error_m"]
            assert abs(e1 - e0) > 1.0
            assert outs[True, False][step][a]["layout"][0] > 0.3
            assert outs[True, True][step][a]["layout"][0] == 0.0


def test_layout_centroid_and_spread_are_numpys_bit_for_bit(rng):
    """The compiled centroid / spread components equal numpy's mean / std, clipped, exactly."""
    from uav_struct_env.wrappers.layout import _centroid_spread

    for k in range(3000):
        w, h = ((128, 72), (1280, 720), (7, 5))[k % 3]
        n = int(rng.integers(1, 25))
        uv = np.column_stack([rng.uniform(-60, w + 60, n), rng.uniform(-60, h + 60, n)])
        half = np.array([w / 2.0, h / 2.0])
        want = np.concatenate([
            np.clip((uv.mean(axis=0) - (half - 0.5)) / half, -1.0, 1.0),
            np.clip(uv.std(axis=0) / half, 0.0, 2.0),
        ])
        np.testing.assert_array_equal(_centroid_spread(uv, w / 2.0, h / 2.0), want)
    got = _centroid_spread(np.array([[np.nan, 1.0], [2.0, 3.0]]), 64.0, 36.0)
    assert np.isnan(got[0]) and np.isnan(got[2]) and got[1] == np.clip((2.0 - 35.5) / 36.0, -1, 1)


def test_mode_is_still_accepted_with_a_future_warning_naming_association():
    env = uav_struct_env.parallel_env("train", landmark_sets=("column_tops",), **SMALL)
    with pytest.warns(FutureWarning, match="association="):
        wenv = LocalizationWrapper(env, mode="paper")
    assert wenv.association == "paper" and wenv.poses.spec.association == "paper"
    with pytest.raises(ConfigError, match="association= only"):
        LocalizationWrapper(env, association="paper", mode="robust")
    with pytest.warns(FutureWarning, match="'association'"):
        config = TRAIN_CONFIGS["state"].replace(wrapper={"mode": "paper"})
    assert config.wrapper["association"] == "paper" and "mode" not in config.wrapper
    with pytest.warns(FutureWarning, match="'association'"):  # a configuration saved before the rename
        old = TrainConfig.from_dict({**TRAIN_CONFIGS["state"].as_dict(), "wrapper": {"mode": "paper"}})
    assert old.wrapper == {"association": "paper"}


def test_the_wrapper_chain_is_walked_through_env_alone():
    wenv = make_localization_env(
        "column_tops", env_overrides={"observe_image": False, **SMALL}, temporal=True, warm_start=True,
    )
    layers = list(iter_chain(wenv))
    kinds = [LocalizationWrapper, RewardWrapper, LayoutObservation, FilterPoses, WarmStart, LocalizePoses]
    assert [type(layer) for layer in layers[:6]] == kinds
    assert layers[-1] is wenv.unwrapped and len(layers) == 7
    assert find_wrapper(wenv, LocalizePoses) is wenv.poses and wenv.poses.env is wenv.unwrapped
    assert find_wrapper(wenv, FilterPoses).tracks is wenv.tracks
    assert find_wrapper(wenv.poses, FilterPoses) is None
    plain = make_localization_env("column_tops", env_overrides={"observe_image": False, **SMALL})
    kinds = [RewardWrapper, LayoutObservation, LocalizePoses]
    assert [type(layer) for layer in iter_chain(plain)][1:4] == kinds
    assert plain.tracks is None and not plain.warm_start


def test_each_one_job_wrapper_needs_a_localize_poses_below():
    env = uav_struct_env.parallel_env("train", landmark_sets=("column_tops",), **SMALL)
    for cls in (WarmStart, FilterPoses, LayoutObservation, RewardWrapper):
        with pytest.raises(ConfigError, match="needs a LocalizePoses wrapper below"):
            cls(env)
    poses = LocalizePoses(env, landmarks="column_tops")
    FilterPoses(poses)
    with pytest.raises(ConfigError, match="another FilterPoses"):
        FilterPoses(poses)


def test_the_pixels_configuration_sees_camera_gnss_and_attitude_and_is_rewarded_as_image():
    pixels = make_train_env("pixels", max_cycles=3)
    image = make_train_env("image", max_cycles=3)
    try:
        space = pixels.observation_space(pixels.possible_agents[0])
        assert sorted(space.spaces) == ["attitude", "gnss", "image"]
        obs_p, _ = pixels.reset(seed=4)
        obs_i, _ = image.reset(seed=4)
        zero = {a: np.zeros(5, np.float32) for a in pixels.agents}
        obs_p, rew_p, *_, info_p = pixels.step(zero)
        obs_i, rew_i, *_, info_i = image.step(zero)
        for agent in pixels.agents:  # the same env and reward; only what the policy sees differs
            assert sorted(obs_p[agent]) == ["attitude", "gnss", "image"] and space.contains(obs_p[agent])
            np.testing.assert_array_equal(obs_p[agent]["image"], obs_i[agent]["image"])
            assert rew_p[agent] == rew_i[agent] and "pose" in obs_i[agent]
            assert info_p[agent]["reward_terms"] == info_i[agent]["reward_terms"]
    finally:
        pixels.close()
        image.close()
    env = uav_struct_env.parallel_env("train", landmark_sets=("column_tops",), **SMALL)
    with pytest.raises(ConfigError, match="cannot drop \\['altitude'\\]"):
        LocalizationWrapper(env, drop_keys=("layout", "altitude"))
    with pytest.raises(ConfigError, match="not 'layout'"):
        LocalizationWrapper(env, drop_keys="layout")
