"""Confident wrong poses under a detector's real failure modes: ghosts, dense clutter, its own errors.

The integrity fuzz (``tests/localization/test_integrity.py``) draws problems with
:func:`localization.testing.fuzz.draw_case` and detects every in-frame landmark with 1 px noise.
Here the same cases get what a real detector adds (:func:`localization.testing.fuzz.corrupt_detections`):
a ghost copy of every detection shifted by one common offset or by an offset of its own, 5-80 px;
uniform clutter over the image (500 or 2,000 points); the learned detector's false detections on
real renders, replayed. Case ``k`` is drawn from ``default_rng((19, k))`` as in the test, and its
corruption from ``default_rng((44, k))``.

The localizer holds its poses to :data:`localization.verify.CONFIRM_TOLERANCE_M` (``tolerance_m``),
as the study's learned detector does. A success counts as confidently wrong when its position
error exceeds ``max(1 m, 10 x its reported position std)`` (the fuzz test's rule). Prints, per
mode: cases, successes, confident wrong poses, the worst of them, and the median, P99 and
slowest localization time; with ``--compare``, the same without the verification
(:mod:`localization.verify`) beside it.

    .venv/bin/python benchmarks/integrity_fuzz.py --cases 300 [--compare] [--time-budget S]

``record`` writes the replayed library (:class:`localization.testing.fuzz.FalseDetections`) from
study folders of the learned detector (their ``detections.csv``): for the ``detector`` mode only
training buildings, the paper site and random sites, never a held-out building; the held-out
buildings' own library (``detector_heldout``) once, with the method fixed, into its own file.

    .venv/bin/python benchmarks/integrity_fuzz.py record results/paper results/duplex ...
    .venv/bin/python benchmarks/integrity_fuzz.py record heldout/revit_tall_building ... \
        --out localization/testing/false_detections_heldout.json
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from localization import Localizer
from localization.geometry.transforms import camera_center
from localization.testing.fuzz import (
    CORRUPTIONS,
    FALSE_DETECTION_LIBRARIES,
    FALSE_DETECTIONS_PATH,
    FalseDetections,
    corrupt_detections,
    draw_case,
)
from localization.verify import CONFIRM_TOLERANCE_M
from localization.warmup import warm_up

#: A false detection within this distance of a landmark is recorded by its offset from it, px.
NEAR_PX = 80.0


def run(
    mode: str, cases: int, verify: bool = True, library: FalseDetections | None = None,
    tolerance_m: float | None = CONFIRM_TOLERANCE_M, first: int = 0, time_budget_s: float | None = None,
) -> dict:
    """Localize ``cases`` fuzz cases from ``first`` under ``mode``; counts, the worst wrong pose, timings.

    ``tolerance_m``: the localizer's (:class:`localization.Localizer`), the study's
    :data:`localization.verify.CONFIRM_TOLERANCE_M` by default, as the learned detector runs.
    ``time_budget_s``: the localizer's per-frame budget (:mod:`localization.budget`), or None.
    """
    wrong, ok, times, codes = [], 0, [], defaultdict(int)
    for k in range(first, first + cases):
        case = draw_case(np.random.default_rng((19, k)))
        det = corrupt_detections(case, mode, np.random.default_rng((44, k)), library)
        loc = Localizer(case.landmarks_xyz, case.K, association="robust", image_size=case.image_size,
                        pixel_sigma=case.pixel_sigma, verify=verify, tolerance_m=tolerance_m,
                        time_budget_s=time_budget_s)
        t0 = time.perf_counter()
        est = loc.localize(det, case.prior_cam_from_world)
        times.append(time.perf_counter() - t0)
        if not est.success:
            codes[est.failure_code.value] += 1
            continue
        ok += 1
        err = float(np.linalg.norm(est.position - camera_center(case.cam_from_world)))
        std = float(np.sqrt(np.trace(est.covariance[:3, :3])))
        if err > max(1.0, 10.0 * std):
            wrong.append((k, err, std))
    worst = max(wrong, key=lambda t: t[1]) if wrong else None
    ms = 1e3 * np.asarray(times)
    return {"mode": mode, "verify": verify, "first": first, "cases": cases, "successes": ok,
            "wrong": len(wrong),
            "worst": worst, "median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99)),
            "max_ms": float(ms.max()), "wrong_cases": [k for k, _, _ in wrong], "codes": dict(codes)}


def main(cases: int = 300, modes: tuple[str, ...] = CORRUPTIONS, compare: bool = False,
         first: int = 0, time_budget_s: float | None = None) -> list[dict]:
    """Run every mode (and, with ``compare``, again without verification) and print the table.

    ``first``: the first case's index (a long run split over processes: ``--first 0 --cases 5000``
    and ``--first 5000 --cases 5000`` are cases 0-9999). ``time_budget_s``: each frame's budget
    (failures past it count as ``timed_out``; the max column shows how far a frame overran it).
    """
    warm_up(announce=print)
    budget = "none" if time_budget_s is None else f"{time_budget_s:g} s per frame"
    print(f"cases {first}-{first + cases - 1} per mode; time budget: {budget}")
    rows = []
    for mode in modes:
        path = FALSE_DETECTION_LIBRARIES.get(mode)
        library = None if path is None else FalseDetections.load(path)
        for verify in (True, False) if compare else (True,):
            rows.append(run(mode, cases, verify, library, first=first, time_budget_s=time_budget_s))
    print(f"{'mode':<14} {'verify':>6} {'cases':>6} {'poses':>6} {'wrong':>6} {'worst (m, sigma m)':>20} "
          f"{'median ms':>10} {'P99 ms':>8} {'max ms':>8}")
    for r in rows:
        worst = f"{r['worst'][1]:.2f}, {r['worst'][2]:.3f}" if r["worst"] else "-"
        print(f"{r['mode']:<14} {'yes' if r['verify'] else 'no':>6} {r['cases']:>6} {r['successes']:>6} "
              f"{r['wrong']:>6} {worst:>20} {r['median_ms']:>10.1f} {r['p99_ms']:>8.0f} {r['max_ms']:>8.0f}")
        if r["wrong_cases"]:
            print(f"  wrong in cases {r['wrong_cases'][:20]}")
        if r["verify"]:
            print(f"  failures {dict(sorted(r['codes'].items()))}")
    return rows


def _view_false_detections(rows: list[dict]) -> dict:
    """One view's false detections (``true_id == -1``) as the library stores them."""
    found = {int(r["true_id"]): (float(r["u"]), float(r["v"])) for r in rows if int(r["true_id"]) >= 0}
    near, far = [], []
    for r in rows:
        if int(r["true_id"]) >= 0:
            continue
        u, v, dist = float(r["u"]), float(r["v"]), float(r["nearest_px"])
        if dist <= NEAR_PX:
            ref = found.get(int(r["nearest_id"]))
            near.append([u - ref[0], v - ref[1]] if ref is not None else [dist, None])
        else:
            far.append([u, v])
    return {"near": near, "far": far}


def record(studies: list[Path], out: Path = FALSE_DETECTIONS_PATH) -> dict:
    """Write the learned detector's false detections from study folders into the library."""
    views, sources = [], []
    for folder in studies:
        config = json.loads((folder / "results.json").read_text())["config"]
        if not str(config.get("detector", "")).startswith("learned"):
            raise ValueError(f"{folder}: detector {config.get('detector')!r}, expected a learned detector")
        w, h = config["image_size"]
        site = Path(str(config["site"])).name
        conditions = ", ".join(f"{k} {config[k]}" for k in ("activity", "camera", "imaging", "detector"))
        sources.append(f"{folder.name}: site {site}, {conditions}")
        by_view = defaultdict(list)
        with open(folder / "detections.csv") as f:
            for r in csv.DictReader(line for line in f if not line.startswith("#")):
                by_view[(r["method"], r["uav"], r["viewpoint"])].append(r)
        for (method, uav, vp), rows in sorted(by_view.items()):
            if method not in ("slab_corners", "opening_corners", "column_tops"):
                continue
            v = _view_false_detections(rows)
            if v["near"] or v["far"]:
                v["far"] = [[u / w, y / h] for u, y in v["far"]]
                v["source"] = f"{folder.name}/{method}/uav{uav}/vp{vp}"
                views.append(v)
    data = {"sources": sources, "views": views}
    out.write_text(json.dumps(data, indent=None, separators=(",", ":")) + "\n")
    n = sum(len(v["near"]) + len(v["far"]) for v in views)
    print(f"{out}: {len(views)} views, {n} false detections from {len(studies)} studies")
    return data


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sub = ap.add_subparsers(dest="command")
    rec = sub.add_parser("record", help="write the false-detection library from study folders",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    rec.add_argument("studies", nargs="+", type=Path, help="study output folders (learned detector)")
    rec.add_argument("--out", type=Path, default=FALSE_DETECTIONS_PATH, help="the library file written")
    ap.add_argument("--cases", type=int, default=300, help="fuzz cases per mode")
    ap.add_argument("--modes", nargs="+", default=list(CORRUPTIONS), choices=CORRUPTIONS,
                    help="corruptions to run")
    ap.add_argument("--first", type=int, default=0,
                    help="index of the first case (to split a run over processes)")
    ap.add_argument("--compare", action="store_true", help="also run each mode without verification")
    ap.add_argument("--time-budget", type=float, default=None, metavar="S",
                    help="each frame's time budget, s (Localizer time_budget_s); default none")
    args = ap.parse_args()
    if args.command != "record" and (args.first < 0 or args.cases < 1):
        ap.error(f"--first must be >= 0 and --cases >= 1, got {args.first} and {args.cases}")
    if args.time_budget is not None and not 0 < args.time_budget < float("inf"):
        ap.error(f"--time-budget must be a positive number of seconds, got {args.time_budget}")
    if args.command == "record":
        record(args.studies, args.out)
    else:
        main(args.cases, tuple(args.modes), args.compare, args.first, args.time_budget)
