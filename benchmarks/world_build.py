"""Building a site's world: the first one in a process, the next ones, and the memory they hold.

A ``SiteWorld`` builds its site's meshes and textures (``site.mesh.site_elements``), formats them
as OBJ + MTL + BMP files and loads them into its pybullet client. Worlds of the same site, seed and
texture size in one process (envs made again with the same settings, a test suite's episodes) share the
meshes and textures (``site.mesh.shared_site_elements``) and their formatted files. This prints,
per site and texture size, the CPU and wall milliseconds of the first world and the median of the
next ``--worlds`` (all of the same seed, each kept open), and the resident memory they add,
with the sharing on and off (``--no-share`` alone: the behaviour before 2026-11-29).

    .venv/bin/python benchmarks/world_build.py
    .venv/bin/python benchmarks/world_build.py --worlds 16 --texture-size 512
"""

from __future__ import annotations

import argparse
import multiprocessing
import resource
import statistics
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import mesh, paper_site, random_site


def _rss_mb() -> float:
    """Resident memory now, MB (Linux: /proc; elsewhere the peak, an upper bound)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * resource.getpagesize() / 1e6
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def build(site, worlds: int, texture_size: int) -> dict:
    """``worlds`` + 1 worlds of ``site`` held open together: the first's and the next ones' times."""
    held, cpu, wall = [], [], []
    rss0 = _rss_mb()
    try:
        for _ in range(worlds + 1):
            c, t = time.process_time(), time.perf_counter()
            held.append(SiteWorld(site, renderer="tiny", image_size=(128, 72), texture_size=texture_size,
                                  rng=np.random.default_rng(0)))
            cpu.append(1e3 * (time.process_time() - c))
            wall.append(1e3 * (time.perf_counter() - t))
        rss = _rss_mb() - rss0
    finally:
        for w in held:
            w.close()
    return {"first_cpu_ms": cpu[0], "first_wall_ms": wall[0], "next_cpu_ms": statistics.median(cpu[1:]),
            "next_wall_ms": statistics.median(wall[1:]), "mb_per_world": rss / len(held)}


def run_mode(keep: int, worlds: int, texture_size: int) -> list[dict]:
    """Every site's row with ``SHARED_SITES = keep`` (0: not shared), after a warm-up world."""
    mesh.SHARED_SITES = keep
    SiteWorld(paper_site("slab"), renderer="tiny", image_size=(128, 72), texture_size=16).close()  # imports
    sites = {"paper (columns)": paper_site("columns"), "random site 0": random_site(np.random.default_rng(0))}
    return [{"site": name, "elements": len(site.built), **build(site, worlds, texture_size)}
            for name, site in sites.items()]


def main(worlds: int = 8, texture_size: int = 512, share: bool = True) -> list[dict]:
    """Each mode in a fresh process (so that the memory of one does not serve the other)."""
    modes = (("shared", mesh.SHARED_SITES), ("not shared", 0)) if share else (("not shared", 0),)
    print(f"{worlds + 1} worlds of each site held open, texture size {texture_size} px, TinyRenderer")
    print("| site | elements | first world: cpu / wall ms | next worlds (median): cpu / wall ms "
          "| MB per world |")
    print("|---|---:|---:|---:|---:|")
    rows = []
    for mode, keep in modes:
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            for r in pool.submit(run_mode, keep, worlds, texture_size).result():
                r["site"] = f"{r['site']}, {mode}"
                rows.append(r)
                print(f"| {r['site']} | {r['elements']} | {r['first_cpu_ms']:.0f} / "
                      f"{r['first_wall_ms']:.0f} | {r['next_cpu_ms']:.0f} / {r['next_wall_ms']:.0f} | "
                      f"{r['mb_per_world']:.1f} |")
    return rows


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--worlds", type=int, default=8, help="worlds built after the first, per site and mode")
    p.add_argument("--texture-size", type=int, default=512,
                   help="the worlds' texture_size (the env's default)")
    p.add_argument("--no-share", dest="share", action="store_false",
                   help="only the unshared build (every world its own meshes, textures and files)")
    a = p.parse_args()
    main(a.worlds, a.texture_size, a.share)
