"""Worker tracking in the study (``--track-workers``): what a camera-pose error costs downstream.

At every viewpoint of every scene with structural methods, the four cameras detect the site's
workers (:class:`~uav_struct_env.tracking_sim.SimulatedWorkerDetector` at the true poses: what
the images show; seeded per scene and viewpoint, so every pose source sees the same detections)
and :func:`tracking.track_workers` triangulates them three times, from the cameras'

* ``truth``: true poses, the floor set by the detector's pixel noise alone;
* ``estimated``: the localizer's poses (with their covariance; a camera whose localization
  failed takes no part) -- of the scene's tracking method, :data:`TRACKING_METHODS` (slab corners
  at the slab stage, all structural landmarks at the columns stage), and of every structural
  method in ``estimated_by_method``;
* ``prior``: the onboard GNSS / attitude poses (with the prior's sigmas).

One *observation* is one worker triangulated from at least two cameras at one viewpoint; its
error is the larger of its feet and head-top errors (:mod:`tracking.metrics`). ``results.json``
gains ``worker_tracking``: ``truth``, ``estimated``, ``prior`` and ``estimated_by_method``, each
``{median_m, p95_m, n_observations}``, plus the workers present and the settings.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from localization.geometry.transforms import invert
from tracking import error_summary, track_workers, worker_errors
from uav_struct_env.study.cells import cell
from uav_struct_env.tracking_sim import DEFAULT_WORKER_SIGMA_PX, SimulatedWorkerDetector, camera_views

__all__ = [
    "HEIGHT_RANGE",
    "TRACKING_ACTIVITY",
    "TRACKING_METHODS",
    "ViewpointTracking",
    "WorkerObservation",
    "track_viewpoint",
    "tracking_markdown",
    "tracking_summary",
]

#: The site activity the study runs with when it tracks workers and none was chosen.
TRACKING_ACTIVITY = "light"
#: The method whose estimated poses give the ``estimated`` figure, per scene stage role.
TRACKING_METHODS = {"slab": "slab_corners", "columns": "all"}
#: Head-above-feet heights accepted in an association, m.
HEIGHT_RANGE = (1.0, 2.3)
#: Misses of the simulated worker detector.
MISS_RATE = 0.05


@dataclass(frozen=True)
class WorkerObservation:
    """One worker triangulated at one viewpoint from one pose source.

    ``method`` is the localization method of an ``estimated`` source (``""`` for the others);
    ``tracking`` says whether it is the scene's tracking method (:data:`TRACKING_METHODS`).
    """

    source: str
    method: str
    tracking: bool
    stage: str
    viewpoint: int
    worker: str
    n_cameras: int
    error_m: float


@dataclass(frozen=True)
class ViewpointTracking:
    """The workers present at one viewpoint of one scene and their observations."""

    stage: str
    viewpoint: int
    n_workers: int
    observations: tuple[WorkerObservation, ...]


def tracking_method(scene_stage: str, methods: Sequence[str]) -> str | None:
    """The scene's tracking method among its structural ``methods`` (the first when absent)."""
    preferred = TRACKING_METHODS.get(scene_stage)
    return preferred if preferred in methods else (methods[0] if methods else None)


def track_viewpoint(
    env: Any,
    infos: Mapping[str, dict],
    estimates: Mapping[str, Mapping[str, Any]],
    *,
    stage: str,
    viewpoint: int,
    rng: np.random.Generator,
    prior_sigmas: Any = None,
    pixel_sigma: float = DEFAULT_WORKER_SIGMA_PX,
    upright: bool = False,
) -> ViewpointTracking:
    """The workers and worker observations of one rendered viewpoint (module docstring).

    Args:
        env: the study's env, just reset at the viewpoint (with site activity).
        infos: its per-agent infos.
        estimates: per structural method key, per agent, the :class:`localization.PoseEstimate`.
        stage: the scene's stage role (``"slab"`` / ``"columns"``).
        viewpoint: the viewpoint index.
        rng: the detector's generator for this viewpoint.
        prior_sigmas: the localizer's prior sigmas (None: the paper's).
        pixel_sigma: the worker detector's keypoint noise, px of the env's images.
        upright: triangulate the workers standing (:func:`tracking.track_workers`).
    """
    points = env.worker_points()
    detector = SimulatedWorkerDetector(pixel_sigma, miss_rate=MISS_RATE, rng=rng)
    size = tuple(env.config.image_size)
    detections = {
        agent: detector.detect(points, env.worker_visibility(agent), info["intrinsics"],
                               invert(info["world_from_cam"]), size, info.get("distortion"))
        for agent, info in infos.items()
    }
    chosen = tracking_method(stage, list(estimates))
    runs = [("truth", "", False, None), ("prior", "", False, None)]
    runs += [("estimated", key, key == chosen, est) for key, est in estimates.items()]
    out = []
    for source, method, is_tracking, est in runs:
        views = camera_views(infos, source, est, prior_sigmas)
        used = {v.name for v in views}
        result = track_workers(views, {a: d for a, d in detections.items() if a in used},
                               height_range=HEIGHT_RANGE, upright=upright)
        errors = worker_errors(result, points)
        for w, e in zip(result.tracked, errors, strict=True):
            out.append(WorkerObservation(source, method, is_tracking, stage, viewpoint, str(w.label),
                                         len(w.cameras), float(e)))
    return ViewpointTracking(stage, viewpoint, len(points), tuple(out))


def tracking_summary(
    viewpoints: Sequence[ViewpointTracking], pixel_sigma: float, activity: str, upright: bool = False
) -> dict:
    """The ``worker_tracking`` entry of ``results.json`` (NaN where undefined; null once written).

    ``pixel_sigma`` (the worker detector's noise, px of the images) and ``activity`` (the site
    activity preset) and ``upright`` (workers triangulated standing) are recorded beside the numbers.
    """
    observations = [o for v in viewpoints for o in v.observations]

    def summary(rows):
        return error_summary([r.error_m for r in rows])

    truth = [r for r in observations if r.source == "truth"]
    estimated = [r for r in observations if r.source == "estimated"]
    methods = sorted({r.method for r in estimated}, key=[r.method for r in estimated].index)
    return {
        "truth": summary(truth),
        "estimated": summary([r for r in estimated if r.tracking]),
        "prior": summary([r for r in observations if r.source == "prior"]),
        "estimated_by_method": {m: summary([r for r in estimated if r.method == m]) for m in methods},
        "estimated_methods": dict(sorted({(r.stage, r.method) for r in estimated if r.tracking})),
        "workers_present": sum(v.n_workers for v in viewpoints),
        "activity": activity,
        "detector_pixel_sigma_px": float(pixel_sigma),
        "detector_miss_rate": MISS_RATE,
        "upright": bool(upright),
    }


def tracking_markdown(results: dict, settings: str) -> str:
    """The worker-tracking table: 3D worker error with true, estimated and prior camera poses."""
    t = results["worker_tracking"]
    lines = [
        f"Settings: {settings}",
        "",
        "| Camera poses | Worker error median (m) | P95 (m) | Observations |",
        "|---|---:|---:|---:|",
    ]
    label = ", ".join(f"{m} at the {s} stage" for s, m in t["estimated_methods"].items())
    rows = [("Ground truth (floor)", t["truth"]), (f"Estimated ({label})", t["estimated"]),
            ("Onboard prior (GNSS + attitude)", t["prior"])]
    rows += [(f"Estimated, {m}", s) for m, s in t["estimated_by_method"].items()]
    for name, s in rows:
        lines.append(f"| {name} | {cell(s['median_m'])} | {cell(s['p95_m'])} | {s['n_observations']} |")
    lines += [
        "",
        f"Workers: {t['activity']} site activity, {t['workers_present']} worker-viewpoints present; "
        f"simulated feet / head-top detector, {t['detector_pixel_sigma_px']} px noise, "
        f"{t['detector_miss_rate']:.0%} misses, occlusion-tested"
        f"{'; workers triangulated standing (upright)' if t.get('upright') else ''}. "
        "An observation is a worker triangulated from >= 2 cameras at one viewpoint; its error is "
        "the larger of its feet and head-top errors. Target: P95 <= 0.15 m with estimated poses.",
    ]
    return "\n".join(lines) + "\n"
