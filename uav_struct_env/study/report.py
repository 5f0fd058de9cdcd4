"""Turn per-image results into ``results.json``, the paper's Tables I and II, and a CSV.

Statistics follow the paper: error medians and P90 over the *successful* poses only, with the
success count beside them. Detection rate and association precision/recall/F1 are pooled over
all images of a method (sums of counts, then ratios). Every statistic comes from
:mod:`localization.metrics`, which gives NaN where a value cannot be computed (no successful
pose, nothing visible); at the JSON boundary NaN becomes ``null`` (``—`` in the tables). Failures
are grouped by their :class:`~localization.FailureCode`, with a count and an example message.
"""

from __future__ import annotations

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
from uav_struct_env.outputs import atomic_write_json
from uav_struct_env.provenance import software, version_text
from uav_struct_env.study.cells import cell, json_ready, pct_cell, write_records_csv
from uav_struct_env.study.protocol import METHODS, Method, PaperFigures, StudyConfig
from uav_struct_env.study.run import ImageResult, bound_source

__all__ = [
    "failure_breakdown",
    "settings_line",
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


def _pooled_rms(rows: Sequence[ImageResult]) -> float:
    """RMS pixel error over every true detection of ``rows`` (NaN without any)."""
    pairs = [(r.n_true_detections, r.pixel_error_rms_px) for r in rows
             if r.n_true_detections > 0 and math.isfinite(r.pixel_error_rms_px)]
    n = sum(k for k, _ in pairs)
    return math.sqrt(sum(k * e * e for k, e in pairs) / n) if n else float("nan")


def summarize(method: Method, rows: Sequence[ImageResult], bound: str | None = None) -> dict:
    """The ``results.json`` entry of one method (NaN where undefined; null once written).

    ``bound`` says where the rows' Cramér-Rao pixel noise came from (``"configured"`` or
    ``"measured"``, see :func:`uav_struct_env.study.run.bound_pixel_sigma`).
    """
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
        "cramer_rao_pixel_sigma_px": rows[0].crb_pixel_sigma_px if rows else float("nan"),
        "cramer_rao_sigma_source": bound,
        "detection_error_rms_px": _pooled_rms(rows),
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
        methods[m.key] = summarize(m, [r for r in rows if r.method == m.key], bound_source(config, m))
    out = {"config": cfg, "software": software(), "methods": json_ready(methods)}
    if config.skip_reasons:
        out["skipped"] = dict(config.skip_reasons)
    return out


def _paper(results: dict, m: Method) -> PaperFigures | None:
    """The paper's figures for ``m``: only beside a run on the paper's own building."""
    return m.paper if results["config"].get("site") == "paper" else None


def _skipped_lines(results: dict) -> list[str]:
    skipped = results.get("skipped", {})
    return ["", *(f"Left out: {key} -- {why}." for key, why in skipped.items())] if skipped else []


def write_results_json(path: Path, results: dict) -> None:
    """Write ``results.json`` (strict JSON: no NaN)."""
    atomic_write_json(path, results, indent=2, allow_nan=False)


def write_csv(path: Path, rows: Sequence[ImageResult], comment: str | None = None) -> None:
    """Every per-image result, one row each (``comment``: a first ``#`` line, the settings)."""
    write_records_csv(path, ImageResult, rows, comment=comment)


#: The paper's protocol (StudyConfig's defaults): viewpoints per UAV and UAVs; fewer is ``--quick``.
PAPER_PROTOCOL = tuple(
    next(f.default for f in dataclasses.fields(StudyConfig) if f.name == name)
    for name in ("n_viewpoints", "n_agents")
)
#: Config keys that do not change the numbers (or that the tables show themselves).
_UNSTATED = {"workers", "methods", "elapsed_s"}


def _name(path: str | None, default: Path) -> str:
    return Path(path).name if path else default.name


def settings_line(results: dict) -> str:
    """One line that says how a study output was made: every setting and the software.

    Used by the table files, the figures and the console. A config key it does not spell out (a
    setting added later) is still listed, as ``key value``.
    """
    from localization.detect.learned import DEFAULT_MODEL
    from localization.detect.refiner import DEFAULT_REFINER

    c = dict(results["config"])
    sw = results.get("software") or {}
    noise = (f"miss rate {c.pop('miss_rate')}, false positives {c.pop('false_positives')}/image")
    sigma = c.pop("pixel_sigma")
    kind = c.pop("detector")
    if kind in ("learned", "guided"):
        detector = (f"{'BIM-guided' if kind == 'guided' else 'learned'} detector "
                    f"({_name(c.pop('detector_model'), DEFAULT_MODEL)} + "
                    f"{_name(c.pop('refiner_model'), DEFAULT_REFINER)}; localizer noise model "
                    f"pixel sigma {sigma} px, {noise})")
    else:
        for key in ("detector_model", "refiner_model"):
            c.pop(key, None)
        detector = f"projection detector (pixel sigma {sigma} px, {noise})"
    nv, na = c.pop("n_viewpoints"), c.pop("n_agents")
    protocol = f"{nv} viewpoints x {na} UAVs " + (
        "(the paper's protocol)" if (nv, na) == PAPER_PROTOCOL
        else "(QUICK: not the paper's {} x {})".format(*PAPER_PROTOCOL)
    )
    site, stage = c.pop("site"), c.pop("stage", None)
    as_built, scale = c.pop("as_built", None), c.pop("as_built_scale", None)
    building = "as designed" if as_built is None else f"as built {as_built} x {scale:g}"
    building += f", site activity {c.pop('activity', 'none')}"
    w, h = c.pop("image_size")
    parts = [
        version_text(sw),
        f"site {site if site in ('paper', 'random') else Path(site).name}"
        + (f", stage {stage}" if stage else "") + f", {building}",
        detector,
        f"{c.pop('association')} association",
        f"{c.pop('noise')} prior",
        f"{c.pop('camera', 'paper')} camera, "
        f"{c.pop('imaging')} imaging, {c.pop('lighting', 'fixed')} lighting, {w}x{h} px, "
        f"{c.pop('renderer')} renderer",
        f"seed {c.pop('seed')}",
        protocol,
    ]
    worker_sigma = c.pop("worker_pixel_sigma", None)
    upright = c.pop("upright_workers", False)
    if c.pop("track_workers", False):
        parts.append(f"worker tracking ({worker_sigma} px keypoint noise{', upright' if upright else ''})")
    parts += [f"{k} {v}" for k, v in sorted(c.items()) if k not in _UNSTATED]
    return " · ".join(parts)


def _settings_header(results: dict) -> list[str]:
    return [f"Settings: {settings_line(results)}", ""]


def table1_markdown(results: dict) -> str:
    """Table I: detection and association, ours beside the paper's (settings line first)."""
    lines = _settings_header(results) + [
        "| Landmark type | Detection (%) | Paper | Association F1 (%) | Paper | Latency (s) | Paper |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for m in METHODS:
        r = results["methods"].get(m.key)
        if r is None or not m.structural:
            continue
        p = _paper(results, m)
        lines.append(
            f"| {m.label} | {pct_cell(r['detection_rate'])} | {cell(p and p.detection_pct, 2)} | "
            f"{pct_cell(r['association_f1'])} | {cell(p and p.association_f1_pct, 2)} | "
            f"{cell(r['latency_s']['median'], 4)} | {cell(p and p.latency_s, 2)} |"
        )
    return "\n".join(lines + _skipped_lines(results)) + "\n"


def table2_markdown(results: dict) -> str:
    """Table II: pose accuracy, ours beside the paper's, with the Cramér-Rao bound.

    The settings line comes first. The paper's success counts stand beside ours only where the
    run had as many images as the paper (not in a ``--quick`` run).
    """
    lines = _settings_header(results) + [
        "| Method | Successful | Translation median / P90 (m) | Paper | Bound median (m) "
        "| Rotation median / P90 (°) | Paper | Bound median (°) | Bound noise (px) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    uncounted = []
    for m in METHODS:
        r = results["methods"].get(m.key)
        if r is None:
            continue
        p = _paper(results, m)
        t, rot = r["translation_error_m"], r["rotation_error_deg"]
        paper_t = f"{p.translation_median_m:.3f} / {p.translation_p90_m:.3f}" if p else "—"
        paper_r = f"{p.rotation_median_deg:.3f} / {p.rotation_p90_deg:.3f}" if p else "—"
        paper_n = ""
        if p and p.total == r["total"]:
            paper_n = f" (paper {p.successful}/{p.total})"
        elif p:
            uncounted.append(p.total)
        lines.append(
            f"| {m.label} | {r['successful']}/{r['total']}{paper_n} | "
            f"{cell(t['median'])} / {cell(t['p90'])} | "
            f"{paper_t} | {cell(r['cramer_rao_translation_m']['median'])} | "
            f"{cell(rot['median'])} / {cell(rot['p90'])} | {paper_r} | "
            f"{cell(r['cramer_rao_rotation_deg']['median'])} | {_bound_noise(r)} |"
        )
    first = next(iter(results["methods"].values()), None)
    if first is not None:
        t, rot = first["prior_translation_error_m"], first["prior_rotation_error_deg"]
        lines.append(
            f"| Onboard prior (GNSS + attitude, input) | — | {cell(t['median'])} / {cell(t['p90'])} | — | — "
            f"| {cell(rot['median'])} / {cell(rot['p90'])} | — | — | — |"
        )
    lines += [
        "",
        "Bound: the Cramér–Rao bound (RMS error) for the same images and visible landmarks at the "
        "detector's own pixel noise (per axis, last column): *set* is the projection detector's "
        "configured noise; *measured* is the RMS error of this run's true detections (those matched "
        "to a visible landmark within 3 px). An RMS bound sits somewhat above error medians. ArUco "
        "rows have no bound (their corners have another noise). Errors: over successful poses "
        "only, as in the paper.",
    ]
    if uncounted:
        total = next(iter(results["methods"].values()))["total"]
        lines += [
            "",
            f"The paper's success counts (over {max(uncounted)} images per method) are left out: "
            f"this run had {total} per method, so its counts and medians are not comparable to "
            "the paper's one for one.",
        ]
    return "\n".join(lines + _skipped_lines(results)) + "\n"


def _bound_noise(r: dict) -> str:
    sigma, source = r.get("cramer_rao_pixel_sigma_px"), r.get("cramer_rao_sigma_source")
    if sigma is None or source is None:
        return "—"
    return f"{sigma:.2f} ({'set' if source == 'configured' else source})"
