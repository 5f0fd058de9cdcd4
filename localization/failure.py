"""Why a localization failed: a machine-readable :class:`FailureCode` beside the human message.

Every failed :class:`~localization.pipeline.PoseEstimate` (and the
:class:`~localization.associate.paper.Association` / :class:`~localization.pose.pnp.PnPResult` it came
from) carries ``failure_code`` -- one of a closed set, for grouping and counting -- and
``failure_reason``, a message with the numbers of that case (counts, thresholds) for people.
Group by the code, never by the message: messages differ whenever the numbers do.
"""

from __future__ import annotations

from enum import Enum

__all__ = ["FailureCode"]


class FailureCode(str, Enum):
    """The cause of a failed pose; its ``value`` is the string written to results.json."""

    #: Fewer usable (finite) detections than the minimum number of correspondences.
    TOO_FEW_DETECTIONS = "too_few_detections"
    #: No model landmark projects in front of the prior camera near the image.
    NO_CANDIDATES = "no_candidates"
    #: Every association hypothesis gave a pose too far from the prior (Mahalanobis gate).
    INCONSISTENT_WITH_PRIOR = "inconsistent_with_prior"
    #: No association hypothesis kept enough mutually consistent correspondences.
    NO_CONSISTENT_ASSOCIATION = "no_consistent_association"
    #: Two association hypotheses with conflicting identities and distinct poses fit about
    #: equally well: the geometry cannot tell them apart (:mod:`localization.associate.ambiguity`).
    AMBIGUOUS = "ambiguous"
    #: Fewer assigned detections than the minimum number of correspondences.
    TOO_FEW_CORRESPONDENCES = "too_few_correspondences"
    #: The PnP solver returned no pose, or a non-finite one.
    PNP_FAILED = "pnp_failed"
    #: Every candidate pose puts landmarks (or marker corners) behind the camera.
    BEHIND_CAMERA = "behind_camera"
    #: The inlier detections lie on a line (landmarks seen edge-on).
    DEGENERATE_GEOMETRY = "degenerate_geometry"
    #: The pose covariance exceeds the localizer's ``max_position_std_m``.
    ILL_CONDITIONED = "ill_conditioned"
    #: No marker of the map was detected (ArUco).
    NO_MARKERS = "no_markers"
    #: A failure without a code (e.g. from a third-party localizer).
    UNKNOWN = "unknown"
    # Added later, after UNKNOWN: a code's position is its number in the wrappers' observations.
    #: The pose's support is what chance gives: it matches too few of the landmarks it projects
    #: into the image for the detections' density (dense clutter), or it rests on the minimum
    #: number of pairs and fits them more loosely than 95 % of true poses (:mod:`localization.verify`).
    UNSUPPORTED = "unsupported"
    #: Unassigned detections at one offset from the pairs fit the same landmarks about as well
    #: with a distinct camera centre: a detector's ghost copy that only the prior could tell from
    #: the structure (:mod:`localization.verify`).
    DUPLICATED_DETECTIONS = "duplicated_detections"
    #: A pose on few pairs that the building's structure, matched in the image around what the
    #: pose predicts, places elsewhere: a nearby pose explains the image clearly better
    #: (:mod:`uav_struct_env.stack.confirm`).
    UNCONFIRMED = "unconfirmed"
    #: The localization did not finish within the localizer's time budget (``time_budget_s``,
    #: :mod:`localization.budget`): a search cut short cannot rule out the rivals a full one finds.
    TIMED_OUT = "timed_out"
