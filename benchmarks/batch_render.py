"""The batched renderer (``renderer="batch"``) beside pybullet's TinyRenderer: agreement and throughput.

Usage::

    .venv/bin/python benchmarks/batch_render.py                       # both parts, default sizes
    .venv/bin/python benchmarks/batch_render.py --part agreement --views 500
    .venv/bin/python benchmarks/batch_render.py --part throughput --steps 400
    .venv/bin/python benchmarks/batch_render.py --part frames --views 400
    .venv/bin/python benchmarks/batch_render.py --part throughput --only "wrapped image config (64x36)"

**Agreement** (issue 41, item 1): for each world -- the paper site at both stages, random sites,
``tests/data/ifc/duplex.ifc`` at each stage, and the paper site with the busy site activity
(workers, equipment, materials) and the four airframes in the air -- ``--views`` random camera
poses (:func:`uav_struct_env.sim.batch.agreement.random_views`) at 128 x 72 are rendered by
TinyRenderer and by :func:`uav_struct_env.sim.batch.render_batch`; printed: the share of pixels
with the same body id (target >= 99 %), of landmark-views in the image with the same visibility
(target >= 99.9 %) and the mean absolute RGB difference on pixels showing the same body.

**Frames** (the ground per pixel): the CPU time of one frame rendered by
:func:`~uav_struct_env.sim.batch.render_batch` with the ground drawn per pixel (the default) and
with its ~1,700 triangles (``BatchScene(world, ground_per_pixel=False)``, the path before), the
same random views of the paper site, batches of 50 alternating, at 64 x 36 and 128 x 72.

**Throughput** (items 2 and 5): the same env configurations with ``renderer="tiny"`` and
``renderer="batch"``, stepped in alternating blocks of 20 steps with the same seeded random
actions, so a shared machine's load drifts over both alike: the ``train`` preset (4 agents,
128 x 72 cameras), the same with the busy site activity, with the Mavic 2 Pro camera
(distortion and rolling shutter by remapping), the wrapped ``image`` training configuration
(64 x 36 + localization) and, as the reference that renders nothing, the wrapped ``state`` one
(both renderers: the same env). Agent-steps per second by wall time and by the process's CPU time (the
steadier figure on a shared machine); ``uptime``'s load is printed.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
from tqdm import tqdm

import uav_struct_env
from uav_struct_env.sim.batch import BatchScene
from uav_struct_env.sim.batch.agreement import Agreement, compare, random_views

DUPLEX = "tests/data/ifc/duplex.ifc"

#: name -> env keyword arguments (the world is built with renderer="tiny").
WORLDS = {
    "paper, slab": {"stage": "slab"},
    "paper, columns": {"stage": "columns"},
    "random site (seed 1)": {"site": "random", "texture_seed": 1},
    "random site (seed 2)": {"site": "random", "texture_seed": 2},
    "random site (seed 3)": {"site": "random", "texture_seed": 3},
    "duplex.ifc, Level 2/slab": {"site": DUPLEX, "stage": "Level 2/slab", "marker_size": None},
    "duplex.ifc, Roof/slab": {"site": DUPLEX, "stage": "Roof/slab", "marker_size": None},
    "paper, columns, busy activity + airframes": {"stage": "columns", "activity": "busy"},
}

#: name -> (preset or training config, env overrides); "wrapped:" names a TRAIN_CONFIGS entry.
THROUGHPUT = {
    "train 128x72": ("train", {}),
    "train 128x72, busy activity": ("train", {"activity": "busy"}),
    "train 128x72, mavic2pro camera": ("train", {"camera": "mavic2pro"}),
    "wrapped image config (64x36)": ("wrapped:image", {}),
    "wrapped state config (no image)": ("wrapped:state", {}),  # the reference: nothing rendered
}


def agreement(views: int, seed: int = 0) -> dict[str, Agreement]:
    """Agreement per world of :data:`WORLDS` over ``views`` random views each, and in total."""
    out: dict[str, Agreement] = {}
    total = Agreement()
    print(f"{'world':44s} {'views':>6s} {'pixels equal':>13s} {'landmark-views':>15s} "
          f"{'equal':>9s} {'rgb |diff|':>10s}")
    for k, (name, kwargs) in enumerate(WORLDS.items()):
        env = uav_struct_env.parallel_env("train", renderer="tiny", image_size=(128, 72), **kwargs)
        env.reset(seed=seed + k)  # airframes and site activity placed
        world, rng = env.world, np.random.default_rng(seed + k)
        scene = BatchScene(world)
        result = Agreement()
        for _ in tqdm(range(0, views, 50), desc=name, leave=False):
            result = result + compare(world, scene, random_views(world, rng, 50), env.camera)
        env.close()
        out[name] = result
        total = total + result
        _print_row(name, result)
    _print_row("all", total)
    out["all"] = total
    return out


def _print_row(name: str, a: Agreement) -> None:
    print(f"{name:44s} {a.views:6d} {a.pixel_agreement:12.4%} {a.landmark_views:15d} "
          f"{a.landmark_agreement:8.3%} {a.rgb_mean_abs_diff:10.3f}", flush=True)


def frames(views: int, seed: int = 0, rounds: int = 5) -> dict[str, dict[str, float]]:
    """CPU ms per frame with the ground per pixel and as triangles, alternating (module docstring)."""
    from uav_struct_env.sim.batch import BatchView, render_batch
    from uav_struct_env.sim.camera import Camera

    env = uav_struct_env.parallel_env("train", renderer="tiny", stage="columns")
    env.reset(seed=seed)
    world = env.world
    scenes = {"per pixel": BatchScene(world), "triangles": BatchScene(world, ground_per_pixel=False)}
    poses = random_views(world, np.random.default_rng(seed), views)
    out: dict[str, dict[str, float]] = {}
    print(f"{'size':>8s} {'ground':>10s} {'triangles drawn':>16s} {'cpu ms per frame':>17s}")
    for w, h in ((64, 36), (128, 72)):
        camera = Camera().scaled(w, h)
        cpu = dict.fromkeys(scenes, 0.0)
        for _ in range(rounds):
            for start in range(0, views, 50):
                for name, scene in scenes.items():
                    batch = [BatchView(scene, T, camera) for T in poses[start:start + 50]]
                    c0 = time.process_time()
                    render_batch(batch)
                    cpu[name] += time.process_time() - c0
        ms = out[f"{w}x{h}"] = {name: 1e3 * t / (rounds * views) for name, t in cpu.items()}
        for name, scene in scenes.items():
            print(f"{w:4d}x{h:<3d} {name:>10s} {scene.n_triangles:16d} {ms[name]:17.4f}", flush=True)
    env.close()
    return out


def _make(spec: str, overrides: dict, renderer: str):
    if spec.startswith("wrapped:"):
        from uav_struct_env.wrappers import make_train_env

        return make_train_env(spec.split(":", 1)[1], renderer=renderer, **overrides)
    return uav_struct_env.parallel_env(spec, renderer=renderer, **overrides)


def throughput(
    steps: int, seed: int = 0, block: int = 20, only: list[str] | None = None
) -> dict[str, dict[str, dict[str, float]]]:
    """Agent-steps per second of each :data:`THROUGHPUT` entry with each renderer, alternating.

    ``only``: the names of the entries to measure (None: all).
    """
    out = {}
    print(f"{'configuration':34s} {'renderer':8s} {'agent-steps/s wall':>19s} {'cpu':>8s}")
    for name, (spec, overrides) in THROUGHPUT.items():
        if only is not None and name not in only:
            continue
        envs = {r: _make(spec, overrides, r) for r in ("tiny", "batch")}
        rngs = {r: np.random.default_rng(seed) for r in envs}
        tally = {r: np.zeros(3) for r in envs}  # wall s, cpu s, agent-steps
        for env in envs.values():
            env.reset(seed=seed)
            env.step({a: np.zeros(5, np.float32) for a in env.agents})  # warm up
        for _ in tqdm(range(max(1, steps // block)), desc=name, leave=False):
            for r, env in envs.items():
                t0, c0, n = time.perf_counter(), time.process_time(), 0
                for _ in range(block):
                    if not env.agents:
                        env.reset()
                    obs, *_ = env.step(
                        {a: rngs[r].uniform(-0.3, 0.3, 5).astype(np.float32) for a in env.agents}
                    )
                    n += len(obs)
                tally[r] += (time.perf_counter() - t0, time.process_time() - c0, n)
        out[name] = {}
        for r, (wall, cpu, n) in tally.items():
            out[name][r] = {"wall": n / wall, "cpu": n / cpu}
            print(f"{name:34s} {r:8s} {n / wall:19.0f} {n / cpu:8.0f}", flush=True)
        ratio = out[name]["batch"]["cpu"] / out[name]["tiny"]["cpu"]
        print(f"{'':34s} batch / tiny (cpu): {ratio:.2f}x", flush=True)
        for env in envs.values():
            env.close()
    return out


def main(
    part: str = "all", views: int = 500, steps: int = 400, seed: int = 0, only: list[str] | None = None
) -> dict:
    warnings.filterwarnings("ignore", "The `render_mode` attribute is not defined")
    print(f"load average (1, 5, 15 min): {os.getloadavg()}, {os.cpu_count()} cores")
    out: dict = {}
    if part in ("all", "agreement"):
        out["agreement"] = agreement(views, seed)
    if part in ("all", "frames"):
        out["frames"] = frames(views, seed)
    if part in ("all", "throughput"):
        out["throughput"] = throughput(steps, seed, only=only)
    print(f"load average (1, 5, 15 min): {os.getloadavg()}")
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("--part", default="all", choices=("all", "agreement", "frames", "throughput"),
                        help="agreement with TinyRenderer, the cost of a frame, env throughput, or all")
    parser.add_argument("--views", type=int, default=500, help="random views per world (agreement, frames)")
    parser.add_argument("--steps", type=int, default=400, help="env steps per configuration and renderer")
    parser.add_argument("--seed", type=int, default=0, help="seed of the views and sites")
    parser.add_argument("--only", action="append", choices=list(THROUGHPUT), metavar="NAME",
                        help=f"throughput: only this configuration (repeatable), one of {list(THROUGHPUT)}")
    args = parser.parse_args()
    main(args.part, args.views, args.steps, args.seed, args.only)
