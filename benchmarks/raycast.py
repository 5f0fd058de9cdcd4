"""Ray-cast landmark visibility against the rendered depth test: agreement and time per view.

For random views of several sites (the paper's at both stages, random layouts, and the duplex
IFC when ifcopenshell is installed), with a UAV airframe placed in the line of sight, every
landmark set's visibility is decided twice: on the rendered depth image
(``SiteWorld.landmark_truth``) and by ray casting (``SiteWorld.landmark_truth_raycast``). Prints
the in-frame landmark-views, how many disagree, and the milliseconds per view of each.

    .venv/bin/python benchmarks/raycast.py --views 60 --renderer tiny
    .venv/bin/python benchmarks/raycast.py --views 60 --renderer egl
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from localization.geometry.transforms import look_at
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site, random_site

SETS = ("slab_corners", "opening_corners", "column_tops", "aruco")
DUPLEX = Path(__file__).resolve().parents[1] / "tests" / "data" / "ifc" / "duplex.ifc"


def sites() -> list:
    out = [paper_site("columns"), paper_site("slab")]
    out += [random_site(np.random.default_rng(s)) for s in range(3)]
    try:
        from uav_struct_env.site import load_ifc

        out.append(load_ifc(DUPLEX, "Level 2/slab"))
    except (ImportError, ValueError):  # no ifcopenshell (the ifc extra): no IFC site
        pass
    return out


def main(views: int = 60, renderer: str = "tiny") -> dict:
    total = disagree = 0
    t_render = t_rays = 0.0
    examples = []
    all_sites = sites()
    for k, site in enumerate(all_sites):
        rng = np.random.default_rng(k)
        camera = Camera().scaled(128, 72) if k % 2 else Camera().scaled(640, 360)
        with SiteWorld(site, renderer=renderer, image_size=(camera.width, camera.height)) as world:
            body = world.add_body((0.161, 0.121, 0.042))
            c = np.asarray(site.center)
            for v in range(views):
                az, r = rng.uniform(0, 2 * np.pi), rng.uniform(8, 45)
                eye = np.array([c[0] + r * np.cos(az), c[1] + r * np.sin(az), rng.uniform(3, 35)])
                T = look_at(eye, c + rng.uniform(-5, 5, 3))
                B = np.eye(4)
                B[:3, 3] = eye + (c - eye) * rng.uniform(0.05, 0.3)
                world.move_body(body, B)
                t0 = time.perf_counter()
                rendered = world.render(T, camera, depth=True)
                depth_truth = {n: world.landmark_truth(n, T, camera, rendered) for n in SETS}
                t_render += time.perf_counter() - t0
                t0 = time.perf_counter()
                ray_truth = {n: world.landmark_truth_raycast(n, T, camera) for n in SETS}
                t_rays += time.perf_counter() - t0
                for n in SETS:
                    a, b = depth_truth[n], ray_truth[n]
                    total += int(a["in_frame"].sum())
                    bad = np.flatnonzero((a["visible"] != b["visible"]) & a["in_frame"])
                    disagree += len(bad)
                    examples += [(site.name, v, n, bool(a["visible"][i])) for i in bad]
    n_views = views * len(all_sites)
    out = {
        "renderer": renderer, "sites": len(all_sites), "views": n_views,
        "landmark_views_in_frame": total, "disagree": disagree,
        "agreement_percent": 100.0 * (1 - disagree / max(total, 1)),
        "render_and_depth_test_ms_per_view": 1e3 * t_render / n_views,
        "raycast_ms_per_view": 1e3 * t_rays / n_views,
        "load_average_1min": os.getloadavg()[0],
    }
    for key, value in out.items():
        print(f"{key:36s} {value:.4g}" if isinstance(value, float) else f"{key:36s} {value}")
    for e in examples[:20]:
        print("disagreement (site, view, set, depth test says visible):", e)
    return out


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--views", type=int, default=60, help="random views per site")
    p.add_argument("--renderer", default="tiny", choices=("tiny", "egl"),
                   help="pybullet renderer of the depth-tested reference")
    main(**vars(p.parse_args()))
