"""A minimal fit held to the building's structure it predicts in the image.

A pose on four pairs (the minimum; its fit test keeps two degrees of freedom) hides one corner a
few pixels off, or two wrong pairs that fit, in what its residuals leave: no test on the pairs
alone tells such a pose 1-9 m off from a right one (:mod:`localization.verify`). The building
model tells them apart. At the pose, every structural landmark of the stage the model shows
(slab and opening corners, column tops: not only the set's) is rendered with its neighbourhood
(:class:`uav_struct_env.sim.templates.SiteTemplates`) and matched in the image around its
predicted projection (:class:`localization.detect.guided.TemplateMatcher`, searching
:attr:`PoseConfirmation.search_px`, wider than the guided detector's few pixels). Each match
carries its landmark's identity, so the matches give a pose of their own, the *structure's pose*
(RANSAC over the matches, then refined on those within :attr:`PoseConfirmation.gate_px`).
:class:`PoseConfirmation` refuses the localizer's pose as
:attr:`~localization.failure.FailureCode.UNCONFIRMED` when

* **a nearby pose explains the image better**: the structure's pose, on at least
  :attr:`~PoseConfirmation.min_agree` matches and on :attr:`~PoseConfirmation.min_gain` more of
  them than the pose itself explains (a RANSAC pose that explains one more match is no evidence),
  lies farther from it than its tolerance, ``max(tolerance_m, 3 x the Cramer-Rao bound of the
  set's landmarks it predicts in the image)`` at the detector's noise (issue 44's line between
  a right pose and a confident wrong one); or
* **the image does not show its structure**: the matches give no structure's pose, and fewer
  than :attr:`~PoseConfirmation.min_seen` of them lie within ``gate_px`` of where the pose
  predicts them (a pose that rests on false detections predicts structure where the image has
  none).

A structure's pose within the tolerance confirms the pose, however few matches lie within
``gate_px`` of its own predictions (a detector that places its corners a pixel or two off the
model's, as on buildings unlike its training data, leaves a right pose a few decimetres off).

Fits on more pairs than :attr:`~PoseConfirmation.max_pairs` are reported as the localizer gives
them (their spare pairs carry the evidence, which the verification weighs). Nothing here moves a
pose: it is confirmed or refused. The stack holds the final pose of every structural detector
that reads the image to it (:func:`uav_struct_env.stack.build_stack` with a site), not the
simulated projection detector's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization import PoseEstimate
from localization.detect.guided import TemplateMatcher
from localization.failure import FailureCode
from localization.geometry.distortion import is_pinhole, undistort_points
from localization.geometry.transforms import camera_center, project
from localization.pose.pnp import refine_pose, solve_pnp
from localization.verify import position_tolerance

__all__ = ["Confirmation", "PoseConfirmation", "confirmation_for"]


@dataclass(frozen=True)
class Confirmation:
    """What the structure says of one pose (:meth:`PoseConfirmation.assess`).

    Attributes:
        n_matched: landmarks of the stage matched in the image around their projections.
        n_agree: matches within ``gate_px`` of the structure's own pose (0 without one).
        n_here: matches within ``gate_px`` of the pose's own predictions.
        shift_m: distance from the pose's camera centre to the structure's pose's, m (NaN
            without one).
        tolerance_m: the pose's tolerance, m (``max(tolerance_m, 3 x bound)``).
        confirmed: False when the pose is refused.
        reason: why it is refused, for people (None when confirmed).
    """

    n_matched: int
    n_agree: int
    n_here: int
    shift_m: float
    tolerance_m: float
    confirmed: bool
    reason: str | None = None


@dataclass(frozen=True, eq=False)
class _Matched:
    """The templates matched at a pose: landmark points, undistorted pixels, and how many agree."""

    xyz: NDArray[np.float64]
    uv: NDArray[np.float64]
    here: int


class PoseConfirmation:
    """Holds minimal fits to the structure the building model predicts (module docstring).

    Args:
        matcher: a :class:`~localization.detect.guided.TemplateMatcher` over every structural
            landmark of the stage.
        set_xyz: (M, 3) the landmark set's model points (the localizer's): their bound sets the
            tolerance.
        K: (3, 3) intrinsics of the frames.
        distortion: the frames' distortion coefficients, or None for a pinhole.
        pixel_sigma_px: the detector's pixel noise, px, at which the tolerance's bound is taken.
        tolerance_m: the position error a pose must be confirmed within, m (or three times its
            bound when larger).
        max_pairs: fits on at most this many pairs are held to the structure.
        search_px: half-size of the template search around each predicted landmark, px.
        gate_px: a match agrees with a pose within this distance, px.
        min_agree: the fewest agreeing matches that give the structure's pose.
        min_seen: the fewest matches within ``gate_px`` of the pose's predictions that let it stand.
        min_gain: how many more matches the structure's pose must explain than the pose itself.
    """

    def __init__(self, matcher: TemplateMatcher, set_xyz: Any, K: Any, distortion: Any = None, *,
                 pixel_sigma_px: float = 1.0, tolerance_m: float = 1.0, max_pairs: int = 4,
                 search_px: int = 12, gate_px: float = 2.5, min_agree: int = 6, min_seen: int = 2,
                 min_gain: int = 2) -> None:
        self.matcher = matcher
        self.set_xyz = np.asarray(set_xyz, dtype=np.float64).reshape(-1, 3)
        self.K = np.asarray(K, dtype=np.float64)
        self.distortion = None if is_pinhole(distortion) else np.asarray(distortion, dtype=np.float64)
        self.pixel_sigma_px = float(pixel_sigma_px)
        self.tolerance_m = float(tolerance_m)
        self.max_pairs = int(max_pairs)
        self.search_px = int(search_px)
        self.gate_px = float(gate_px)
        self.min_agree = int(min_agree)
        self.min_seen = int(min_seen)
        self.min_gain = int(min_gain)

    def confirmed(self, image: Any, est: PoseEstimate, prior_cam_from_world: NDArray[np.float64]
                  ) -> PoseEstimate:
        """``est``, or a failure (``UNCONFIRMED``, the prior as its pose) when the structure refuses it.

        Only successes on at most ``max_pairs`` pairs are assessed; the others are returned as given.
        """
        if not est.success or est.n_inliers > self.max_pairs:
            return est
        verdict = self.assess(image, est.cam_from_world)
        if verdict.confirmed:
            return est
        return replace(est, success=False, cam_from_world=np.array(prior_cam_from_world, dtype=np.float64),
                       failure_code=FailureCode.UNCONFIRMED, failure_reason=verdict.reason, n_inliers=0,
                       reprojection_rmse_px=float("inf"), covariance=np.full((6, 6), np.inf),
                       prior_mahalanobis_sq=0.0)

    def tolerance(self, cam_from_world: NDArray[np.float64], image_size: tuple[int, int]) -> float:
        """``max(tolerance_m, 3 x bound)``, m, with the bound of the set's landmarks the pose shows.

        The verification's tolerance (:func:`localization.verify.position_tolerance`): infinite
        (nothing refused for its shift) with fewer than three of them.
        """
        return position_tolerance(self.K, cam_from_world, self.set_xyz, image_size, self.pixel_sigma_px,
                                  self.tolerance_m)[0]

    def _matched(self, image: NDArray[np.uint8], cam_from_world: NDArray[np.float64]) -> _Matched:
        """The stage's landmarks matched around their projections at ``cam_from_world``."""
        found = self.matcher.find(image, cam_from_world, self.K, self.distortion, search_px=self.search_px)
        uv = found.uv
        if self.distortion is not None and len(uv):
            uv = undistort_points(uv, self.K, self.distortion)
        X = self.matcher.xyz[found.index]
        here = int(self._agree(cam_from_world, X, uv).sum()) if len(uv) else 0
        return _Matched(X, uv, here)

    def _agree(self, cam_from_world: NDArray[np.float64], X: NDArray[np.float64],
               uv: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(N,) the matches ``uv`` of ``X`` within ``gate_px`` of where ``cam_from_world`` projects them."""
        return np.hypot(*(project(self.K, cam_from_world, X)[0] - uv).T) <= self.gate_px

    def structure_pose(self, matched: _Matched, cam_from_world: NDArray[np.float64]
                       ) -> tuple[NDArray[np.float64] | None, int]:
        """``(pose, agree)``: the matches' own pose, from ``cam_from_world``; ``(None, 0)`` without one.

        RANSAC over the matches, then three rounds of refinement on those within ``gate_px``; no
        pose when fewer than ``min_agree`` agree.
        """
        X, uv = matched.xyz, matched.uv
        if len(X) < self.min_agree:
            return None, 0
        fit = solve_pnp(X, uv, self.K, cam_from_world, rule="prior", ransac=True,
                        ransac_threshold_px=self.gate_px, min_points=self.min_agree)
        if not fit.success:
            return None, 0
        T = fit.cam_from_world
        for _ in range(3):
            agree = self._agree(T, X, uv)
            if agree.sum() < self.min_agree:
                return None, 0
            T, _ = refine_pose(X[agree], uv[agree], self.K, T)
        n = int(self._agree(T, X, uv).sum())
        return (T, n) if n >= self.min_agree else (None, 0)

    def assess(self, image: Any, cam_from_world: NDArray[np.float64]) -> Confirmation:
        """What the structure matched at ``cam_from_world`` says of it (module docstring)."""
        img = np.asarray(image)
        tol = self.tolerance(cam_from_world, (img.shape[1], img.shape[0]))
        matched = self._matched(img, cam_from_world)
        n, here = len(matched.uv), matched.here
        T, agree = self.structure_pose(matched, cam_from_world)
        if T is None:
            if here >= self.min_seen:
                return Confirmation(n, 0, here, float("nan"), tol, True)
            reason = (f"{here} of the {n} structural landmarks matched within "
                      f"{self.search_px} px of its predictions lie within {self.gate_px:g} px of them "
                      f"(at least {self.min_seen} needed): the image does not show the structure it predicts")
            return Confirmation(n, 0, here, float("nan"), tol, False, reason)
        shift = float(np.linalg.norm(camera_center(T) - camera_center(cam_from_world)))
        if shift <= tol or agree < here + self.min_gain:
            return Confirmation(n, agree, here, shift, tol, True)
        reason = (f"{agree} of the {n} structural landmarks matched around its "
                  f"predictions fit a pose {shift:.2f} m away, which it explains only {here} of, beyond "
                  f"its tolerance {tol:.2f} m: a nearby pose explains the image better")
        return Confirmation(n, agree, here, shift, tol, False, reason)


def confirmation_for(templates: Any, stage_xyz: Any, localizer: Any, default_tolerance_m: float
                     ) -> PoseConfirmation:
    """The :class:`PoseConfirmation` of a stack's ``localizer`` (:class:`localization.Localizer`).

    Args:
        templates: the building model's renderer (:class:`uav_struct_env.sim.templates.SiteTemplates`).
        stage_xyz: (L, 3) every structural landmark of the stage (``site.landmarks("all").xyz``).
        localizer: the set's localizer: its model points, intrinsics, distortion, the detector's
            noise (``fit_sigma_px``, else ``pixel_sigma``), ``tolerance_m`` and
            ``min_correspondences`` (the fits held to the structure are those on that many pairs).
        default_tolerance_m: the tolerance when the localizer has none, m.
    """
    sigma = localizer.fit_sigma_px if localizer.fit_sigma_px is not None else localizer.pixel_sigma
    tol = localizer.tolerance_m if localizer.tolerance_m is not None else default_tolerance_m
    return PoseConfirmation(TemplateMatcher(stage_xyz, templates), localizer.landmarks_xyz, localizer.K,
                            localizer.distortion, pixel_sigma_px=sigma, tolerance_m=tol,
                            max_pairs=max(int(localizer.min_correspondences), 4))
