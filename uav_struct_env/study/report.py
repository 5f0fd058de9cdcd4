"""Turn per-image results into ``results.json``, the paper's Tables I and II, and a CSV.

Statistics follow the paper: error medians and P90 over the *successful* poses only, with the
success count beside them. Detection rate and association precision/recall/F1 are pooled over
all images of a method (sums of counts, then ratios). Every statistic comes from
:mod:`localization.metrics`, which gives NaN where a value cannot be computed (no successful
pose, nothing visible); at the JSON boundary NaN becomes ``null`` (``—`` in the tables). Failures
are grouped by their :class:`~localization.FailureCode`, with a count and an example message.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path

from localization import FailureCode
from localization.metrics import (
    DEFAULT_THRESHOLDS,
    median_p90,
    pooled_scores,
    recall_at,
    summarize_errors,
)
from uav_struct_env.outputs import atomic_path, atomic_write_json
from uav_struct_env.study.protocol import METHODS, Method, StudyConfig
from uav_struct_env.study.run import ImageResult

__all__ = [
    "failure_breakdown",
    "summarize",
    "write_csv",
    "write_results_json",
    "table1_markdown",
    "table2_markdown",
]

#: The (m, deg) recall thresholds of results.json: the first three of the package's defaults.
RECALL_THRESHOLDS = DEFAULT_THRESHOLDS[:3]


def _ratio(a: int, b: int) -> float:
    return a / b if b else float("nan")


def failure_breakdown(rows: Sequence[ImageResult]) -> dict[str, dict]:
    """Failed images grouped by :class:`~localization.FailureCode` value, most frequent first.

    Each group holds its ``count`` and an ``example`` message (the first one).
    """
    groups: dict[str, dict] = {}
    for r in rows:
        if not r.success:
            code = r.failure_code or FailureCode.UNKNOWN.value
            g = groups.setdefault(code, {"count": 0, "example": r.failure_reason})
            g["count"] += 1
    return dict(sorted(groups.items(), key=lambda kv: -kv[1]["count"]))


def summarize(method: Method, rows: Sequence[ImageResult]) -> dict:
    """The ``results.json`` entry of one method (NaN where undefined; null once written)."""
    ok = [r for r in rows if r.success]
    visible = sum(r.n_visible for r in rows)
    true_det = sum(r.n_true_detections for r in rows)
    correct = sum(r.n_correct for r in rows)
    scores = pooled_scores(correct, sum(r.n_assigned for r in rows), true_det)
    # Structural: detections of a true landmark / visible landmarks. Markers: correctly decoded
    # visible markers / visible markers (n_true_detections counts the visible markers there).
    detection_rate = _ratio(true_det, visible) if method.structural else _ratio(correct, true_det)
    errors = summarize_errors(
        [r.translation_error_m for r in rows],
        [r.rotation_error_deg for r in rows],
        [r.success for r in rows],
    ).as_dict()
    t_stats = errors["translation_error_m"]
    crb_t = median_p90([r.crb_translation_m for r in rows])
    recall = recall_at(
        [r.translation_error_m for r in rows],
        [r.rotation_error_deg for r in rows],
        [r.success for r in rows],
        RECALL_THRESHOLDS,
    )
    return {
        "label": method.label,
        "stage": method.scene.stage,
        "marker_size_m": method.scene.marker_size if not method.structural else None,
        "successful": len(ok),
        "total": len(rows),
        "translation_error_m": t_stats,
        "rotation_error_deg": errors["rotation_error_deg"],
        "detection_rate": detection_rate,
        "association_precision": scores.precision,
        "association_recall": scores.recall,
        "association_f1": scores.f1,
        "latency_s": median_p90([r.latency_s for r in rows]),
        "cramer_rao_translation_m": crb_t,
        "cramer_rao_rotation_deg": median_p90([r.crb_rotation_deg for r in rows]),
        "median_error_over_bound": (
            t_stats["median"] / crb_t["median"] if crb_t["median"] != 0.0 else float("nan")
        ),
        "recall_at": {f"{tm}m_{rd}deg": v for (tm, rd), v in recall.items()} if rows else {},
        "prior_translation_error_m": median_p90([r.prior_translation_error_m for r in rows]),
        "prior_rotation_error_deg": median_p90([r.prior_rotation_error_deg for r in rows]),
        "failures": failure_breakdown(rows),
    }


def results_dict(config: StudyConfig, rows: Sequence[ImageResult], extra_config: dict | None = None) -> dict:
    """The whole ``results.json`` document."""
    cfg = dataclasses.asdict(config)
    cfg["image_size"] = list(config.image_size)
    cfg["methods"] = list(config.methods)
    cfg.update(extra_config or {})
    methods = {}
    for m in config.selected_methods:
        methods[m.key] = summarize(m, [r for r in rows if r.method == m.key])
    return {"config": cfg, "methods": _clean(methods)}


def _clean(obj):
    """The JSON boundary: NaN and infinities (undefined statistics) become null."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    return obj


def write_results_json(path: Path, results: dict) -> None:
    """Write ``results.json`` (strict JSON: no NaN)."""
    atomic_write_json(path, results, indent=2, allow_nan=False)


def write_csv(path: Path, rows: Sequence[ImageResult]) -> None:
    """Every per-image result, one row each."""
    fields = [f.name for f in dataclasses.fields(ImageResult)]
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        for r in rows:
            writer.writerow(dataclasses.asdict(r))


def _f(x: float | None, digits: int = 3) -> str:
    return "—" if x is None else f"{x:.{digits}f}"


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.2f}"


def table1_markdown(results: dict) -> str:
    """Table I: detection and association, ours beside the paper's."""
    lines = [
        "| Landmark type | Detection (%) | Paper | Association F1 (%) | Paper | Latency (s) | Paper |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for m in METHODS:
        r = results["methods"].get(m.key)
        if r is None or not m.structural:
            continue
        p = m.paper
        lines.append(
            f"| {m.label} | {_pct(r['detection_rate'])} | {_f(p and p.detection_pct, 2)} | "
            f"{_pct(r['association_f1'])} | {_f(p and p.association_f1_pct, 2)} | "
            f"{_f(r['latency_s']['median'], 4)} | {_f(p and p.latency_s, 2)} |"
        )
    return "\n".join(lines) + "\n"


def table2_markdown(results: dict) -> str:
    """Table II: pose accuracy, ours beside the paper's, with the Cramér-Rao bound."""
    lines = [
        "| Method | Successful | Translation median / P90 (m) | Paper | Bound median (m) "
        "| Rotation median / P90 (°) | Paper | Bound median (°) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for m in METHODS:
        r = results["methods"].get(m.key)
        if r is None:
            continue
        p = m.paper
        t, rot = r["translation_error_m"], r["rotation_error_deg"]
        paper_t = f"{p.translation_median_m:.3f} / {p.translation_p90_m:.3f}" if p else "—"
        paper_r = f"{p.rotation_median_deg:.3f} / {p.rotation_p90_deg:.3f}" if p else "—"
        paper_n = f" (paper {p.successful}/{p.total})" if p else ""
        lines.append(
            f"| {m.label} | {r['successful']}/{r['total']}{paper_n} | {_f(t['median'])} / {_f(t['p90'])} | "
            f"{paper_t} | {_f(r['cramer_rao_translation_m']['median'])} | "
            f"{_f(rot['median'])} / {_f(rot['p90'])} | {paper_r} | "
            f"{_f(r['cramer_rao_rotation_deg']['median'])} |"
        )
    first = next(iter(results["methods"].values()), None)
    if first is not None:
        t, rot = first["prior_translation_error_m"], first["prior_rotation_error_deg"]
        lines.append(
            f"| Onboard prior (GNSS + attitude, input) | — | {_f(t['median'])} / {_f(t['p90'])} | — | — "
            f"| {_f(rot['median'])} / {_f(rot['p90'])} | — | — |"
        )
    sigma = results["config"].get("pixel_sigma")
    lines += [
        "",
        f"Bound: the Cramér–Rao bound (RMS error) for the same images, visible landmarks and "
        f"{sigma} px detector noise (structural rows; ArUco corners have another noise). "
        "Errors: over successful poses only, as in the paper.",
    ]
    return "\n".join(lines) + "\n"
