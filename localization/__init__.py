"""Localization from BIM structural landmarks: detect, associate, PnP, ArUco baseline, metrics.

Pure numpy / scipy / OpenCV; usable on images and poses that did not come from the simulator.

    from localization import Localizer
    loc = Localizer(landmarks_xyz, K, association="robust")   # or "paper"
    est = loc.localize(detections_uv, prior_cam_from_world)
    est.success, est.cam_from_world, est.assignment

One stage per module: :mod:`~localization.detect`, :mod:`~localization.associate`,
:mod:`~localization.pose.pnp`, :mod:`~localization.aruco`, :mod:`~localization.metrics`, composed in
:mod:`~localization.pipeline`. Conventions: :mod:`~localization.geometry`.
"""

from localization.aruco import ARUCO_MODES, ArucoLocalizer, MarkerSpec
from localization.associate.paper import Association, assign, associate_paper
from localization.associate.robust import associate_robust
from localization.checks import check_choice, check_number
from localization.detect.interface import Detections, Detector
from localization.detect.projection import ProjectionDetector
from localization.failure import FailureCode
from localization.metrics import (
    AssociationScores,
    CramerRaoBound,
    ErrorSummary,
    association_scores,
    cramer_rao_bound,
    detection_rate,
    latency_summary,
    median_p90,
    pooled_scores,
    pose_errors,
    pose_nees,
    recall_at,
    rotation_error_deg,
    summarize_errors,
    translation_error_m,
)
from localization.pipeline import ASSOCIATION_METHODS, Localizer, PoseEstimate, image_size_from_K
from localization.pose.covariance import PriorSigmas, pose_covariance
from localization.pose.pnp import PnPResult, solve_pnp

__all__ = [
    "ARUCO_MODES",
    "ArucoLocalizer",
    "MarkerSpec",
    "ASSOCIATION_METHODS",
    "Association",
    "AssociationScores",
    "CramerRaoBound",
    "Detections",
    "Detector",
    "ErrorSummary",
    "FailureCode",
    "Localizer",
    "PnPResult",
    "PoseEstimate",
    "PriorSigmas",
    "ProjectionDetector",
    "assign",
    "associate_paper",
    "associate_robust",
    "check_choice",
    "check_number",
    "association_scores",
    "cramer_rao_bound",
    "detection_rate",
    "image_size_from_K",
    "latency_summary",
    "median_p90",
    "pooled_scores",
    "pose_covariance",
    "pose_errors",
    "pose_nees",
    "recall_at",
    "rotation_error_deg",
    "solve_pnp",
    "summarize_errors",
    "translation_error_m",
]
