"""One frame's "detect -> localize -> score" step, shared by the study, the wrapper and scripts.

:func:`localize_frame` runs a detector on one camera frame, localizes the detections against
the BIM landmarks from the onboard prior and scores the result against ground truth
(translation/rotation error, association precision/recall/F1, latency);
:func:`localize_aruco_frame` does the same from ArUco markers. They hold no state: the caller
owns the detector (and its seeded generator) and the localizer, usually through a
:class:`~uav_struct_env.stack.LocalizationStack` built from a
:class:`~uav_struct_env.stack.StackSpec`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
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
        marker_ids: (K,) ids of the ArUco markers decoded in the frame (:func:`localize_aruco_frame`
            only; None for structural landmarks).
        prior_rotation_error_deg: geodesic rotation error of the prior, deg (NaN without truth).
    """

    estimate: PoseEstimate
    detections: Detections
    scores: AssociationScores
    translation_error_m: float
    rotation_error_deg: float
    prior_translation_error_m: float
    latency_s: float
    marker_ids: NDArray[np.int64] | None = None
    prior_rotation_error_deg: float = float("nan")


_NO_SCORES = AssociationScores(0, 0, 0, float("nan"), float("nan"), float("nan"))


def localize_frame(
    detector: Any,
    localizer: Localizer,
    image: Any,
    context: Mapping[str, Any],
    prior_cam_from_world: NDArray[np.float64],
    gt_cam_from_world: NDArray[np.float64] | None = None,
    model_ids: NDArray[np.int64] | None = None,
    *,
    prior_sigmas: Any = None,
    warm_start: NDArray[np.float64] | None = None,
    confirmation: Any = None,
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
        prior_sigmas: this frame's :class:`~localization.PriorSigmas` (None: the localizer's).
        warm_start: a (4, 4) ``cam_from_world`` predicted for this frame
            (:meth:`localization.Localizer.localize`), or None.
        confirmation: a :class:`~uav_struct_env.stack.confirm.PoseConfirmation` the pose is
            held to in ``image`` (its time is the estimate's ``confirm`` timing and part of the
            latency), or None.
    """
    t0 = time.perf_counter()
    det = detector.detect(image, context)
    t_detect = time.perf_counter() - t0
    est = localizer.localize(det, prior_cam_from_world, prior_sigmas=prior_sigmas, warm_start=warm_start)
    if confirmation is not None:
        t1 = time.perf_counter()
        est = confirmation.confirmed(image, est, prior_cam_from_world)
        est.timings["confirm"] = time.perf_counter() - t1
    latency = t_detect + float(est.timings.get("total", 0.0)) + float(est.timings.get("confirm", 0.0))
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
    *,
    use_prior: bool = True,
) -> FrameLocalization:
    """Localize one frame from its ArUco markers and score it like :func:`localize_frame`.

    ``aruco`` is a :class:`localization.aruco.ArucoLocalizer`. Markers carry their ids, so there
    are no anonymous detections and no association scores; ``detections`` holds the decoded
    markers' corners (4 per marker) and ``marker_ids`` their ids. With ``use_prior=False`` the
    prior does not choose between a marker's two IPPE solutions (the lowest reprojection error
    does); errors are still measured against it.
    """
    t0 = time.perf_counter()
    ids, corners = aruco.detect(image)
    est = aruco.localize_corners(ids, corners, prior_cam_from_world if use_prior else None)
    latency = time.perf_counter() - t0
    det = Detections(np.asarray(corners, dtype=np.float64).reshape(-1, 2))
    frame = _scored(est, det, _NO_SCORES, prior_cam_from_world, gt_cam_from_world, latency)
    return replace(frame, marker_ids=np.asarray(ids, dtype=np.int64))


def _scored(est, det, scores, prior, gt, latency) -> FrameLocalization:
    nan = float("nan")
    if gt is None:
        t_err = r_err = p_err = p_rot = nan
    else:
        p_err, p_rot = pose_errors(prior, gt)
        t_err, r_err = pose_errors(est.cam_from_world, gt) if est.success else (nan, nan)
    return FrameLocalization(est, det, scores, float(t_err), float(r_err), float(p_err), latency,
                             prior_rotation_error_deg=float(p_rot))
