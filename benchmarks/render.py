"""Rendering benchmark: ms per frame for each backend and image size, with/without segmentation.

    .venv/bin/python benchmarks/render.py [--repeats 10] [--backends tiny egl] [--stage columns]

Renders the paper site from 25 m south, 15 m up (the study's viewing geometry) and prints a
table of the median time per ``SiteWorld.render`` call (RGB + metric depth, as the environment
uses it) and the scene load time of each backend. A benchmark, not a test: numbers depend on the
machine and on what else runs on it.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np

from localization.geometry.transforms import look_at
from uav_struct_env.errors import RendererUnavailableError
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site

SIZES = ((1280, 720), (640, 360), (128, 72))


def main(
    repeats: int = 10,
    backends: tuple[str, ...] = ("tiny", "egl"),
    sizes: tuple[tuple[int, int], ...] = SIZES,
    stage: str = "columns",
) -> list[dict]:
    """Run the benchmark, print the table and return its rows."""
    site = paper_site(stage)
    centre = site.center
    pose = look_at(centre + [0.0, -25.0, 15.0 - centre[2]], centre)
    rows: list[dict] = []
    loads: list[tuple[str, float, float]] = []
    for backend in backends:
        t0 = time.perf_counter()
        try:
            world = SiteWorld(site, renderer=backend, rng=np.random.default_rng(0))
        except RendererUnavailableError as exc:
            warnings.warn(f"skipping {backend}: {exc}", stacklevel=1)
            continue
        with world:
            t1 = time.perf_counter()
            world.render(pose, Camera(), depth=True)  # first frame uploads textures
            first = time.perf_counter() - t1
            loads.append((backend, t1 - t0, first))
            for width, height in sizes:
                camera = Camera().scaled(width, height)
                for segmentation in (False, True):
                    world.render(pose, camera, depth=True, segmentation=segmentation)  # warm-up
                    times = []
                    for _ in range(repeats):
                        t = time.perf_counter()
                        world.render(pose, camera, depth=True, segmentation=segmentation)
                        times.append(time.perf_counter() - t)
                    rows.append({
                        "backend": backend, "size": f"{width}x{height}",
                        "segmentation": segmentation,
                        "ms": 1e3 * statistics.median(times), "ms_min": 1e3 * min(times),
                    })
    print(f"paper site, stage {stage!r}; median (min) ms per render (RGB + depth), "
          f"{repeats} frames")
    print(f"{'backend':8} {'size':>9}  {'no segmentation':>17}  {'with segmentation':>17}")
    for backend in dict.fromkeys(r["backend"] for r in rows):
        for width, height in sizes:
            size = f"{width}x{height}"
            cells = []
            for seg in (False, True):
                (r,) = [r for r in rows if r["backend"] == backend and r["size"] == size
                        and r["segmentation"] == seg]
                cells.append(f"{r['ms']:8.1f} ({r['ms_min']:6.1f})")
            print(f"{backend:8} {size:>9}  {cells[0]:>17}  {cells[1]:>17}")
    for backend, load, first in loads:
        print(f"scene load ({backend}): {load:.2f} s (textures, meshes, pybullet); "
              f"first 1280x720 frame {1e3 * first:.0f} ms")
    return rows


def _size(text: str) -> tuple[int, int]:
    w, h = text.lower().split("x")
    return int(w), int(h)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--repeats", type=int, default=10, help="frames timed per cell")
    parser.add_argument("--backends", nargs="+", default=["tiny", "egl"], choices=["tiny", "egl"],
                        help="renderers to time")
    parser.add_argument("--sizes", nargs="+", type=_size, default=list(SIZES),
                        help="image sizes as WxH")
    parser.add_argument("--stage", default="columns", choices=["slab", "columns"],
                        help="the paper building's stage")
    args = parser.parse_args()
    main(repeats=args.repeats, backends=tuple(args.backends), sizes=tuple(args.sizes),
         stage=args.stage)
