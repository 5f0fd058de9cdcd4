"""Per-detection records of the study's structural methods (``detections.csv``).

One row per detection of every structural localization: where it is, the detector's score, the
landmark the association named (or none), the visible landmark it is within the match radius (or
none), and the landmark of the type whose true projection is nearest, visible or hidden, with its
distance. ``per_image.csv``'s counts are sums over these rows (``n_true_detections``: rows with
``true_id >= 0``; ``n_assigned``: ``assigned_id >= 0``; ``n_correct``: both and equal); the rows
say what each false positive was: clutter far from every landmark, a visible landmark placed
beyond the match radius, or a hidden one that the detector placed anyway (its ``nearest_id`` is
the assigned one and ``nearest_visible`` is false).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from uav_struct_env.study.cells import write_records_csv

__all__ = ["DetectionRow", "detection_rows", "write_detections_csv"]


@dataclass(frozen=True)
class DetectionRow:
    """One detection of one structural localization (a row of ``detections.csv``)."""

    method: str
    uav: int
    viewpoint: int
    detection: int  # its index in the detector's output
    u: float  # pixels of the delivered image (before undistortion)
    v: float
    score: float  # the detector's probability that it is a landmark; NaN without scores
    assigned_id: int  # the landmark the estimate names (as n_assigned counts); -1 none
    true_id: int  # the visible landmark within the match radius; -1 none
    nearest_id: int  # the landmark whose true projection is nearest, visible or not
    nearest_px: float  # distance to that projection
    nearest_visible: bool


def detection_rows(
    method: str,
    uav: int,
    viewpoint: int,
    uv: np.ndarray,
    scores: np.ndarray | None,
    true_ids: np.ndarray | None,
    assignment: np.ndarray,
    model_ids: np.ndarray,
    truth: dict,
) -> list[DetectionRow]:
    """The rows of one localization.

    Args:
        method: the method's key.
        uav: the image's UAV.
        viewpoint: the image's viewpoint.
        uv: (N, 2) detections.
        scores: (N,) the detector's scores, or None.
        true_ids: (N,) the visible landmark each detection is within the match radius, or None
            (then -1).
        assignment: (N,) model index per detection, -1 unassigned.
        model_ids: (M,) landmark id of each model index.
        truth: the env's ground truth for the landmark type (``ids``, ``uv``, ``visible``).
    """
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    n = uv.shape[0]
    ids = np.asarray(truth["ids"]).reshape(-1)
    uv_true = np.asarray(truth["uv"], dtype=float).reshape(-1, 2)
    visible = np.asarray(truth["visible"], dtype=bool).reshape(-1)
    score = np.full(n, np.nan) if scores is None else np.asarray(scores, dtype=float).reshape(-1)
    true = np.full(n, -1) if true_ids is None else np.asarray(true_ids).reshape(-1)
    a = np.asarray(assignment).reshape(-1)
    named = np.where(a >= 0, np.asarray(model_ids).reshape(-1)[np.maximum(a, 0)], -1)
    # (N, M) distances to every true projection; a projection that is not finite is never nearest
    diff = uv[:, None, :] - uv_true[None, :, :]
    d = np.hypot(diff[..., 0], diff[..., 1])
    d = np.where(np.isfinite(d), d, np.inf)
    j = np.argmin(d, axis=1) if ids.size else np.zeros(n, dtype=int)
    near = d[np.arange(n), j] if ids.size else np.full(n, np.inf)
    found = np.isfinite(near)
    return [
        DetectionRow(
            method=method, uav=uav, viewpoint=viewpoint, detection=i,
            u=float(uv[i, 0]), v=float(uv[i, 1]), score=float(score[i]),
            assigned_id=int(named[i]), true_id=int(true[i]),
            nearest_id=int(ids[j[i]]) if found[i] else -1,
            nearest_px=float(near[i]) if found[i] else float("nan"),
            nearest_visible=bool(visible[j[i]]) if found[i] else False,
        )
        for i in range(n)
    ]


def write_detections_csv(path: Path, rows: Sequence[DetectionRow], comment: str | None = None) -> None:
    """Every detection row, in the order given (``comment``: a first ``#`` line, the settings)."""
    write_records_csv(path, DetectionRow, rows, comment=comment)
