"""Issue 44 item 2's table from study outputs: one row per building folder and landmark set.

Counted over the views that see at least four landmarks of the set (``n_visible >= 4`` in
``per_image.csv``), as item 2 asks:

- *detection*: true detections / visible landmarks, summed over those views;
- *F1*: association F1 pooled over those views (:func:`localization.metrics.pooled_scores` of
  the summed correct, assigned and true-detection counts);
- *poses*: successes among those views / those views;
- *median / bound*: the median translation error of the successes and the median Cramer-Rao
  bound of the same views (metres), and their ratio;
- *wrong*: successes (any view) farther than max(1 m, 3 x the view's bound) from the truth
  (``benchmarks/wrong_poses.py``'s rule).

    .venv/bin/python benchmarks/building_table.py DIR/revit_tall_building DIR/renga_house ...

prints a Markdown table, then the totals of poses and wrong ones; ``--check`` also marks each
row's item 2 targets (detection >= 90 %, F1 >= 95 %, poses >= 90 %, median <= 1.5 x bound).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from wrong_poses import is_success, is_wrong, rows_by_method  # noqa: E402


def row(rows: list[dict]) -> dict:
    """Item 2's figures of one building's landmark set (its ``per_image.csv`` rows)."""
    from localization.metrics import pooled_scores

    seen = [r for r in rows if int(r["n_visible"]) >= 4]
    visible = sum(int(r["n_visible"]) for r in seen)
    true = sum(int(r["n_true_detections"]) for r in seen)
    f1 = pooled_scores(sum(int(r["n_correct"]) for r in seen), sum(int(r["n_assigned"]) for r in seen),
                       true).f1
    ok = [r for r in seen if is_success(r)]
    med = float(np.median([float(r["translation_error_m"]) for r in ok])) if ok else float("nan")
    bound = float(np.median([float(r["crb_translation_m"]) for r in ok])) if ok else float("nan")
    detection = true / visible if visible else float("nan")
    return {"views": len(rows), "posable": len(seen), "detection": detection,
            "f1": f1, "poses": len(ok), "median_m": med, "bound_m": bound,
            "wrong": sum(is_wrong(r) for r in rows), "successes": sum(is_success(r) for r in rows)}


def _pct(x: float) -> str:
    return "--" if not np.isfinite(x) else f"{100 * x:.1f} %"


def _targets(f: dict) -> str:
    ratio = f["median_m"] / f["bound_m"] if f["poses"] else float("inf")
    marks = [("det", f["detection"] >= 0.90), ("F1", f["f1"] >= 0.95),
             ("poses", f["posable"] > 0 and f["poses"] >= 0.9 * f["posable"]), ("median", ratio <= 1.5)]
    return " ".join(f"{name}{'+' if good else '-'}" for name, good in marks)


def main(argv: list[str] | None = None) -> int:
    """Print the table of the study folders given; returns 0."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("folders", nargs="+", type=Path, help="study output folders (each with per_image.csv)")
    ap.add_argument("--check", action="store_true", help="mark item 2's targets per row")
    args = ap.parse_args(argv)
    missing = [str(f) for f in args.folders if not (f / "per_image.csv").is_file()]
    if missing:  # before any row: a folder given by a glob that is no study's
        ap.error(f"not a study output folder (no per_image.csv): {', '.join(missing)}")
    head = "| building | landmarks | detection | F1 | poses / views with >= 4 | median / bound (m) | wrong |"
    print(head + (" item 2 |" if args.check else ""))
    print("|---|---|---:|---:|---:|---:|---:|" + ("---|" if args.check else ""))
    poses = wrong = 0
    for folder in args.folders:
        for method, rows in rows_by_method(folder / "per_image.csv").items():
            f = row(rows)
            poses, wrong = poses + f["successes"], wrong + f["wrong"]
            ratio = f" ({f['median_m'] / f['bound_m']:.2f}x)" if f["poses"] else ""
            median = f"{f['median_m']:.3f} / {f['bound_m']:.3f}{ratio}" if f["poses"] else "--"
            line = (f"| {folder.name} | {method.replace('_', ' ')} | {_pct(f['detection'])} | "
                    f"{_pct(f['f1'])} | {f['poses']}/{f['posable']} | {median} | {f['wrong']} |")
            print(line + (f" {_targets(f)} |" if args.check else ""))
    print(f"\ntotal: {poses} poses, {wrong} wrong")
    return 0


if __name__ == "__main__":
    sys.exit(main())
