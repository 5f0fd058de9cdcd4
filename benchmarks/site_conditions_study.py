"""The active-site x real-camera table of docs/study.md, from a run instead of by hand.

Runs the paper's study (learned detector, seed 0, 40 images per landmark type) for every site
activity (``none``, ``light``, ``busy``) and camera / imaging pair, named as the study's options:

- camera ``paper``, imaging ``ideal``: the paper's ideal pinhole, no image effects;
- camera ``mavic2pro``, imaging ``ideal``: the Mavic 2 Pro preset (lens distortion, rolling
  shutter, motion blur; the localizers undistort with its coefficients);
- camera ``mavic2pro``, imaging ``camera``: the Mavic 2 Pro plus the sensor effects (blur, sensor
  noise, JPEG).

and prints two Markdown tables: every figure (detection, association F1, poses, poses of the views
with at least four visible landmarks, how many of those got no pose with fewer than four of their
landmarks detected within the match radius -- left short by the detector, not the association --
and the association F1 pooled over those views alone, median / P90, Cramér-Rao bound, median over
bound) and a summary with the three landmark types per row.
The study's association F1 pools every view, so a view with fewer than four visible landmarks,
which no PnP can pose, counts its true detections as misses; the second F1 leaves such views out.
"exact F1" is the pooled F1 of an exact pipeline at the same views: every visible landmark of a
view with at least four detected and correctly assigned, nothing assigned in the other views
(recall = their share of the visible landmarks, precision 1). A real pipeline exceeds it only by
posing a view with three visible landmarks through a detection of a fourth that the ground truth
calls hidden (an occluder covers its point; the detector infers it a few pixels off): the three
visible pairs then count, and the pose is as far off as that displaced point makes it.
``--detector learned:NAME`` evaluates a named weight set (``learned:active``: the active-site
set), ``--detector-model`` / ``--refiner-model`` other files; ``--keep DIR`` keeps every run's outputs.

    .venv/bin/python benchmarks/site_conditions_study.py                  # ~2-3 min on 2 cores (2026-11-27)
    .venv/bin/python benchmarks/site_conditions_study.py --detector learned:active
    .venv/bin/python benchmarks/site_conditions_study.py --detector-model kp.onnx --refiner-model ref.onnx
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from localization.metrics import pooled_scores
from uav_struct_env.study import StudyConfig, run_study
from uav_struct_env.study.cells import read_records_csv

ACTIVITIES = ("none", "light", "busy")
#: (StudyConfig.camera, StudyConfig.imaging) of each row, the study's --camera / --imaging words
CONDITIONS = (("paper", "ideal"), ("mavic2pro", "ideal"), ("mavic2pro", "camera"))
METHODS = ("slab_corners", "opening_corners", "column_tops", "all")
SUMMARY_METHODS = ("slab_corners", "opening_corners", "column_tops")


def read_per_image(per_image: Path) -> list[dict]:
    """The rows of a study's ``per_image.csv`` (strings, as ``csv.DictReader`` gives them)."""
    return read_records_csv(per_image)


def posable_views(rows: list[dict], method: str, at_least: int = 4) -> tuple[int, int, float]:
    """(posed, views, association F1) over the views of ``method`` with >= ``at_least`` visible
    landmarks (F1 pooled over those views, as the study pools it over all); ``rows`` from
    :func:`read_per_image`."""
    rows = [r for r in rows if r["method"] == method and int(r["n_visible"]) >= at_least]
    scores = pooled_scores(sum(int(r["n_correct"]) for r in rows), sum(int(r["n_assigned"]) for r in rows),
                           sum(int(r["n_true_detections"]) for r in rows))
    return sum(r["success"] == "True" for r in rows), len(rows), scores.f1


def unposed_short(rows: list[dict], method: str, at_least: int = 4) -> int:
    """How many views of ``method`` with >= ``at_least`` visible landmarks got no pose and have
    fewer than ``at_least`` detections within the match radius of a visible landmark: the
    detector, not the association, left them short; ``rows`` from :func:`read_per_image`."""
    return sum(1 for r in rows if r["method"] == method and int(r["n_visible"]) >= at_least
               and r["success"] != "True" and int(r["n_true_detections"]) < at_least)


def exact_f1(rows: list[dict], method: str, at_least: int = 4) -> float:
    """The pooled association F1 of an exact pipeline at these views (module docstring):
    ``2 r / (1 + r)`` with ``r`` the share of the visible landmarks that lie in views with at
    least ``at_least`` of them; ``rows`` from :func:`read_per_image`."""
    visible = [int(r["n_visible"]) for r in rows if r["method"] == method]
    total = sum(visible)
    r = sum(v for v in visible if v >= at_least) / total if total else float("nan")
    return 2 * r / (1 + r)


def run_all(workers: int, keep: Path | None, detector_model: str | None,
            refiner_model: str | None, detector: str = "learned") -> list[dict]:
    """Every (activity, camera, imaging) run: dicts with the settings, results.json and the posed counts."""
    from tqdm import tqdm

    runs = []
    cells = [(a, c, i) for a in ACTIVITIES for c, i in CONDITIONS]
    with tempfile.TemporaryDirectory() as tmp:
        for activity, camera, imaging in tqdm(cells, unit="study", desc="site conditions"):
            out = (keep or Path(tmp)) / f"{activity}-{camera}-{imaging}"
            config = StudyConfig(detector=detector, activity=activity, camera=camera, imaging=imaging,
                                 workers=workers, methods=METHODS, detector_model=detector_model,
                                 refiner_model=refiner_model)
            results = run_study(config, out, progress=False, figures=keep is not None, overwrite=True)
            rows = read_per_image(out / "per_image.csv")
            posed = {m: posable_views(rows, m) for m in METHODS}
            short = {m: unposed_short(rows, m) for m in METHODS}
            exact = {m: exact_f1(rows, m) for m in METHODS}
            runs.append({"activity": activity, "camera": camera, "imaging": imaging, "results": results,
                         "posed": posed, "short": short, "exact_f1": exact})
    return runs


def _pair(stats: dict) -> str:
    return "—" if stats["median"] is None else f"{stats['median']:.3f} / {stats['p90']:.3f}"


def _ratio(x: float | None) -> str:
    return "—" if x is None else f"{x:.2f}"


def _condition(run: dict) -> str:
    """The activity, camera and imaging cells of a row."""
    return f"{run['activity']} | {run['camera']} | {run['imaging']}"


def full_block(runs: list[dict]) -> str:
    """Every figure, a Markdown table."""
    lines = [
        "| activity | camera | imaging | landmarks | detection (%) | assoc. F1 (%) | exact F1 (%) | poses | "
        "views with >= 4 visible: posed | not posed, < 4 found | their assoc. F1 (%) | median / P90 (m) | "
        "bound median (m) | median / bound |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for run in runs:
        for m in METHODS:
            r = run["results"]["methods"][m]
            posed, views, f1 = run["posed"][m]
            lines.append(
                f"| {_condition(run)} | {r['label']} | {100 * r['detection_rate']:.1f} | "
                f"{100 * r['association_f1']:.1f} | {100 * run['exact_f1'][m]:.1f} | "
                f"{r['successful']}/{r['total']} | {posed}/{views} | {run['short'][m]} | "
                f"{100 * f1:.1f} | "
                f"{_pair(r['translation_error_m'])} | {r['cramer_rao_translation_m']['median']:.3f} | "
                f"{_ratio(r['median_error_over_bound'])} |"
            )
    return "\n".join(lines)


def summary_block(runs: list[dict]) -> str:
    """Three landmark types per row, a Markdown table."""
    lines = [
        "| activity | camera | imaging | slab corners: det. / F1 (%), poses, median / bound (m) "
        "| opening corners | column tops |",
        "|---|---|---|---|---|---|",
    ]
    for run in runs:
        cells = []
        for m in SUMMARY_METHODS:
            r = run["results"]["methods"][m]
            median = r["translation_error_m"]["median"]
            cells.append(f"{100 * r['detection_rate']:.0f} / {100 * r['association_f1']:.0f}, "
                         f"{r['successful']}/{r['total']}, "
                         f"{'—' if median is None else f'{median:.3f}'} / "
                         f"{r['cramer_rao_translation_m']['median']:.3f}")
        lines.append(f"| {_condition(run)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(workers: int = 2, keep: str | None = None, detector_model: str | None = None,
         refiner_model: str | None = None, detector: str = "learned") -> int:
    runs = run_all(workers, Path(keep) if keep else None, detector_model, refiner_model, detector)
    print(full_block(runs))
    print()
    print(summary_block(runs))
    return 0


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--workers", type=int, default=2, help="study processes")
    ap.add_argument("--keep", default=None, help="also keep every run's outputs in this folder")
    ap.add_argument("--detector", default="learned",
                    help="learned (the default weights), learned:NAME (a named weight set: learned:active), "
                    "guided or guided:NAME (the BIM-guided detector with those weights)")
    ap.add_argument("--detector-model", default=None, help="keypoint-network weights to evaluate")
    ap.add_argument("--refiner-model", default=None, help="patch-refiner weights to evaluate")
    sys.exit(main(**vars(ap.parse_args())))
