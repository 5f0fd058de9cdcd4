"""One frame's "detect -> localize -> score" step, shared by the wrapper and scripts.

:func:`localize_frame` runs a detector on one camera frame, localizes the detections against
the BIM landmarks from the onboard prior and scores the result against ground truth
(translation/rotation error, association precision/recall/F1, latency). It holds no state:
the caller owns the detector (and its seeded generator) and the localizer.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization import AssociationScores, Detections, Localizer, PoseEstimate
from localization.metrics import association_scores, pose_errors

__all__ = ["FrameLocalization", "localize_aruco_frame", "localize_frame"]


@dataclass(frozen=True, eq=False)
class FrameLocalization:
    """The outcome of :func:`localize_frame` for one frame.

    Attributes:
        estimate: the localizer's :class:`~localization.PoseEstimate` (the prior when failed).
        detections: what the detector returned.
        scores: association precision/recall/F1 against the detections' true ids (NaN-free
            only for simulated detectors that know ``true_ids``; else all NaN).
        translation_error_m: camera-centre error of the estimate, m (NaN when failed or when
            no ground truth was given).
        rotation_error_deg: geodesic rotation error, deg (NaN likewise).
        prior_translation_error_m: camera-centre error of the prior, m (NaN without truth).
        latency_s: detection + localization wall time, s.
    """

    estimate: PoseEstimate
    detections: Detections
    scores: AssociationScores
    translation_error_m: float
    rotation_error_deg: float
    prior_translation_error_m: float
    latency_s: float


_NO_SCORES = AssociationScores(0, 0, 0, float("nan"), float("nan"), float("nan"))


def localize_frame(
    detector: Any,
    localizer: Localizer,
    image: Any,
    context: Mapping[str, Any],
    prior_cam_from_world: NDArray[np.float64],
    gt_cam_from_world: NDArray[np.float64] | None = None,
    model_ids: NDArray[np.int64] | None = None,
) -> FrameLocalization:
    """Detect, localize and score one frame.

    Args:
        detector: anything with ``detect(image, context) -> Detections``.
        localizer: a :class:`~localization.Localizer` over the landmark set's model points.
        image: the frame (ignored by simulated detectors).
        context: the detector context (``landmarks``: per-set truth dicts, ``image_size``).
        prior_cam_from_world: (4, 4) onboard prior.
        gt_cam_from_world: (4, 4) ground truth, or None (errors are then NaN).
        model_ids: (M,) landmark id of each model index (for association scores); default the
            index itself.
    """
    t0 = time.perf_counter()
    det = detector.detect(image, context)
    t_detect = time.perf_counter() - t0
    est = localizer.localize(det.uv, prior_cam_from_world)
    latency = t_detect + float(est.timings.get("total", 0.0))
    scores = (
        association_scores(est.assignment, det.true_ids, model_ids)
        if det.true_ids is not None
        else _NO_SCORES
    )
    return _scored(est, det, scores, prior_cam_from_world, gt_cam_from_world, latency)


def localize_aruco_frame(
    aruco: Any,
    image: Any,
    prior_cam_from_world: NDArray[np.float64],
    gt_cam_from_world: NDArray[np.float64] | None = None,
) -> FrameLocalization:
    """Localize one frame from its ArUco markers and score it like :func:`localize_frame`.

    ``aruco`` is a :class:`localization.aruco.ArucoLocalizer`. Markers carry their ids, so there
    are no anonymous detections and no association scores.
    """
    t0 = time.perf_counter()
    est = aruco.localize(image, prior_cam_from_world)
    latency = time.perf_counter() - t0
    det = Detections(np.zeros((0, 2)))
    return _scored(est, det, _NO_SCORES, prior_cam_from_world, gt_cam_from_world, latency)


def _scored(est, det, scores, prior, gt, latency) -> FrameLocalization:
    nan = float("nan")
    if gt is None:
        t_err = r_err = p_err = nan
    else:
        p_err = pose_errors(prior, gt)[0]
        t_err, r_err = pose_errors(est.cam_from_world, gt) if est.success else (nan, nan)
    return FrameLocalization(est, det, scores, float(t_err), float(r_err), float(p_err), latency)
