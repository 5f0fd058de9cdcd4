"""Confident wrong poses under a detector's real failure modes: ghost copies and dense clutter.

The integrity fuzz (``tests/localization/test_integrity.py``) draws problems with
:func:`localization.testing.fuzz.draw_case` and detects every in-frame landmark with 1 px noise.
Here the same cases get what a real detector adds: a ghost copy of every detection (a detector
that fires twice per corner) shifted by one common offset or by an offset of its own, 5-80 px;
and uniform clutter over the image (500 or 2,000 points). Case ``k`` is drawn from
``default_rng((19, k))`` as in the test, and its corruption from ``default_rng((44, k))``.

A success counts as confidently wrong when its position error exceeds ``max(1 m, 10 x its
reported position std)`` (the fuzz test's rule). Prints, per mode: cases, successes, confident
wrong poses, the worst of them, and the median and slowest localization time.

    .venv/bin/python benchmarks/integrity_fuzz.py --cases 300
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from localization import Localizer
from localization.geometry.transforms import camera_center
from localization.testing.fuzz import FuzzCase, draw_case
from localization.warmup import warm_up

MODES = ("clean", "ghost_shift", "ghost_each", "clutter_500", "clutter_2000")


def corrupt(case: FuzzCase, mode: str, rng: np.random.Generator) -> np.ndarray:
    """The case's detections with ``mode``'s corruption, in random order."""
    det = case.detections_uv
    w, h = case.image_size
    if mode == "ghost_shift":
        shift = rng.uniform(5.0, 80.0) * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
        det = np.vstack([det, det + shift])
    elif mode == "ghost_each":
        r = rng.uniform(5.0, 80.0, len(det))
        a = rng.uniform(0.0, 2 * np.pi, len(det))
        det = np.vstack([det, det + np.column_stack([r * np.cos(a), r * np.sin(a)])])
    elif mode.startswith("clutter_"):
        n = int(mode.split("_")[1])
        det = np.vstack([det, rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], (n, 2))])
    return det[rng.permutation(len(det))]


def run(mode: str, cases: int) -> dict:
    """Localize ``cases`` fuzz cases under ``mode``; counts, the worst wrong pose, timings."""
    wrong, ok, times = [], 0, []
    for k in range(cases):
        case = draw_case(np.random.default_rng((19, k)))
        det = corrupt(case, mode, np.random.default_rng((44, k)))
        loc = Localizer(case.landmarks_xyz, case.K, association="robust", image_size=case.image_size,
                        pixel_sigma=case.pixel_sigma)
        t0 = time.perf_counter()
        est = loc.localize(det, case.prior_cam_from_world)
        times.append(time.perf_counter() - t0)
        if not est.success:
            continue
        ok += 1
        err = float(np.linalg.norm(est.position - camera_center(case.cam_from_world)))
        std = float(np.sqrt(np.trace(est.covariance[:3, :3])))
        if err > max(1.0, 10.0 * std):
            wrong.append((k, err, std))
    worst = max(wrong, key=lambda t: t[1]) if wrong else None
    return {"mode": mode, "cases": cases, "successes": ok, "wrong": len(wrong), "worst": worst,
            "median_ms": 1e3 * float(np.median(times)), "max_ms": 1e3 * float(np.max(times)),
            "wrong_cases": [k for k, _, _ in wrong]}


def main(cases: int = 300, modes: tuple[str, ...] = MODES) -> list[dict]:
    warm_up(announce=print)
    rows = [run(mode, cases) for mode in modes]
    print(f"{'mode':<14} {'cases':>6} {'poses':>6} {'wrong':>6} {'worst (m, sigma m)':>20} "
          f"{'median ms':>10} {'max ms':>8}")
    for r in rows:
        worst = f"{r['worst'][1]:.2f}, {r['worst'][2]:.3f}" if r["worst"] else "-"
        print(f"{r['mode']:<14} {r['cases']:>6} {r['successes']:>6} {r['wrong']:>6} {worst:>20} "
              f"{r['median_ms']:>10.1f} {r['max_ms']:>8.0f}")
        if r["wrong_cases"]:
            print(f"  wrong in cases {r['wrong_cases'][:20]}")
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--cases", type=int, default=300, help="fuzz cases per mode")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES, help="corruptions to run")
    args = ap.parse_args()
    main(args.cases, tuple(args.modes))
