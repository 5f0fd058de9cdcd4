"""TorchRL's rollout and collector on the vector env: its batched shapes, its resets, the same numbers."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl", reason="TorchRL is not installed (pip install 'uav-struct-env[rl-extra]')")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from uav_struct_env.errors import ConfigError  # noqa: E402
from uav_struct_env.vector import FINAL_OBSERVATION, make_vector_env  # noqa: E402
from uav_struct_env.vector.torchrl_env import TorchRLVectorEnv  # noqa: E402
from uav_struct_env.wrappers import FlattenObservation  # noqa: E402

pytestmark = pytest.mark.filterwarnings("ignore:The `render_mode` attribute is not defined")

K, CYCLES, STEPS = 2, 3, 7


def hover(td):
    td["uav", "action"] = torch.zeros(K, 4, 5)
    return td


def test_a_rollout_through_resets_matches_the_vector_env():
    env = TorchRLVectorEnv(make_vector_env("state", K, wrap=FlattenObservation, max_cycles=CYCLES))
    check_env_specs(env)
    env.set_seed(11)
    td = env.rollout(STEPS, policy=hover, break_when_any_done=False, auto_reset=True)
    assert td["uav", "observation"].shape == (K, STEPS, 4, 30)
    assert td["next", "uav", "info", "localization.success"].shape == (K, STEPS, 4)
    done = td["next", "done"][..., 0]
    assert done[:, CYCLES - 1].all() and done[:, 2 * CYCLES - 1].all() and done.sum() == 2 * K
    assert not td["next", "terminated"].any()  # hovering: time limits, no crash
    env.close()

    vec = make_vector_env("state", K, wrap=FlattenObservation, max_cycles=CYCLES)
    obs, _ = vec.reset(seed=11)
    for t in range(STEPS):
        np.testing.assert_array_equal(td["uav", "observation"][:, t].reshape(K * 4, -1).numpy(), obs)
        obs, rewards, _, _, infos = vec.step(np.zeros((K * 4, 5), np.float32))
        final = np.stack([i.get(FINAL_OBSERVATION, o) for i, o in zip(infos, obs, strict=True)])
        got = td["next", "uav", "observation"][:, t].reshape(K * 4, -1).numpy()
        np.testing.assert_array_equal(got, final)
        np.testing.assert_array_equal(td["next", "uav", "reward"][:, t].reshape(-1).numpy(), rewards)
        got = td["next", "uav", "info", "localization.translation_error_m"][:, t].reshape(-1).numpy()
        np.testing.assert_array_equal(got, [i["localization"]["translation_error_m"] for i in infos])
    vec.close()


def test_a_dict_observation_is_refused():
    with pytest.raises(ConfigError, match="wrap=FlattenObservation"):
        TorchRLVectorEnv(make_vector_env("state", 1))


def test_a_masked_reset_restarts_only_the_masked_env():
    env = TorchRLVectorEnv(make_vector_env("state", K, wrap=FlattenObservation, max_cycles=CYCLES))
    env.set_seed(0)
    td = env.reset()
    td = env.step(hover(td))["next"]
    before = td["uav", "observation"].clone()
    td["_reset"] = torch.tensor([[True], [False]])
    out = env.reset(td)
    assert [e.unwrapped.num_cycles for e in env.vec.envs] == [0, 1]
    assert not torch.equal(out["uav", "observation"][0], before[0])
    assert torch.equal(out["uav", "observation"][1], before[1])
    env.close()


def test_torchrls_collector_gathers_whole_batches_across_episodes():
    from torchrl.collectors import Collector

    torch.manual_seed(0)  # the collector's random policy
    env = TorchRLVectorEnv(make_vector_env("state", K, wrap=FlattenObservation, max_cycles=CYCLES))
    env.set_seed(0)
    collector = Collector(env, policy=None, frames_per_batch=4 * K, total_frames=8 * K)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2 and batches[0]["uav", "action"].shape == (K, 4, 4, 5)
    done = torch.cat([b["next", "done"] for b in batches], dim=1)[..., 0]
    assert done[:, CYCLES - 1].all() and done[:, 2 * CYCLES - 1].all()
    assert torch.cat([b["uav", "info", "localization.success"] for b in batches], 1).shape == (K, 8, 4)
