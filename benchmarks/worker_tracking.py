"""Worker tracking: CPU time of one tracking step and its error with true poses, light and busy sites.

For the paper's scripted viewpoints of the columns stage with site activity, the four cameras
detect the workers (simulated detector, 2 px at 1280 px, 5 % misses, occlusion-tested) and
``tracking.track_workers`` associates and triangulates them from the true camera poses. Prints per
activity the workers, the tracked observations, the median / P95 3D error and the CPU time
(``time.process_time``, median and max over repeats) of ``track_workers`` alone, with the load
average (the machine is shared).

    .venv/bin/python benchmarks/worker_tracking.py --viewpoints 6 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import uav_struct_env
from localization.geometry.transforms import invert
from tracking import error_summary, track_workers, worker_errors
from uav_struct_env.tracking_sim import SimulatedWorkerDetector, camera_views


def main(viewpoints: int = 6, repeats: int = 3, upright: bool = False) -> dict:
    out = {}
    for activity in ("light", "busy"):
        env = uav_struct_env.parallel_env(activity=activity, observe_image=False, stage="columns",
                                          landmark_sets=())
        times, errors, present = [], [], 0
        try:
            for vp in range(viewpoints):
                _, infos = env.reset(seed=vp, options={"viewpoint": vp})
                points = env.worker_points()
                present += len(points)
                det = SimulatedWorkerDetector(rng=np.random.default_rng(vp))
                dets = {a: det.detect(points, env.worker_visibility(a), infos[a]["intrinsics"],
                                      invert(infos[a]["world_from_cam"]), env.config.image_size)
                        for a in env.agents}
                views = camera_views(infos, "truth")
                for _ in range(repeats):
                    t0 = time.process_time()
                    result = track_workers(views, dets, height_range=(1.0, 2.3), upright=upright)
                    times.append(time.process_time() - t0)
                errors.extend(worker_errors(result, points))
        finally:
            env.close()
        s = error_summary(errors)
        cpu = 1000 * float(np.median(times)), 1000 * max(times)
        out[activity] = {"cpu_ms_median": cpu[0], "cpu_ms_max": cpu[1], **s}
        print(f"{activity:5s}: {present} worker-viewpoints, {s['n_observations']} tracked, error median "
              f"{s['median_m']:.3f} / P95 {s['p95_m']:.3f} m; track_workers CPU {cpu[0]:.1f} ms median, "
              f"{cpu[1]:.1f} ms max")
    print(f"load average {os.getloadavg()[0]:.1f}")
    return out


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--viewpoints", type=int, default=6, help="viewpoints per UAV")
    p.add_argument("--repeats", type=int, default=3, help="timed repeats (the median is reported)")
    p.add_argument("--upright", action="store_true", help="triangulate workers standing")
    a = p.parse_args()
    main(a.viewpoints, a.repeats, a.upright)
