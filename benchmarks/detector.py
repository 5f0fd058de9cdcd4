"""Benchmark the learned landmark detector on held-out renders.

Renders ``--layouts`` random sites x ``--views`` viewpoints at 1280 x 720 with the dataset
generator's domain randomization, from a dataset seed never used for training or validation
(the committed model: training seed 0, validation seed 1; default here: 2), runs
:class:`localization.learned.LearnedDetector` on every full-resolution image and prints, per
landmark type, precision and recall at 3 px, the median pixel error of true positives, and the
detection latency per 1280 x 720 image on one core (``--threads 1``: one ONNX Runtime thread per
network, ``cv2.setNumThreads(1)``; all images are rendered before the timed detection).

    python benchmarks/detector.py --seed 2 --layouts 20 --views 5
    python benchmarks/detector.py --operating-point recall   # as the robust localizer uses it
    python benchmarks/detector.py --refiner none --threshold 0.45 --no-votes   # network alone
    python benchmarks/detector.py --no-votes --baseline   # A/B against the default, interleaved
    python benchmarks/detector.py --activity mixed --camera mixed   # an active site, a real camera
    python benchmarks/detector.py --activity busy --camera mavic2pro --imaging camera   # + noise, JPEG
    python benchmarks/detector.py --site tests/data/ifc/duplex.ifc   # a real (IFC) building

``--activity``, ``--camera``, ``--imaging`` and ``--site`` are the dataset generator's options
(:mod:`uav_struct_env.datasets.landmarks`); the labels are where each landmark appears in the
delivered (distorted) image, so detections are compared there.

This virtual machine's speed drifts by about 10 % within minutes, so two separate runs cannot
resolve a smaller latency difference. ``--baseline`` also runs the default detector (committed
weights, same operating point) on every image, alternating which of the two goes first, and
prints both latencies and the per-image ratio.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from localization.learned import LANDMARK_TYPES, LearnedDetector, match_detections
from uav_struct_env.datasets import DatasetConfig, render_layout
from uav_struct_env.datasets.landmarks import ACTIVITIES, CAMERAS, IMAGINGS


def main(seed: int = 2, layouts: int = 20, views: int = 5, match_px: float = 3.0,
         threads: int = 1, json_out: str | None = None, baseline: bool = False,
         activity: str = "none", camera: str = "paper", site: str = "random",
         imaging: str = "ideal", **detector_kwargs) -> dict:
    """Run the benchmark; ``detector_kwargs`` go to :class:`LearnedDetector` (None: default).

    ``baseline``: also time the default detector at the same operating point, interleaved.
    """
    cv2.setNumThreads(threads)
    kwargs = {k: v for k, v in detector_kwargs.items() if v is not None}
    det = LearnedDetector("all", threads=threads, **kwargs)
    base = None
    if baseline:
        point = {"operating_point": kwargs["operating_point"]} if "operating_point" in kwargs else {}
        base = LearnedDetector("all", threads=threads, **point)
    base_latencies = []
    config = DatasetConfig(n_layouts=layouts, views_per_layout=views, seed=seed, scale=1.0,
                           activity=activity, camera=camera, site=site, imaging=imaging)
    counts = {t: {"tp": 0, "fp": 0, "fn": 0, "err": []} for t in LANDMARK_TYPES}
    latencies = []
    n_images = 0
    # Render everything first: the renderer's own threads must not run during the timing.
    frames = [f for layout in tqdm(range(layouts), desc="render", unit="layout")
              for f in render_layout(config, layout)]
    for d in (det, base):
        if d is not None:
            d.detect_all(np.zeros((720, 1280, 3), np.uint8))  # warm-up
    for i, (rgb, rec) in enumerate(frames):
        if base is not None and i % 2 == 0:
            base_latencies.append(_timed(base, rgb)[0])
        dt, (uv, _, kinds) = _timed(det, rgb)
        latencies.append(dt)
        if base is not None and i % 2 == 1:
            base_latencies.append(_timed(base, rgb)[0])
        n_images += 1
        kps = np.array(rec["keypoints"], np.float64).reshape(-1, 4)
        for t, name in enumerate(LANDMARK_TYPES):
            gt = kps[kps[:, 2] == t, :2]
            m, d = match_detections(uv[kinds == t], gt, match_px)
            c = counts[name]
            c["tp"] += int((m >= 0).sum())
            c["fp"] += int((m < 0).sum())
            c["fn"] += len(gt) - int((m >= 0).sum())
            c["err"] += d[m >= 0].tolist()
    lat = np.array(latencies) * 1e3
    report = {"seed": seed, "layouts": layouts, "views": views, "images": n_images,
              "activity": activity, "camera": camera, "imaging": imaging, "site": site,
              "match_px": match_px, "threads": threads, "detector": repr(det),
              "latency_ms": {"median": float(np.median(lat)), "p90": float(np.percentile(lat, 90)),
                             "mean": float(lat.mean())},
              "types": {}}
    print(f"held-out renders: dataset seed {seed}, {layouts} layouts x {views} views = "
          f"{n_images} images at 1280x720 (site {site}, activity {activity}, camera {camera}, "
          f"imaging {imaging}); "
          f"match radius {match_px} px\n{det!r}")
    print(f"{'landmark type':<16} {'GT':>5} {'det':>5} {'precision':>9} {'recall':>7} "
          f"{'median err px':>13}")
    tot = {"tp": 0, "fp": 0, "fn": 0, "err": []}
    for c in counts.values():
        for k in tot:
            tot[k] += c[k]
    for name, c in [*counts.items(), ("all", tot)]:
        p = c["tp"] / max(c["tp"] + c["fp"], 1)
        r = c["tp"] / max(c["tp"] + c["fn"], 1)
        e = float(np.median(c["err"])) if c["err"] else float("nan")
        report["types"][name] = {"gt": c["tp"] + c["fn"], "detections": c["tp"] + c["fp"],
                                 "precision": p, "recall": r, "median_error_px": e}
        print(f"{name:<16} {c['tp'] + c['fn']:>5} {c['tp'] + c['fp']:>5} {100 * p:>8.1f}% "
              f"{100 * r:>6.1f}% {e:>13.2f}")
    print(f"latency per 1280x720 image, {threads} thread(s): median {np.median(lat):.1f} ms, "
          f"p90 {np.percentile(lat, 90):.1f} ms (resize + network + decoding + refinement)")
    if base is not None:
        b = np.array(base_latencies) * 1e3
        report["baseline"] = {"detector": repr(base),
                              "latency_ms": {"median": float(np.median(b)),
                                             "p90": float(np.percentile(b, 90)),
                                             "mean": float(b.mean())},
                              "median_ratio": float(np.median(lat / b))}
        print(f"baseline {base!r}\n  interleaved on the same images: median {np.median(b):.1f} ms, "
              f"p90 {np.percentile(b, 90):.1f} ms; this / baseline per image: median "
              f"{np.median(lat / b):.3f}")
    if json_out:
        Path(json_out).write_text(json.dumps(report, indent=2))
    return report


def _timed(det: LearnedDetector, rgb: np.ndarray) -> tuple[float, tuple]:
    t0 = time.perf_counter()
    out = det.detect_all(rgb)
    return time.perf_counter() - t0, out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=2, help="held-out dataset seed (not 0 or 1)")
    ap.add_argument("--layouts", type=int, default=20)
    ap.add_argument("--views", type=int, default=5)
    ap.add_argument("--match-px", type=float, default=3.0)
    ap.add_argument("--threshold", type=float, default=None, help="keypoint-network score")
    ap.add_argument("--model", default=None, help="keypoint-network ONNX (default: committed)")
    ap.add_argument("--refiner", default=None,
                    help="refiner ONNX, or 'none' for the network alone (default: committed)")
    ap.add_argument("--iterations", type=int, default=None, help="refinement passes")
    ap.add_argument("--refine-threshold", type=float, default=None)
    ap.add_argument("--operating-point", default=None, choices=["balanced", "recall"],
                    help="default thresholds (default: balanced; the study with robust "
                         "association uses recall)")
    ap.add_argument("--vote-threshold", type=float, default=None,
                    help="minimum score of a non-peak heatmap cell that proposes a candidate")
    ap.add_argument("--no-votes", action="store_true",
                    help="candidates from heatmap peaks only (the decoding before votes)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", dest="json_out", default=None)
    ap.add_argument("--activity", default="none", choices=ACTIVITIES, help="site activity per layout")
    ap.add_argument("--camera", default="paper", choices=CAMERAS, help="camera per image")
    ap.add_argument("--imaging", default="ideal", choices=IMAGINGS,
                    help="camera imaging per image (blur, sensor noise, JPEG)")
    ap.add_argument("--site", default="random", help="random, or a site file / IFC file")
    ap.add_argument("--baseline", action="store_true",
                    help="also time the default detector, interleaved image by image")
    a = ap.parse_args()
    refiner = {None: None, "none": False}.get(a.refiner, a.refiner)
    main(a.seed, a.layouts, a.views, a.match_px, a.threads, a.json_out, a.baseline, a.activity,
         a.camera, a.site, a.imaging, model=a.model,
         score_threshold=a.threshold, refiner=refiner, refine_iterations=a.iterations,
         refine_threshold=a.refine_threshold, operating_point=a.operating_point,
         votes=not a.no_votes, vote_threshold=a.vote_threshold)
