"""Tracking error statistics: per-worker 3D errors against the truth and their summary.

The error of one worker observation (one tracked worker at one instant) is the larger of its
feet and head-top errors, ``max(|feet_est - feet_true|, |head_est - head_true|)`` in metres: a
worker counts as located only as well as its worse point. A tracked worker is compared with the
true worker its detections' labels name most often, so a wrong association shows up as a large
error rather than disappearing.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tracking.tracker import TrackingResult

__all__ = ["error_summary", "worker_errors"]


def worker_errors(result: TrackingResult, truth: Mapping[Hashable, ArrayLike]) -> NDArray[np.float64]:
    """(K,) 3D error in m of each tracked worker whose label is in ``truth``.

    Args:
        result: a :func:`~tracking.track_workers` result whose detections carry labels.
        truth: per label, the (2, 3) true points (row 0 feet, row 1 head top), m.
    """
    errors = []
    for w in result.tracked:
        if w.label not in truth:
            continue
        true = np.asarray(truth[w.label], dtype=np.float64).reshape(2, 3)
        errors.append(float(np.max(np.linalg.norm(w.points - true, axis=1))))
    return np.asarray(errors, dtype=np.float64)


def error_summary(errors: Iterable[float]) -> dict[str, float | int]:
    """``{"median_m", "p95_m", "n_observations"}`` of finite errors (NaN statistics when none)."""
    e = np.asarray(list(errors), dtype=np.float64).reshape(-1)
    e = e[np.isfinite(e)]
    if e.size == 0:
        return {"median_m": float("nan"), "p95_m": float("nan"), "n_observations": 0}
    return {
        "median_m": float(np.median(e)),
        "p95_m": float(np.percentile(e, 95)),
        "n_observations": int(e.size),
    }
