"""Throughput of the LocalizationWrapper at a training configuration, in agent-steps per second.

Measures, in this process (one core), the bare env with the landmark truth the wrapper needs and
the wrapped env, under the same seeded actions (``hold``: hover; ``random``: uniform; a crash
ends the episode and the next one starts). One agent-step is one agent's observation.

    .venv/bin/python benchmarks/wrapper_throughput.py --config state --steps 400
    .venv/bin/python benchmarks/wrapper_throughput.py --config state --mode robust  # association
    .venv/bin/python benchmarks/wrapper_throughput.py --config state --render-images  # as before
                                                 # ray-cast visibility: frames rendered and dropped

Other processes sharing the machine's 2 cores lower the figure; ``uptime``'s load is printed.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np


def measure(env, steps: int, policy: str, seed: int) -> tuple[float, int, float]:
    """(agent-steps per second, agent-steps, CPU seconds) over at least ``steps`` agent-steps."""
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    n = 0
    t0, c0 = time.perf_counter(), time.process_time()
    episode = 0
    while n < steps:
        if not env.agents:
            episode += 1
            env.reset(seed=seed + episode)
        acts = {
            a: (rng.uniform(-1, 1, 5) if policy == "random" else np.zeros(5)).astype(np.float32)
            for a in env.agents
        }
        obs, *_ = env.step(acts)
        n += len(obs)
    return n / (time.perf_counter() - t0), n, time.process_time() - c0


def main(config: str = "state", steps: int = 400, policy: str = "hold", seed: int = 0,
         render_images: bool = False, mode: str | None = None) -> dict:
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    from uav_struct_env.wrappers import make_train_env
    from uav_struct_env.wrappers.configs import TRAIN_CONFIGS

    train = TRAIN_CONFIGS[config]
    if mode is not None:  # the association mode of the named config, overridden
        train = train.replace(wrapper={"mode": mode})
    wrapped = make_train_env(train, **({"observe_image": True} if render_images else {}))
    bare = wrapped.env
    measure(wrapped, 40, policy, seed)  # build the world, warm caches
    bare_rate, _, bare_cpu = measure(bare, steps, policy, seed)
    rate, n, cpu = measure(wrapped, steps, policy, seed)
    wrapped.close()
    out = {
        "config": config,
        "mode": train.wrapper["mode"],
        "policy": policy,
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
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="state")
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--policy", default="hold", choices=("hold", "random"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--render-images", action="store_true",
                   help="render every frame even if the config drops it (the depth-tested truth)")
    p.add_argument("--mode", default=None, choices=("paper", "robust"),
                   help="association mode (default: the config's)")
    main(**vars(p.parse_args()))
