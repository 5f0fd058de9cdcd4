"""Stage composition: anonymous detections + prior pose -> :class:`PoseEstimate`.

from localization import Localizer
loc = Localizer(landmarks_xyz, K, association="robust")
est = loc.localize(detections_uv, prior_cam_from_world)
est.success, est.cam_from_world, est.assignment
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.associate.paper import Association, associate_paper
from localization.associate.robust import associate_robust
from localization.budget import Deadline
from localization.checks import check_choice, check_number
from localization.detect.interface import Detections, check_image_size
from localization.failure import FailureCode
from localization.geometry.distortion import check_distortion, is_pinhole, undistort_points
from localization.geometry.kernels import minor_spread
from localization.geometry.transforms import (
    as_points,
    camera_center,
    check_intrinsics,
    check_transform,
    invert,
)
from localization.pose.covariance import PriorSigmas, pose_covariance, prior_mahalanobis_sq
from localization.pose.finish import FinishInputs, finish_pose
from localization.pose.pnp import is_coplanar, solve_pnp
from localization.verify import VerifyInputs, landmark_spacing_m, verify_pose

__all__ = ["ASSOCIATION_METHODS", "Localizer", "PoseEstimate", "image_size_from_K"]

ASSOCIATION_METHODS = ("paper", "robust")


@dataclass(frozen=True, eq=False)
class PoseEstimate:
    """A camera pose estimate with its quality.

    Attributes:
        success: True when a pose was estimated from at least ``min_correspondences`` inliers.
        cam_from_world: (4, 4) the estimate; when not successful, the prior (a valid fallback).
        assignment: (N,) model landmark index of each detection, -1 if unassigned or an outlier.
        reprojection_rmse_px: RMSE of the inliers at the estimate, px (inf when failed).
        n_inliers: number of correspondences in the final pose.
        covariance: (6, 6) pose covariance from the Jacobian at the estimate and the localizer's
            ``pixel_sigma``. Parameterization: first 3 = camera centre in the project frame [m],
            last 3 = small rotation vector [rad] in the project frame perturbing
            ``world_from_cam`` (``R' = exp([dtheta]x) R``). All inf when unknown.
        failure_reason: why it failed, for people (with the numbers of the case), or None.
        failure_code: why it failed, for grouping: a :class:`~localization.failure.FailureCode`
            (``UNKNOWN`` when a failed estimate was built without one), None on success.
        timings: seconds per stage (``validate``, ``associate``, ``pnp``, ``covariance``,
            ``verify``, ``total``). ``associate`` includes the PnP runs made inside robust association; in
            robust mode ``pnp`` includes the covariance (one compiled call) and ``covariance`` is 0.
        prior_mahalanobis_sq: squared Mahalanobis distance of the estimate from the prior.
        n_hypotheses: association hypotheses evaluated.
        warm_started: True when the robust association accepted the warm start
            (:meth:`Localizer.localize`, ``warm_start``) and searched no hypothesis.
        refused_cam_from_world: (4, 4) the pose the verification refused (what the localizer
            returns with ``verify=False``), None unless the verification ended the frame. A caller
            that wants a pose to look from even unconfirmed reads it here instead of localizing
            again without the verification.
    """

    success: bool
    cam_from_world: NDArray[np.float64]
    assignment: NDArray[np.int64]
    reprojection_rmse_px: float = float("inf")
    n_inliers: int = 0
    covariance: NDArray[np.float64] = field(default_factory=lambda: np.full((6, 6), np.inf))
    failure_reason: str | None = None
    timings: dict[str, float] = field(default_factory=dict)
    prior_mahalanobis_sq: float = float("nan")
    n_hypotheses: int = 0
    failure_code: FailureCode | None = None
    warm_started: bool = False
    refused_cam_from_world: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        if not self.success and self.failure_code is None:
            object.__setattr__(self, "failure_code", FailureCode.UNKNOWN)

    @property
    def world_from_cam(self) -> NDArray[np.float64]:
        """(4, 4) inverse of ``cam_from_world``."""
        return invert(self.cam_from_world)

    @property
    def position(self) -> NDArray[np.float64]:
        """(3,) camera centre in the project frame, metres."""
        return camera_center(self.cam_from_world)

    @property
    def pose_std(self) -> NDArray[np.float64]:
        """(6,) standard deviations from ``covariance``: position x, y, z [m], rotation [rad]."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))


@dataclass(frozen=True, eq=False)
class _Frame:
    """One frame's validated inputs to :meth:`Localizer.localize`.

    Attributes:
        detections_uv: (N, 2) the detections, pinhole pixels.
        prior: (4, 4) the prior ``cam_from_world``.
        prior_sigmas: the prior's uncertainty for this frame.
        scores: (N,) the detections' probabilities of being landmarks, or None.
        warm_start: (4, 4) the predicted ``cam_from_world`` to try first, or None.
        deadline: when the call must be done (``time_budget_s``), or None.
    """

    detections_uv: NDArray[np.float64]
    prior: NDArray[np.float64]
    prior_sigmas: PriorSigmas
    scores: NDArray[np.float64] | None
    warm_start: NDArray[np.float64] | None
    deadline: Deadline | None = None


@dataclass(frozen=True, eq=False)
class _Pose:
    """A pose finished on the association's pairs, before the checks both modes share.

    Attributes:
        cam_from_world: (4, 4) the pose.
        assignment: (N,) model landmark of each detection, -1 if unassigned or an outlier.
        n_inliers: correspondences in the pose.
        rmse_px: reprojection RMSE of the inliers, px.
        covariance: (6, 6) in ``(C [m], dtheta [rad])``.
        spread_px: RMS distance of the inlier detections from their best-fit line, px.
        prior_mahalanobis_sq: squared Mahalanobis distance from the prior when already
            computed, else None (computed for the estimate).
    """

    cam_from_world: NDArray[np.float64]
    assignment: NDArray[np.int64]
    n_inliers: int
    rmse_px: float
    covariance: NDArray[np.float64]
    spread_px: float
    prior_mahalanobis_sq: float | None = None


@dataclass(frozen=True, eq=False)
class _Failure:
    """Why a step of :meth:`Localizer.localize` ends the frame without a pose.

    Attributes:
        code: for grouping.
        reason: for people, with the numbers of the case.
        assignment: (N,) the assignment so far, or None (all -1).
        n_hypotheses: association hypotheses evaluated.
        refused_cam_from_world: (4, 4) the pose the verification refused, or None.
    """

    code: FailureCode
    reason: str
    assignment: NDArray[np.int64] | None = None
    n_hypotheses: int = 0
    refused_cam_from_world: NDArray[np.float64] | None = None


def _optional_positive(name: str, value: float | None) -> float | None:
    """None, or ``value`` checked to be a positive finite number (:func:`check_number`)."""
    return None if value is None else check_number(name, value, 0, lo_open=True)


class Localizer:
    """Structural-landmark localizer: association with the BIM, then PnP.

    Args:
        landmarks_xyz: (M, 3) model landmarks in the project frame, metres.
        K: (3, 3) camera intrinsics.
        association: ``"robust"`` (default) or ``"paper"`` (see :mod:`localization.associate`).
        pixel_sigma: detector noise, px (gates and the covariance).
        image_size: (W, H) of the detections' image. Association keeps only the landmarks whose
            prior projection falls within ``margin_px`` of ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``,
            and ``margin_px`` defaults to a quarter of the larger side. Default:
            :func:`image_size_from_K` -- exact for the paper's camera and for every camera the
            environment scales from it (128 x 72 gives 128 x 72); pass it for other cameras.
        margin_px: how far outside the image a prior projection may fall and still be a
            candidate; default a quarter of the larger image side.
        min_correspondences: fewer inliers fail (>= 3; the paper and the default use 4).
        gate_px: robust final inlier gate, px; default ``max(5 * pixel_sigma, 3)``.
        coarse_gate_px: robust first-assignment gate, px.
        max_hypotheses: robust mode: distinct coarse assignments refined by PnP + re-association.
        prior_sigmas: :class:`~localization.pose.covariance.PriorSigmas` or a 2-tuple
            ``(position_m, (tilt_x_deg, tilt_y_deg, yaw_deg))``; default 3 m and 2, 2, 5 degrees.
        ransac: in ``paper`` mode, reject outliers with RANSAC before LM when >= 6 pairs.
        ransac_threshold_px: RANSAC inlier threshold, px.
        max_position_std_m: if set, a pose whose covariance gives a position std (largest axis)
            above this fails as ill-conditioned.
        max_prior_mahalanobis_sq: robust mode rejects association hypotheses whose pose is
            farther from the prior than this squared Mahalanobis distance (6 dof; default the
            chi-square 99.9 % quantile); None disables the check.
        distortion: the camera's OpenCV coefficients ``(k1, k2, p1, p2, k3)``
            (:mod:`localization.geometry.distortion`), or None for a pinhole. Detections are undistorted
            to pinhole pixels of ``K`` once, on entry; everything after (association, PnP,
            residuals, covariance) is the pinhole model.
        use_scores: robust mode, with :class:`Detections` that carry ``scores``: read them as the
            probability that each detection is a landmark (in [0, 1], as the learned detector's
            refiner gives them) and let their log-odds enter the hypotheses' scoring
            (:mod:`localization.associate`, step 3). False ignores them.
        verify: robust mode: hold the finished pose to what it predicts
            (:mod:`localization.verify`): a pose whose support the detections' density gives by
            chance, that rests on pairs the others reject, or that a ghost copy of the detections
            or a period of the layout fits as well, fails with its reason.
            False reports it unverified (the ``paper`` association never verifies: it is the
            paper's method).
        fit_sigma_px: the detector's own calibrated pixel noise, which the verification's fit
            tests (a minimal fit's residuals, each pair's leave-one-out residual) hold the pairs
            to; None: ``pixel_sigma``. The learned detector declares one
            (:data:`localization.detect.learned.FIT_PIXEL_SIGMA_PX`).
        tolerance_m: the position error a reported pose must be confirmed within, m (three times
            the bound of the landmarks it predicts, where that is larger): a pose that leaving out
            one of its pairs moves farther fails as ill-conditioned (:mod:`localization.verify`).
            None (default): no such test.
        time_budget_s: the most wall-clock seconds one :meth:`localize` call may take; a call
            past it fails as ``TIMED_OUT`` (:mod:`localization.budget`: the robust search checks
            it between steps, so a call may overrun by one step). None (default): no bound, and
            the results are the same to the bit whatever the machine's speed or load.

    Raises:
        TypeError, ValueError: on bad arguments, naming the value and what was expected.
    """

    def __init__(
        self,
        landmarks_xyz: ArrayLike,
        K: ArrayLike,
        association: str = "robust",
        *,
        pixel_sigma: float = 1.0,
        image_size: Sequence[int] | None = None,
        margin_px: float | None = None,
        min_correspondences: int = 4,
        gate_px: float | None = None,
        coarse_gate_px: float = 40.0,
        max_hypotheses: int = 8,
        prior_sigmas: PriorSigmas | tuple | None = None,
        ransac: bool = False,
        ransac_threshold_px: float = 8.0,
        max_position_std_m: float | None = None,
        max_prior_mahalanobis_sq: float | None = 22.46,
        distortion: ArrayLike | None = None,
        use_scores: bool = True,
        verify: bool = True,
        fit_sigma_px: float | None = None,
        tolerance_m: float | None = None,
        time_budget_s: float | None = None,
    ) -> None:
        X = as_points("landmarks_xyz", landmarks_xyz, 3)
        if X.shape[0] == 0:
            raise ValueError("landmarks_xyz must hold at least one landmark, got shape (0, 3)")
        if not np.all(np.isfinite(X)):
            raise ValueError("landmarks_xyz must be finite")
        # Its own writable copy: numba compiles a kernel once per argument type, and a read-only array
        # (a site's landmarks) is another type than the warm-up's and every array derived from it.
        self.landmarks_xyz = np.array(X, dtype=np.float64, order="C")
        self.K = np.ascontiguousarray(check_intrinsics("K", K))
        self.association = check_choice(
            "association", association, ASSOCIATION_METHODS, type_error=TypeError
        )
        self.pixel_sigma = check_number("pixel_sigma", pixel_sigma, 0, lo_open=True)
        if image_size is None:
            image_size = image_size_from_K(self.K)
        self.image_size = check_image_size("image_size", image_size)
        self.margin_px = (
            0.25 * max(self.image_size)
            if margin_px is None
            else check_number("margin_px", margin_px, 0)
        )
        self.min_correspondences = check_number(
            "min_correspondences", min_correspondences, 3, integer=True
        )
        self.gate_px = _optional_positive("gate_px", gate_px)
        self.coarse_gate_px = check_number("coarse_gate_px", coarse_gate_px, 0, lo_open=True)
        self.max_hypotheses = check_number(
            "max_hypotheses", max_hypotheses, 0, integer=True, type_error=ValueError
        )
        self.prior_sigmas = self._prior_sigmas(prior_sigmas)
        self.ransac = bool(ransac)
        self.ransac_threshold_px = check_number("ransac_threshold_px", ransac_threshold_px, 0, lo_open=True)
        self.max_position_std_m = _optional_positive("max_position_std_m", max_position_std_m)
        self.max_prior_mahalanobis_sq = _optional_positive(
            "max_prior_mahalanobis_sq", max_prior_mahalanobis_sq
        )
        self.coplanar = is_coplanar(X)
        self.distortion = distortion
        if not isinstance(use_scores, (bool, np.bool_)):
            raise TypeError(f"use_scores must be True or False, got {use_scores!r}")
        self.use_scores = bool(use_scores)
        if not isinstance(verify, (bool, np.bool_)):
            raise TypeError(f"verify must be True or False, got {verify!r}")
        self.verify = bool(verify)
        self.fit_sigma_px = _optional_positive("fit_sigma_px", fit_sigma_px)
        self.tolerance_m = _optional_positive("tolerance_m", tolerance_m)
        self.time_budget_s = _optional_positive("time_budget_s", time_budget_s)

    @property
    def distortion(self) -> NDArray[np.float64]:
        """(5,) the camera's OpenCV coefficients ``(k1, k2, p1, p2, k3)``, zeros for a pinhole."""
        return self._distortion

    @distortion.setter
    def distortion(self, value: ArrayLike | None) -> None:
        self._distortion = check_distortion("distortion", value)
        self._pinhole = is_pinhole(self._distortion)  # checked once, not per frame

    @staticmethod
    def _prior_sigmas(value: PriorSigmas | tuple | None) -> PriorSigmas:
        if value is None:
            return PriorSigmas()
        if isinstance(value, PriorSigmas):
            return value
        try:
            pos, rot_deg = value
            pos = np.broadcast_to(np.asarray(pos, dtype=float), (3,))
            rot = np.radians(np.broadcast_to(np.asarray(rot_deg, dtype=float), (3,)))
        except (TypeError, ValueError):
            raise ValueError(
                "prior_sigmas must be PriorSigmas or "
                f"(position_m, (tilt_x_deg, tilt_y_deg, yaw_deg)), got {value!r}"
            ) from None
        if not (
            np.all(pos > 0)
            and np.all(rot > 0)
            and np.all(np.isfinite(pos))
            and np.all(np.isfinite(rot))
        ):
            raise ValueError(f"prior_sigmas must be positive and finite, got {value!r}")
        return PriorSigmas(tuple(pos.tolist()), tuple(rot.tolist()))

    def _edge_on(
        self, what: str, uv: NDArray[np.float64] | None = None, spread: float | None = None
    ) -> str | None:
        """Why ``uv`` cannot give a pose when its points lie on one line, else None.

        Landmarks whose images lie on one line (a plane seen edge-on) admit several poses that
        fit equally well; the covariance at any one of them does not show it. ``spread``: the
        points' spread across their line (:func:`_minor_spread_px`) when already computed,
        instead of ``uv``.
        """
        if spread is None:
            spread = _minor_spread_px(uv)
        if spread >= max(2.0 * self.pixel_sigma, 1.0):
            return None
        return (
            f"degenerate geometry: the {what} lie on a line (spread across it {spread:.2g} px), "
            "the landmarks are seen edge-on"
        )

    # ----------------------------------------------------------------------------------------

    def associate(
        self,
        detections_uv: NDArray[np.float64],
        prior: NDArray[np.float64],
        prior_sigmas: PriorSigmas | None = None,
        scores: NDArray[np.float64] | None = None,
        warm_start: NDArray[np.float64] | None = None,
        deadline: Deadline | None = None,
    ) -> Association:
        """Run the configured association only (validated inputs).

        ``prior_sigmas`` and ``warm_start`` as in :meth:`localize`; ``scores`` the detections'
        probabilities of being landmarks (robust mode only); ``deadline`` the robust search's
        (:mod:`localization.budget`; None: no bound).
        """
        if self.association == "paper":
            return associate_paper(
                detections_uv, self.landmarks_xyz, self.K, prior, self.image_size, self.margin_px
            )
        return associate_robust(
            detections_uv,
            self.landmarks_xyz,
            self.K,
            prior,
            self.image_size,
            self.margin_px,
            pixel_sigma=self.pixel_sigma,
            gate_px=self.gate_px,
            coarse_gate_px=self.coarse_gate_px,
            max_hypotheses=self.max_hypotheses,
            min_correspondences=self.min_correspondences,
            prior_sigmas=self.prior_sigmas if prior_sigmas is None else prior_sigmas,
            max_prior_mahalanobis_sq=self.max_prior_mahalanobis_sq,
            detection_scores=scores,
            warm_start=warm_start,
            deadline=deadline,
        )

    def localize(
        self,
        detections_uv: ArrayLike | Detections,
        prior_cam_from_world: ArrayLike,
        *,
        prior_sigmas: PriorSigmas | tuple | None = None,
        warm_start: ArrayLike | None = None,
    ) -> PoseEstimate:
        """Estimate ``cam_from_world`` from anonymous detections and a rough prior pose.

        One sequence for both association modes: validate the inputs, check the detections can
        give a pose, associate them with the landmarks (:meth:`associate`), finish a pose on the
        association's pairs (the mode's way: PnP on them for ``paper``, the refinement of the
        association's own pose for ``robust``), check that pose (in ``robust`` mode, verify it:
        :mod:`localization.verify`; a verified pose whose outlier test dropped pairs is
        reported refit without them, those detections unassigned), build the estimate.

        Args:
            detections_uv: (N, 2) pixel detections (or a :class:`Detections`); rows with NaN are
                ignored (assignment -1).
            prior_cam_from_world: (4, 4) rough pose from GNSS + attitude.
            prior_sigmas: this frame's prior sigmas (as the constructor's), e.g. a filter's
                prediction (:meth:`localization.temporal.PoseFilter.prior_sigmas`); None: the
                localizer's own.
            warm_start: robust mode: a (4, 4) ``cam_from_world`` predicted for this frame (e.g.
                the previous frame's estimate moved by the commanded motion), tried before the
                hypothesis search and accepted only when it explains the whole frame
                (:mod:`localization.associate`, *Warm start*); None (default): the full search.
                Ignored by the ``paper`` association.

        Returns:
            A :class:`PoseEstimate`. Degenerate input (too few usable detections or
            correspondences, no landmark in front of the camera) gives ``success=False`` with a
            ``failure_reason`` and the prior as ``cam_from_world``.

        Raises:
            TypeError, ValueError: if the detections are not (N, 2) numbers or the prior is not a
                4x4 rigid transform.
        """
        t0 = time.perf_counter()
        frame = self._frame(detections_uv, prior_cam_from_world, prior_sigmas, warm_start, t0)
        t1 = time.perf_counter()
        timings = {"validate": t1 - t0}
        failure = self._check_detections(frame.detections_uv)
        if failure is not None:  # no association can help: fail before trying any
            return self._failed(frame, failure, timings, t0)
        assoc = self.associate(
            frame.detections_uv, frame.prior, frame.prior_sigmas, frame.scores, frame.warm_start,
            frame.deadline,
        )
        t2 = time.perf_counter()
        timings["associate"] = t2 - t1
        failure = self._check_association(assoc)
        if failure is not None:
            return self._failed(frame, failure, timings, t0)
        finish = self._finish_paper if self.association == "paper" else self._finish_robust
        pose = finish(frame, assoc, timings, t2)
        if isinstance(pose, _Failure):
            return self._failed(frame, pose, timings, t0)
        failure = self._check_pose(pose, assoc.n_hypotheses)
        if failure is None:
            failure, verified = self._verify(frame, pose, assoc.n_hypotheses, timings)
            if failure is None and verified is not None:
                t3 = time.perf_counter()
                pose = self._without_outliers(frame, pose, verified)
                timings["verify"] += time.perf_counter() - t3
        if failure is None and frame.deadline is not None and frame.deadline.passed():
            # past the deadline the verification's own search may have been cut short
            reason = frame.deadline.reason("the pose was confirmed")
            failure = _Failure(FailureCode.TIMED_OUT, reason, pose.assignment, assoc.n_hypotheses)
        if failure is not None:
            return self._failed(frame, failure, timings, t0)
        timings["total"] = time.perf_counter() - t0
        q = pose.prior_mahalanobis_sq
        return PoseEstimate(
            success=True,
            cam_from_world=pose.cam_from_world,
            assignment=pose.assignment,
            reprojection_rmse_px=float(pose.rmse_px),
            n_inliers=pose.n_inliers,
            covariance=pose.covariance,
            failure_reason=None,
            timings=timings,
            prior_mahalanobis_sq=(
                prior_mahalanobis_sq(pose.cam_from_world, frame.prior, frame.prior_sigmas)
                if q is None
                else float(q)
            ),
            n_hypotheses=assoc.n_hypotheses,
            warm_started=assoc.warm_started,
        )

    # ---------------------------------------------------------------- the steps of localize

    def _frame(
        self,
        detections_uv: ArrayLike | Detections,
        prior_cam_from_world: ArrayLike,
        prior_sigmas: PriorSigmas | tuple | None,
        warm_start: ArrayLike | None,
        start: float,
    ) -> _Frame:
        """:meth:`localize`'s arguments validated, the detections undistorted to pinhole pixels.

        ``start``: the call's start on ``time.perf_counter``'s clock (the deadline's origin).
        """
        scores = None
        if isinstance(detections_uv, Detections):
            if self.use_scores and self.association == "robust" and detections_uv.scores is not None:
                scores = _check_scores(detections_uv.scores)
            detections_uv = detections_uv.uv
        det = as_points("detections_uv", detections_uv, 2)
        if not self._pinhole:  # pinhole pixels from here on
            det = undistort_points(det, self.K, self._distortion)
        prior = check_transform("prior_cam_from_world", prior_cam_from_world)
        if warm_start is not None:
            warm_start = check_transform("warm_start", warm_start)
        sigmas = self.prior_sigmas if prior_sigmas is None else self._prior_sigmas(prior_sigmas)
        return _Frame(det, prior, sigmas, scores, warm_start, Deadline.after(self.time_budget_s, start))

    def _check_detections(self, det: NDArray[np.float64]) -> _Failure | None:
        """Why these detections cannot give a pose (too few usable, on one line), else None."""
        n = det.shape[0]
        usable = np.isfinite(det).all(axis=1)
        n_usable = int(np.count_nonzero(usable))
        need = self.min_correspondences
        if n_usable < need:
            what = "no detections" if n == 0 else f"{n_usable} usable (finite) detections"
            return _Failure(FailureCode.TOO_FEW_DETECTIONS, f"too few detections: {what}, need {need}")
        edge_on = self._edge_on("detections", det if n_usable == n else det[usable])
        if edge_on is not None:
            return _Failure(FailureCode.DEGENERATE_GEOMETRY, edge_on)
        return None

    def _check_association(self, assoc: Association) -> _Failure | None:
        """Why this association cannot give a pose (it failed, too few pairs), else None."""
        if assoc.failure_reason is not None:
            return _Failure(
                assoc.failure_code or FailureCode.UNKNOWN, assoc.failure_reason, None, assoc.n_hypotheses
            )
        n_pairs = int(np.count_nonzero(assoc.assignment >= 0))
        need = self.min_correspondences
        if n_pairs < need:
            return _Failure(
                FailureCode.TOO_FEW_CORRESPONDENCES,
                f"too few correspondences: {n_pairs} assigned, need {need}",
                assoc.assignment.copy(),
                assoc.n_hypotheses,
            )
        return None

    def _finish_paper(
        self, frame: _Frame, assoc: Association, timings: dict[str, float], t_start: float
    ) -> _Pose | _Failure:
        """The paper's pose: PnP on the association's pairs (RANSAC if asked), its inliers kept.

        Records the ``pnp`` and ``covariance`` timings from ``t_start``.
        """
        det = frame.detections_uv
        a = assoc.assignment.copy()
        m = a >= 0
        res = solve_pnp(
            self.landmarks_xyz[a[m]],
            det[m],
            self.K,
            frame.prior,
            rule="paper",
            min_points=self.min_correspondences,
            pixel_sigma=self.pixel_sigma,
            ransac=self.ransac,
            ransac_threshold_px=self.ransac_threshold_px,
        )
        if not res.success:
            timings["pnp"] = time.perf_counter() - t_start
            return _Failure(
                res.failure_code or FailureCode.PNP_FAILED,
                res.failure_reason or "PnP failed",
                a,
                assoc.n_hypotheses,
            )
        a[np.flatnonzero(m)[~res.inliers]] = -1
        m = a >= 0
        t_pnp = time.perf_counter()
        timings["pnp"] = t_pnp - t_start
        cov = pose_covariance(self.K, res.cam_from_world, self.landmarks_xyz[a[m]], self.pixel_sigma)
        timings["covariance"] = time.perf_counter() - t_pnp
        return _Pose(
            res.cam_from_world, a, int(np.count_nonzero(m)), res.rmse_px, cov, _minor_spread_px(det[m])
        )

    def _finish_robust(
        self, frame: _Frame, assoc: Association, timings: dict[str, float], t_start: float
    ) -> _Pose | _Failure:
        """The robust association's pose refined on its pairs, measured in one compiled call.

        :func:`~localization.pose.finish.finish_pose`: the refinement, the depth check, the
        covariance, the edge-on spread and the distance from the prior. Records the ``pnp``
        timing from ``t_start`` (the covariance is in it: ``covariance`` is 0).
        """
        a = assoc.assignment.copy()
        done = finish_pose(
            FinishInputs(
                K=self.K,
                start_cam_from_world=assoc.cam_from_world,
                landmarks_xyz=self.landmarks_xyz,
                detections_uv=frame.detections_uv,
                assignment=a,
                pixel_sigma=self.pixel_sigma,
                prior_cam_from_world=frame.prior,
                prior_sigmas=frame.prior_sigmas,
            )
        )
        timings.update(pnp=time.perf_counter() - t_start, covariance=0.0)
        if not done.in_front:
            return _Failure(
                FailureCode.BEHIND_CAMERA,
                "refined pose puts landmarks behind the camera",
                a,
                assoc.n_hypotheses,
            )
        return _Pose(
            done.cam_from_world,
            a,
            int(np.count_nonzero(a >= 0)),
            done.rmse_px,
            done.covariance,
            done.spread_px,
            done.prior_mahalanobis_sq,
        )

    def _check_pose(self, pose: _Pose, n_hypotheses: int) -> _Failure | None:
        """Why this pose is not an answer (not finite, seen edge-on, ill-conditioned), else None."""
        a = pose.assignment
        if not np.isfinite(pose.cam_from_world).all():
            return _Failure(FailureCode.PNP_FAILED, "PnP returned a non-finite pose", a, n_hypotheses)
        edge_on = self._edge_on("inlier detections", spread=pose.spread_px)
        if edge_on is not None:
            return _Failure(FailureCode.DEGENERATE_GEOMETRY, edge_on, a, n_hypotheses)
        if self.max_position_std_m is not None:
            cov = pose.covariance
            std = float(np.sqrt(np.max(np.diag(cov)[:3]))) if np.all(np.isfinite(cov)) else np.inf
            if std > self.max_position_std_m:
                return _Failure(
                    FailureCode.ILL_CONDITIONED,
                    f"ill-conditioned geometry: position std {std:.3g} m > "
                    f"max_position_std_m={self.max_position_std_m}",
                    a,
                    n_hypotheses,
                )
        return None

    @cached_property
    def _landmark_spacing_m(self) -> float:
        """:func:`localization.verify.landmark_spacing_m` of the landmarks, computed once."""
        return landmark_spacing_m(self.landmarks_xyz)

    def _verify(
        self, frame: _Frame, pose: _Pose, n_hypotheses: int, timings: dict[str, float]
    ) -> tuple[_Failure | None, VerifyInputs | None]:
        """Why the detections do not confirm this pose (:mod:`localization.verify`), else None.

        Robust mode with ``verify`` only; records the ``verify`` timing. Returns ``(failure,
        inputs)``: the verification's inputs (None when it did not run), which hold what its
        tests computed.
        """
        timings["verify"] = 0.0
        if self.association != "robust" or not self.verify:
            return None, None
        t = time.perf_counter()
        inputs = VerifyInputs(
            detections_uv=frame.detections_uv,
            landmarks_xyz=self.landmarks_xyz,
            K=self.K,
            image_size=self.image_size,
            cam_from_world=pose.cam_from_world,
            assignment=pose.assignment,
            covariance=pose.covariance,
            prior_cam_from_world=frame.prior,
            prior_sigmas=frame.prior_sigmas,
            pixel_sigma=self.pixel_sigma,
            gate_px=self.gate_px if self.gate_px is not None else max(5.0 * self.pixel_sigma, 3.0),
            need=max(self.min_correspondences, 3),
            fit_sigma=self.fit_sigma_px,
            tolerance_m=self.tolerance_m,
            search=lambda keep: self._search(frame, keep),
            landmark_spacing_m=self._landmark_spacing_m,
        )
        refusal = verify_pose(inputs)
        timings["verify"] = time.perf_counter() - t
        if refusal is None:
            return None, inputs
        refused = pose.cam_from_world.copy()
        return _Failure(refusal.code, refusal.reason, pose.assignment, n_hypotheses, refused), inputs

    def _without_outliers(self, frame: _Frame, pose: _Pose, verified: VerifyInputs) -> _Pose:
        """The verified pose without the pairs its outlier test dropped, where it dropped any.

        The verification refits the pose without the pairs beyond the others' leave-one-out
        quantile (:func:`localization.verify.without_outliers`) and passes it only when that
        keeps the camera centre inside the pose's 99.9 % ellipsoid; the refit is then the
        better pose -- one or two detections a few pixels off their corners no longer pull it
        -- and least squares on Gaussian pixels at the declared sigma is left alone (a pair is
        dropped with probability 0.001). Reported with those detections unassigned, refined
        and measured on the rest (:func:`~localization.pose.finish.finish_pose`); the pose as
        it was if the refit puts a landmark behind the camera, has no finite covariance (the rest
        a degenerate layout: four corners of a grid on one line) or fails the checks every pose
        passes (:meth:`_check_pose`).
        """
        T, a, dropped = verified.without_outliers
        if dropped == 0:
            return pose
        done = finish_pose(
            FinishInputs(
                K=self.K,
                start_cam_from_world=T,
                landmarks_xyz=self.landmarks_xyz,
                detections_uv=frame.detections_uv,
                assignment=a,
                pixel_sigma=self.pixel_sigma,
                prior_cam_from_world=frame.prior,
                prior_sigmas=frame.prior_sigmas,
            )
        )
        refit = _Pose(done.cam_from_world, a, int(np.count_nonzero(a >= 0)), done.rmse_px, done.covariance,
                      done.spread_px, done.prior_mahalanobis_sq)
        is_pose = done.in_front and np.all(np.isfinite(done.covariance))
        return refit if is_pose and self._check_pose(refit, 0) is None else pose

    def _search(
        self, frame: _Frame, keep: NDArray[np.bool_]
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]] | None:
        """The association over the detections ``keep`` marks (the others as NaN rows, unassigned)."""
        det = np.where(keep[:, None], frame.detections_uv, np.nan)
        assoc = self.associate(det, frame.prior, frame.prior_sigmas, frame.scores, deadline=frame.deadline)
        if assoc.failure_reason is not None:
            return None
        return assoc.assignment, assoc.cam_from_world

    @staticmethod
    def _failed(
        frame: _Frame, failure: _Failure, timings: dict[str, float], t0: float
    ) -> PoseEstimate:
        """The failed estimate: the prior as the pose, the stages not reached timed at 0."""
        for stage in ("associate", "pnp", "covariance", "verify"):
            timings.setdefault(stage, 0.0)
        timings["total"] = time.perf_counter() - t0
        n = frame.detections_uv.shape[0]
        return PoseEstimate(
            success=False,
            cam_from_world=frame.prior.copy(),
            assignment=(
                np.full(n, -1, dtype=np.int64) if failure.assignment is None else failure.assignment
            ),
            failure_reason=failure.reason,
            failure_code=failure.code,
            timings=timings,
            prior_mahalanobis_sq=0.0,
            n_hypotheses=failure.n_hypotheses,
            refused_cam_from_world=failure.refused_cam_from_world,
        )


def image_size_from_K(K: ArrayLike) -> tuple[int, int]:
    """The image size ``(W, H)`` that ``K``'s principal point implies: ``(ceil(2 cx), ceil(2 cy))``.

    A principal point lies between the image centre in pixel-centre coordinates, ``(W - 1) / 2``,
    and the centre of the pixel rectangle, ``W / 2``; so ``2 cx`` lies in ``[W - 1, W]`` and the
    image is ``ceil(2 cx)`` wide. The paper's camera (``cx = 640 = W / 2``) gives 1280; the
    environment's cameras scaled from it keep its half-pixel offset (``cx = 63.55`` at 128 px)
    and give their own width, where ``round(2 cx)`` gave 127. A camera whose principal point is
    exactly ``(W - 1) / 2`` is ambiguous with width ``W - 1`` and gives that: pass ``image_size``.

    Raises:
        ValueError: if the principal point is not positive.
    """
    k = check_intrinsics("K", K)
    # The tolerance keeps an exact 2 cx (the paper's camera) from rounding up through float noise.
    w, h = (int(math.ceil(2.0 * float(c) - 1e-6)) for c in (k[0, 2], k[1, 2]))
    if w <= 0 or h <= 0:
        raise ValueError(
            f"cannot infer image_size from K's principal point ({k[0, 2]}, {k[1, 2]}); pass image_size"
        )
    return w, h


def _minor_spread_px(uv: NDArray[np.float64]) -> float:
    """RMS distance of image points from their best-fit line, px (0 for fewer than 3 points).

    The smaller singular value of the centred points over ``sqrt(N)``, from the smaller
    eigenvalue of their 2 x 2 scatter matrix in closed form, compiled
    (:func:`localization.geometry.kernels.minor_spread`): an SVD or numpy's calls would cost
    more than the arithmetic, on every frame. The closed form loses about 1e-5 px to
    cancellation on exactly collinear points, far below the 1-2 px threshold it is compared with.
    """
    return float(minor_spread(np.ascontiguousarray(uv, dtype=np.float64)))


def _check_scores(scores: NDArray[np.float64]) -> NDArray[np.float64]:
    """Detection scores read as probabilities: each in [0, 1] or NaN (ValueError otherwise)."""
    if np.any((scores < 0.0) | (scores > 1.0)):  # NaN compares False: allowed
        raise ValueError(
            "Detections.scores must be probabilities in [0, 1] (the robust association reads them "
            f"as the odds that each detection is a landmark), got values in [{np.nanmin(scores):g}, "
            f"{np.nanmax(scores):g}]; pass use_scores=False to the Localizer to ignore them"
        )
    return scores
