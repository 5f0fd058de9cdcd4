"""Throughput of the LocalizationWrapper at a training configuration, in agent-steps per second.

Measures, in this process (one core), the bare env with the landmark truth the wrapper needs and
the wrapped env, under the same seeded actions (``hold``: hover; ``random``: uniform; a crash
ends the episode and the next one starts). One agent-step is one agent's observation.

    .venv/bin/python benchmarks/wrapper_throughput.py --config state --steps 400
    .venv/bin/python benchmarks/wrapper_throughput.py --config state --mode robust  # association
    .venv/bin/python benchmarks/wrapper_throughput.py --config state --no-warm-start  # search
                                                 # every frame (the configs start from the last pose)
    .venv/bin/python benchmarks/wrapper_throughput.py --config state --render-images  # as before
                                                 # ray-cast visibility: frames rendered and dropped
    .venv/bin/python benchmarks/wrapper_throughput.py --config state --model runs/ppo_state

What an agent-step costs depends on what the cameras see: ``hold`` keeps the random starts'
views (about two in three see the layout), ``random`` flies away from it (few landmarks, cheap),
and a trained policy faces the building and approaches it (every column top in view: the costly
case, and the one a long training run spends its time in). ``--model`` (a folder of
``examples/train_viewpoint_ppo.py``) first records the policy's deterministic actions on the
wrapped env, episode by episode, then replays them on the bare and the wrapped env from the same
seeds, so both see the same flights and the policy's own inference is not timed.

Other processes sharing the machine's 2 cores lower the figure; ``uptime``'s load is printed.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np


def measure(env, steps: int, policy: str | list, seed: int) -> tuple[float, int, float]:
    """(agent-steps per second, agent-steps, CPU seconds) over at least ``steps`` agent-steps.

    ``policy``: ``"hold"``, ``"random"``, or recorded episodes (:func:`record`), replayed in turn.
    """
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    n = 0
    t0, c0 = time.perf_counter(), time.process_time()
    episode, t = 0, 0
    while n < steps:
        if not env.agents or (isinstance(policy, list) and t == len(policy[episode % len(policy)])):
            episode, t = episode + 1, 0
            env.reset(seed=seed + episode % len(policy) if isinstance(policy, list) else seed + episode)
        if isinstance(policy, list):
            acts = {a: policy[episode % len(policy)][t][a] for a in env.agents}
        else:
            acts = {
                a: (rng.uniform(-1, 1, 5) if policy == "random" else np.zeros(5)).astype(np.float32)
                for a in env.agents
            }
        obs, *_ = env.step(acts)
        n, t = n + len(obs), t + 1
    return n / (time.perf_counter() - t0), n, time.process_time() - c0


def record(env, model: str, episodes: int, seed: int) -> list[list[dict[str, np.ndarray]]]:
    """The deterministic actions of the trained policy in ``model`` on ``episodes`` episodes of the
    wrapped ``env`` (seeds ``seed``, ``seed + 1``, ...): per episode, per step, per agent."""
    from pathlib import Path

    from uav_struct_env.errors import UsageError
    from uav_struct_env.training.policy_files import NORMALIZATION_FILE, load_normalization, load_ppo

    folder = Path(model)
    agent = env.possible_agents[0]
    try:
        ppo = load_ppo(folder / "model.zip", env.observation_space(agent), env.action_space(agent))
        norm = load_normalization(folder / NORMALIZATION_FILE)
    except (ValueError, OSError) as err:
        raise UsageError(f"--model {model!r}: {err}") from None
    out = []
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + e)
        actions = []
        while env.agents:
            batch = norm({k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]})
            act, _ = ppo.predict(batch, deterministic=True)
            actions.append({a: act[i].astype(np.float32) for i, a in enumerate(env.agents)})
            obs, *_ = env.step(actions[-1])
        out.append(actions)
    return out


def main(config: str = "state", steps: int = 400, policy: str = "hold", seed: int = 0,
         render_images: bool = False, mode: str | None = None, model: str | None = None,
         episodes: int = 20, warm_start: bool | None = None) -> dict:
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    from uav_struct_env.wrappers import make_train_env
    from uav_struct_env.wrappers.configs import TRAIN_CONFIGS

    train = TRAIN_CONFIGS[config]
    if mode is not None:  # the association mode of the named config, overridden
        train = train.replace(wrapper={"association": mode})
    if warm_start is not None:  # the config's warm start, overridden
        train = train.replace(wrapper={"warm_start": warm_start})
    wrapped = make_train_env(train, **({"observe_image": True} if render_images else {}))
    bare = wrapped.unwrapped
    actions = record(wrapped, model, episodes, seed) if model is not None else policy
    measure(wrapped, 40, actions, seed)  # build the world, warm caches
    bare_rate, _, bare_cpu = measure(bare, steps, actions, seed)
    rate, n, cpu = measure(wrapped, steps, actions, seed)
    wrapped.close()
    out = {
        "config": config,
        "mode": train.wrapper["association"],
        "warm_start": train.wrapper.get("warm_start", False),
        "policy": f"trained ({model}, {episodes} episodes replayed)" if model is not None else policy,
        "observe_image": wrapped.unwrapped.config.observe_image,
        "agent_steps": n,
        "env_agent_steps_per_s": bare_rate,
        "wrapped_agent_steps_per_s": rate,
        "localization_ms_per_agent_step": 1e3 * (1 / rate - 1 / bare_rate),
        "env_cpu_ms_per_agent_step": 1e3 * bare_cpu / n,
        "wrapped_cpu_ms_per_agent_step": 1e3 * cpu / n,
        "load_average_1min": os.getloadavg()[0],
        "cpu_count": os.cpu_count(),
    }
    for k, v in out.items():
        print(f"{k:34s} {v:.4g}" if isinstance(v, float) else f"{k:34s} {v}")
    return out


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--config", default="state", help="TRAIN_CONFIGS name")
    p.add_argument("--steps", type=int, default=400, help="env steps timed")
    p.add_argument("--policy", default="hold", choices=("hold", "random"),
                   help="actions: hold (hover) or random")
    p.add_argument("--seed", type=int, default=0, help="env seed")
    p.add_argument("--render-images", action="store_true",
                   help="render every frame even if the config drops it (the depth-tested truth)")
    p.add_argument("--mode", default=None, choices=("paper", "robust"),
                   help="association mode; None: the config's")
    p.add_argument("--model", default=None,
                   help="a trained policy's folder (train_viewpoint_ppo.py --out): its actions, replayed")
    p.add_argument("--episodes", type=int, default=20, help="episodes recorded with --model")
    p.add_argument("--warm-start", action=argparse.BooleanOptionalAction, default=None,
                   help="start each association from the last pose and the action ; None: the config's")
    args = p.parse_args()
    if args.episodes < 1:
        p.error(f"--episodes must be at least 1, got {args.episodes}")
    main(**vars(args))
