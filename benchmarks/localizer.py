"""Benchmark of the localization package on the paper's building with synthetic detections.

Prints three tables:

1. the Cramér-Rao bound per landmark set (median over the viewpoints of several per-image
   scalars), beside docs/design.md's quoted figures;
2. accuracy, association quality and latency of ``paper`` and ``robust`` association, for known
   correct detections (1 px noise) and for 10 % missed detections + one false positive per image
   (Poisson mean 1); the last condition repeats that with Gaussian prior errors of the same
   sigmas instead of the paper's exact +-3 m / 2 / 2 / 5 deg;
3. the ArUco baseline (0.5 m and 1.0 m markers; ``average`` and ``joint``) on synthetic marker
   images rendered from the same kind of viewpoints.

Protocol (docs/design.md): camera 1280x720, fx = fy = 1108.5; viewpoints 15-35 m horizontally from the
building centre, 10-25 m up, one per side in turn, aimed at the building; prior = truth + 3 m per
axis, 2 deg roll and pitch, 5 deg yaw with alternating signs (attitude convention of
``uav_struct_env.sim.attitude``). Latency is the CPU time of ``Localizer.localize`` (association +
PnP + covariance) on this thread, i.e. one core.

    .venv/bin/python benchmarks/localizer.py --images 200 --seed 0
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import json
import time

import cv2
import numpy as np

from localization import (
    ArucoLocalizer,
    cramer_rao_bound,
    pose_errors,
    recall_at,
    summarize_errors,
)
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import invert
from localization.testing.synthetic import landmark_context, render_aruco_image, sample_viewpoints
from uav_struct_env.sim.attitude import (
    attitude_from_world_from_cam,
    world_from_cam_from_attitude,
)
from uav_struct_env.site import paper_site
from uav_struct_env.stack import StackSpec, build_stack

SETS = ("slab_corners", "opening_corners", "column_tops", "all")
#: docs/design.md, "Facts measured": median Cramér-Rao bound, position m / rotation deg.
DESIGN_CRB = {
    "slab_corners": (0.14, 0.28),
    "opening_corners": (0.55, 1.07),
    "column_tops": (0.11, 0.22),
    "all": (0.07, 0.15),
}
#: name -> (miss rate, false positives per image, prior law)
CONDITIONS = {
    "clean": (0.0, 0.0, "paper"),
    "miss10+fp1": (0.1, 1.0, "paper"),
    "m10+fp1+gauss": (0.1, 1.0, "gaussian"),
}


def paper_prior(cam_from_world: np.ndarray, index: int) -> np.ndarray:
    """Truth + 3 m per axis, 2 deg roll/pitch, 5 deg yaw; signs alternate with ``index``."""
    s = [1.0 if (index >> k) & 1 == 0 else -1.0 for k in range(4)]
    position, attitude = attitude_from_world_from_cam(invert(cam_from_world))
    position = position + 3.0 * np.array(s[:3])
    attitude = attitude + np.radians([2.0 * s[3], 2.0 * -s[0], 5.0 * -s[1]])
    return invert(world_from_cam_from_attitude(position, attitude))


def gaussian_prior(cam_from_world: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Truth + Gaussian errors with the same sigmas (3 m per axis; 2, 2, 5 deg), not +-1 sigma."""
    position, attitude = attitude_from_world_from_cam(invert(cam_from_world))
    position = position + rng.normal(0.0, 3.0, 3)
    attitude = attitude + np.radians(rng.normal(0.0, [2.0, 2.0, 5.0]))
    return invert(world_from_cam_from_attitude(position, attitude))


def crb_table(views, site) -> list[dict]:
    rows = []
    z = np.random.default_rng(0).normal(size=(4000, 3))
    for name in SETS:
        ls = site.landmarks(name)
        vals = []
        for T in views:
            ctx = landmark_context(PAPER_K, T, {name: (ls.ids, ls.xyz)})
            vis = ctx["landmarks"][name]["visible"]
            b = cramer_rao_bound(ls.xyz[vis], T, PAPER_K, 1.0)
            if not np.isfinite(b.position_rms_m):
                continue
            Lp = np.linalg.cholesky(b.covariance[:3, :3])
            Lr = np.linalg.cholesky(b.covariance[3:, 3:])
            vals.append(
                [
                    b.position_rms_m,
                    np.median(np.linalg.norm(z @ Lp.T, axis=1)),
                    b.position_max_std_m,
                    b.rotation_rms_deg,
                    np.degrees(np.median(np.linalg.norm(z @ Lr.T, axis=1))),
                    np.degrees(np.sqrt(np.max(np.linalg.eigvalsh(b.covariance[3:, 3:])))),
                ]
            )
        med = np.median(np.array(vals), axis=0)
        rows.append({"set": name, "n": len(vals), "values": med.tolist()})
    return rows


def run_structural(views, site, name, mode, miss, fp, seed, prior_law="paper") -> dict:
    ls = site.landmarks(name)
    # The stack the study and the wrapper use (at the paper's width their gate policies agree).
    spec = StackSpec(landmarks=name, association=mode, pixel_sigma=1.0, miss_rate=miss, false_positives=fp)
    stack = build_stack(
        spec, PAPER_K, PAPER_IMAGE_SIZE, model_xyz=ls.xyz, model_ids=ls.ids, rng=np.random.default_rng(seed)
    )
    detector, loc = stack.detector, stack.localizer
    prior_rng = np.random.default_rng(seed + 100)
    te, re, ok, crb, cpu = [], [], [], [], []
    correct = assigned = true_det = found = visible = 0
    for k, T in enumerate(views):
        ctx = landmark_context(PAPER_K, T, {name: (ls.ids, ls.xyz)})
        det = detector.detect(None, ctx)
        prior = paper_prior(T, k) if prior_law == "paper" else gaussian_prior(T, prior_rng)
        t0 = time.thread_time()
        est = loc.localize(det.uv, prior)
        cpu.append(time.thread_time() - t0)
        t, r = pose_errors(est.cam_from_world, T)
        te.append(t)
        re.append(r)
        ok.append(est.success)
        vis = ctx["landmarks"][name]["visible"]
        crb.append(cramer_rao_bound(ls.xyz[vis], T, PAPER_K).position_rms_m)
        a = est.assignment
        ids_assigned = np.where(a >= 0, ls.ids[np.maximum(a, 0)], -1)
        correct += int(np.sum((a >= 0) & (ids_assigned == det.true_ids)))
        assigned += int(np.sum(a >= 0))
        true_det += int(np.sum(det.true_ids >= 0))
        found += np.intersect1d(ls.ids[vis], det.true_ids).size
        visible += int(vis.sum())
    s = summarize_errors(te, re, ok)
    p = correct / assigned if assigned else float("nan")
    r = correct / true_det if true_det else float("nan")
    rec = recall_at(te, re, ok)
    return {
        "summary": s.as_dict(),
        "crb_position_median_m": float(np.median(crb)),
        "recall_0.25m_1deg": rec[(0.25, 1.0)],
        "recall_0.5m_2deg": rec[(0.5, 2.0)],
        "detection_rate": found / visible if visible else float("nan"),
        "association": {"precision": p, "recall": r, "f1": 2 * p * r / (p + r) if p + r else 0.0},
        "latency_cpu_s": {"median": float(np.median(cpu)), "p90": float(np.percentile(cpu, 90))},
    }


def run_aruco(views, side, mode) -> dict:
    site = paper_site(stage="columns", marker_size=side)
    markers = [(m.id, m.side, m.world_from_marker) for m in site.markers]
    loc = ArucoLocalizer(site.markers, PAPER_K, mode=mode)
    te, re, ok, cpu = [], [], [], []
    for k, T in enumerate(views):
        img = render_aruco_image(markers, PAPER_K, T)
        t0 = time.thread_time()
        est = loc.localize(img, paper_prior(T, k))
        cpu.append(time.thread_time() - t0)
        t, r = pose_errors(est.cam_from_world, T)
        te.append(t)
        re.append(r)
        ok.append(est.success)
    return {
        "summary": summarize_errors(te, re, ok).as_dict(),
        "latency_cpu_s": {"median": float(np.median(cpu))},
    }


def main(images: int = 200, aruco_images: int = 40, seed: int = 0, json_out: str | None = None):
    cv2.setNumThreads(1)
    site = paper_site(stage="columns", marker_size=1.0)
    views = sample_viewpoints(np.random.default_rng(seed), images, site.center)
    results: dict = {"config": {"images": images, "aruco_images": aruco_images, "seed": seed}}

    print(f"Cramér-Rao bound, 1 px, median over {images} viewpoints (15-35 m out, 10-25 m up)")
    print(
        f"{'set':16s} {'pos RMS':>8s} {'pos med|e|':>10s} {'pos maxstd':>10s}   "
        f"{'rot RMS':>8s} {'rot med|e|':>10s} {'rot maxstd':>10s}   docs/design.md"
    )
    results["crb"] = crb_table(views, site)
    for row in results["crb"]:
        v = row["values"]
        d = DESIGN_CRB[row["set"]]
        print(
            f"{row['set']:16s} {v[0]:7.3f}m {v[1]:9.3f}m {v[2]:9.3f}m   "
            f"{v[3]:7.3f}° {v[4]:9.3f}° {v[5]:9.3f}°   {d[0]:.2f} m / {d[1]:.2f}°"
        )

    print()
    print("Structural landmarks: errors over successful poses (median / P90); association pooled")
    hdr = (
        f"{'set':16s} {'condition':13s} {'mode':7s} {'ok':>8s} {'t med':>7s} {'t P90':>8s} "
        f"{'r med':>6s} {'r P90':>7s} {'CRB':>6s} {'med/CRB':>7s} {'R@.25/1':>7s} "
        f"{'det':>5s} {'assocP':>6s} {'assocR':>6s} {'F1':>6s} {'cpu ms':>7s} {'P90':>6s}"
    )
    print(hdr)
    results["structural"] = {}
    for name in SETS:
        for cond, (miss, fp, law) in CONDITIONS.items():
            if law != "paper" and name not in ("column_tops", "all"):
                continue
            for mode in ("paper", "robust"):
                r = run_structural(views, site, name, mode, miss, fp, seed + 1, law)
                results["structural"][f"{name}/{cond}/{mode}"] = r
                s = r["summary"]
                t, rot = s["translation_error_m"], s["rotation_error_deg"]
                a = r["association"]
                print(
                    f"{name:16s} {cond:13s} {mode:7s} {s['successful']:>4d}/{s['total']:<3d} "
                    f"{t['median']:6.3f}m {t['p90']:7.3f}m {rot['median']:5.2f}° "
                    f"{rot['p90']:6.2f}° {r['crb_position_median_m']:5.3f}m "
                    f"{t['median'] / r['crb_position_median_m']:7.2f} "
                    f"{r['recall_0.25m_1deg']:7.2f} {r['detection_rate']:5.2f} "
                    f"{a['precision']:6.3f} {a['recall']:6.3f} {a['f1']:6.3f} "
                    f"{1e3 * r['latency_cpu_s']['median']:7.2f} "
                    f"{1e3 * r['latency_cpu_s']['p90']:6.2f}"
                )

    if aruco_images > 0:
        print()
        print(f"ArUco baseline on {aruco_images} synthetic marker images (same viewpoint law)")
        aviews = sample_viewpoints(np.random.default_rng(seed + 2), aruco_images, site.center)
        results["aruco"] = {}
        for side in (0.5, 1.0):
            for mode in ("average", "joint"):
                r = run_aruco(aviews, side, mode)
                results["aruco"][f"aruco_{side}m/{mode}"] = r
                s = r["summary"]
                t, rot = s["translation_error_m"], s["rotation_error_deg"]
                print(
                    f"aruco_{side}m {mode:8s} {s['successful']:>3d}/{s['total']:<3d} "
                    f"t {t['median']:6.3f} / {t['p90']:6.3f} m   "
                    f"r {rot['median']:5.2f} / {rot['p90']:5.2f}°   "
                    f"cpu {1e3 * r['latency_cpu_s']['median']:.1f} ms (incl. detection)"
                )
    if json_out:
        with open(json_out, "w") as f:
            json.dump(results, f, indent=1)
    return results


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--images", type=int, default=200, help="viewpoints per configuration")
    ap.add_argument("--aruco-images", type=int, default=40, help="rendered ArUco views (0: skip)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the synthetic scenes")
    ap.add_argument("--json", dest="json_out", default=None, help="also write results here")
    main(**vars(ap.parse_args()))
