"""Stage 2, association, the paper's method: project the BIM with the prior and solve the assignment.

:func:`candidate_landmarks` projects the BIM landmarks with the prior pose and keeps those in
front of the camera and near the image; :func:`assign` solves the rectangular minimum-cost
one-to-one assignment on squared pixel distance (``scipy.optimize.linear_sum_assignment``,
Crouse 2016), optionally gated; :func:`associate_paper` composes them. Every detection is
assigned whenever there are at least as many projected landmarks; nothing is gated.
:class:`Association` is the result of either method (see :mod:`localization.associate.robust`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from localization.associate.assign_kernels import assignment_costs, assignment_rows, candidates
from localization.failure import FailureCode
from localization.geometry.kernels import kernel_array
from localization.geometry.transforms import project

__all__ = ["Association", "assign", "associate_paper", "candidate_landmarks"]


@dataclass(frozen=True, eq=False)
class Association:
    """Result of an association.

    Attributes:
        assignment: (N,) model landmark index of each detection, -1 when unassigned.
        cam_from_world: (4, 4) the pose the final assignment was computed against (the prior for
            ``paper``; the best hypothesis' refined pose for ``robust``).
        cost: sum of squared pixel distances of the assigned pairs at that pose, px^2.
        score: the hypothesis score (``robust``: negative log-likelihood; ``paper``: ``cost``).
        n_hypotheses: number of distinct hypotheses evaluated.
        failure_reason: set when nothing could be assigned (e.g. no landmark in front of the
            camera), else None.
        failure_code: the :class:`~localization.failure.FailureCode` of ``failure_reason``.
        warm_started: True when the robust association's warm start (a predicted pose) was
            accepted and no hypothesis search ran (:func:`associate_robust`, ``warm_start``).
    """

    assignment: NDArray[np.int64]
    cam_from_world: NDArray[np.float64]
    cost: float
    score: float
    n_hypotheses: int = 1
    failure_reason: str | None = None
    failure_code: FailureCode | None = None
    warm_started: bool = False

    @property
    def n_assigned(self) -> int:
        """Number of detections with a model landmark."""
        return int(np.sum(self.assignment >= 0))


def candidate_landmarks(
    landmarks_xyz: NDArray[np.float64],
    K: NDArray[np.float64],
    cam_from_world: NDArray[np.float64],
    image_size: tuple[int, int],
    margin_px: float,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Indices and projections of the landmarks in front of the camera and near the image.

    "Near" means within ``margin_px`` of the image rectangle ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.
    """
    w, h = image_size
    f64 = np.float64
    return candidates(  # compiled: :func:`localization.geometry.transforms.project` and the bounds, one loop
        kernel_array(K, dtype=f64), kernel_array(cam_from_world, dtype=f64),
        kernel_array(landmarks_xyz, dtype=f64), int(w), int(h), float(margin_px),
    )


def assign(
    det_uv: NDArray[np.float64], model_uv: NDArray[np.float64], gate_px: float | None = None
) -> NDArray[np.int64]:
    """Minimum total squared distance one-to-one assignment of detections to model points.

    Args:
        det_uv: (N, 2) detections.
        model_uv: (M, 2) projected model points.
        gate_px: if given, a pair farther apart than this is never made, and a detection may stay
            unassigned (each unassigned detection costs ``gate_px^2``, so a pair is only made when
            it is within the gate); if None, the plain rectangular assignment (the paper's).

    Returns:
        (N,) index into ``model_uv`` per detection, -1 when unassigned.
    """
    n, m = det_uv.shape[0], model_uv.shape[0]
    if n == 0 or m == 0:
        return np.full(n, -1, dtype=np.int64)
    # Gated, the total cost = sum of assigned d2 + g2 per unassigned detection = n g2 + sum
    # (d2 - g2) over the pairs: so minimize sum min(d2 - g2, 0); pairs beyond the gate cost 0 and
    # are dropped. Compiled: the costs and the reading of the assignment.
    gated = gate_px is not None
    f64 = np.float64
    cost = assignment_costs(
        kernel_array(det_uv, dtype=f64), kernel_array(model_uv, dtype=f64),
        float(gate_px) ** 2 if gated else 0.0, gated,
    )
    rows, cols = linear_sum_assignment(cost)
    return assignment_rows(cost, rows, cols, gated)


def associate_paper(
    detections_uv: NDArray[np.float64],
    landmarks_xyz: NDArray[np.float64],
    K: NDArray[np.float64],
    prior_cam_from_world: NDArray[np.float64],
    image_size: tuple[int, int],
    margin_px: float,
) -> Association:
    """The paper's association: plain rectangular linear assignment at the prior projection.

    Inputs are assumed validated (see :class:`localization.pipeline.Localizer`); detections with
    NaN coordinates stay unassigned.
    """
    n = detections_uv.shape[0]
    out = np.full(n, -1, dtype=np.int64)
    idx, proj = candidate_landmarks(landmarks_xyz, K, prior_cam_from_world, image_size, margin_px)
    if idx.size == 0:
        return no_candidates(out, prior_cam_from_world, 0.0, 1)
    good = np.flatnonzero(np.isfinite(detections_uv).all(axis=1))
    local = assign(detections_uv[good], proj, None)
    ok = local >= 0
    out[good[ok]] = idx[local[ok]]
    a = out >= 0
    cost = float(
        np.sum((detections_uv[a] - project(K, prior_cam_from_world, landmarks_xyz[out[a]])[0]) ** 2)
    )
    return Association(out, prior_cam_from_world, cost, cost, 1, None)


def no_candidates(assignment: NDArray, prior: NDArray, score: float, n_hypotheses: int) -> Association:
    """The failed association of a prior that projects no landmark in front of it near the image."""
    return Association(
        assignment, prior, 0.0, score, n_hypotheses,
        "no landmark projects in front of the prior camera near the image", FailureCode.NO_CANDIDATES,
    )
