"""Stage 4, verification: a finished pose checked against what it predicts the image shows.

A pose makes predictions: the landmarks it projects inside the image must be there, each within
the inlier gate of a detection. :func:`verify_pose` holds a finished pose
(:mod:`localization.pose.finish`) to them before :meth:`localization.Localizer.localize` reports
it, and turns it into a failure with a reason when the detections cannot confirm it:

* *Support beyond chance* (:func:`chance_support`). With ``D`` detections over an image of area
  ``A``, a landmark's projection has a detection within the gate ``g`` by chance with
  probability ``p = 1 - exp(-D pi g^2 / A)``. A pose that matches ``k`` of the ``n`` landmarks
  it predicts is a coincidence when such a match is expected among the poses a search could
  have tried: the two-point hypotheses (:mod:`localization.associate.upright`) number about
  ``n (n - 1) D (D - 1)``, and each explains its two anchors by construction, so the number of
  false alarms is ``NFA = n (n - 1) D (D - 1) P(Binomial(n - 2, p) >= k - 2)`` (an a-contrario
  test, Desolneux, Moisan and Morel 2008). ``NFA > 1`` fails as
  :attr:`~localization.failure.FailureCode.UNSUPPORTED`: dense clutter matches any pose's
  predictions, and only a match far above what the clutter's density gives is evidence. Clean
  detections (``D`` about the landmarks in view) make ``p`` tiny and the test silent.
* *A minimal fit that fits loosely* (:func:`minimal_fit_chi2_limit`). A pose on as many pairs
  as the minimum (four) leaves its fit test two degrees of freedom, and any four detections
  near the prior fit some pose to a few pixels: among the wrong detections of a detector that
  finds few corners, the search finds such a four and its residuals pass the association's
  one-in-a-million test. A minimal fit must fit as well as 95 % of true ones do (the
  chi-square 95 % quantile at ``pixel_sigma``); else it fails as ``UNSUPPORTED`` -- unless,
  with a tolerance (``tolerance_m``), it is loose only at a detector's tighter declared sigma
  and no one pair moves it farther than :data:`MINIMAL_FIT_LEVERAGE` of the tolerance
  (:func:`leave_one_out_shifts`): then a corner a few px off, what makes a right fit loose,
  cannot have carried it far.
* *A twin hypothesis* (:func:`twin_hypotheses`). A detector that fires twice per corner (on both
  edges of a slab's thickness, on a corner and its shadow) gives a second copy of the pattern a
  few to 80 px away. The search pairs one copy; the other, left unassigned, is as consistent a
  pose. The unassigned detections that sit at one common offset from the pairs (a vote over
  the offsets up to :data:`TWIN_RADIUS_PX`, ranked by the pairs that agree; a winner may hold
  some copies of each side) give the twins: the same landmarks paired with those detections,
  refined from the winner's pose; with a few pairs, where a mix of the copies still fits,
  every choice of pairs moved to one of their nearest unassigned detections is a twin too
  (:func:`twin_hypotheses`). A twin that passes
  the fit test, lies at a distinct camera centre (outside the winner's 99.9 % position
  ellipsoid, the ambiguity rule's test; a twin that is the winner's camera turned, at the same
  centre, leaves the position right) and scores within
  the ambiguity margin of the winner -- or better -- fails as
  :attr:`~localization.failure.FailureCode.DUPLICATED_DETECTIONS`: which copy is the structure
  only the prior could say, and the prior is metres off. Both hypotheses are scored as the
  association scores them: squared residuals, a clutter cost per unassigned detection, a miss
  cost per predicted landmark left unmatched, the prior's Mahalanobis distance.

* *Pairs the others reject* (:func:`leave_one_out_chi2`). A detector that fires a few px off a
  corner (on the far edge of a slab, on a hidden corner's neighbour) gives a fit of five to
  seven pairs with one to three wrong, loose (1-2.5 px RMS) but within the association's fit
  test at ``pixel_sigma``. Each pair's residual against the pose the other pairs give is a
  2-dof chi-square for a right pair; the worst beyond :data:`OUTLIER_QUANTILE` is dropped and
  the pose refitted, while more than ``need`` pairs remain (:func:`without_outliers`), and the
  pose fails as ``UNSUPPORTED`` when the refitted camera centre leaves the winner's position
  ellipsoid. When it stays inside and every other test passes, the localizer reports the refit
  where it is a pose at all (a finite covariance: :meth:`localization.Localizer.localize`): the
  stray pairs no longer pull it. The residuals are scaled by the detector's own calibrated noise
  when it declares one (``fit_sigma``, :data:`localization.detect.learned.FIT_PIXEL_SIGMA_PX`),
  which the minimal-fit test uses too.
* *A period of the layout* (:func:`lattice_rivals`). On a regular grid the same detections
  pair as well with the landmarks one period over, seen from a camera moved by the period: the
  residuals are identical and only the prior (and the landmarks each predicts) tell them
  apart. A rival within the ambiguity margin fails as
  :attr:`~localization.failure.FailureCode.AMBIGUOUS`.
* *Rivals grown whole* (:func:`reassociated`, :func:`offset_starts`). A twin or a lattice rival
  pairs only the winner's landmarks, moved; where the winner explains a patch of a ghost copy
  (a copy shifted as a whole fits no pose exactly) or the layout one period over (its edge
  landmarks have no counterpart), the structure's own pose pairs many more. Each rival is
  refined and re-associated at the final gate as the association refines its hypotheses, and
  scored as a hypothesis of its own; so are starts from the winner's predictions moved by the
  common image offsets voted between them and the detections, and from the translations that
  carry at least half of the winner's pairs onto other landmarks (a period of most of the
  layout, or of an irregular one: :func:`lattice_rivals` with ``share``; such a period is
  scored at its refined pose even when the re-association keeps its pairs: one that pairs
  exactly the structure's detections is whole already). One that scores within the ambiguity
  margin of the winner, or better, fails the pose as the twin or rival would.
* *A second search* (:func:`rival_search`, with ``search``). A winner that pairs a patch of
  the detections (a few of each ghost copy, each with the wrong landmark) lies no image offset
  or period from the structure's pose. When it leaves at least as many detections unassigned
  as it pairs, the association runs again over those alone; its hypothesis, re-associated over
  every detection, scoring within the ambiguity margin, or better, fails the pose as
  :attr:`~localization.failure.FailureCode.AMBIGUOUS`.
* *One pair moves it too far* (:func:`leave_one_out_shifts`, with ``tolerance_m``). A pose on
  five to seven pairs with one detection a few px off its corner passes every residual test,
  yet the pose without that pair lies metres away (the linearized refit of regression
  diagnostics, Cook 1977). With a tolerance (:data:`CONFIRM_TOLERANCE_M`, which the study passes
  with the learned detector) a pose that leaving out any one pair moves farther than
  ``max(tolerance_m, 3 x the Cramer-Rao bound of the landmarks it predicts in the image)`` at the
  detector's noise fails as :attr:`~localization.failure.FailureCode.ILL_CONDITIONED`: the
  detections cannot confirm it within the tolerance.
* *A pattern of small biases moves it too far* (:func:`protection_level`, with ``tolerance_m``).
  Seen from far (a long building's row of openings from 60-110 m), a pose on twenty or thirty
  pairs, every identity right and no pair an outlier, can still be metres off: a spatial pattern
  of sub-pixel to few-pixel detection errors over a narrow spread of corners, which no residual
  or leave-one-out test sees. Its protection level (as GNSS integrity monitoring computes one)
  is how far a bias of at most :data:`BIAS_SHARE` of the detector's noise on every detection, in
  the worst pattern, could move the camera centre; beyond the tolerance the pose fails as
  ``ILL_CONDITIONED``.

:class:`VerifyInputs` carries the frame and the pose; :func:`verify_pose` returns None for a
confirmed pose, else a :class:`Refusal`.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from localization.associate.ambiguity import AMBIGUITY_MARGIN
from localization.associate.assign_kernels import assign_rounds, refine_reassign
from localization.associate.hypothesis_kernels import check_many, missed_many
from localization.failure import FailureCode
from localization.geometry.kernels import center, kernel_array
from localization.geometry.transforms import project
from localization.pose.batch import refine_many, to_transforms
from localization.pose.covariance import (
    PriorSigmas,
    pose_covariance,
    pose_difference,
    pose_jacobian,
    prior_mahalanobis_sq,
)
from localization.stats import binomial_log_sf, chi2_quantile
from localization.verify_kernels import (
    lattice_hits,
    leave_one_out,
    offset_votes,
    predictions,
)

__all__ = [
    "BIAS_SHARE",
    "CONFIRM_TOLERANCE_M",
    "DISTINCT_POSITION_SQ",
    "LATTICE_SHARE",
    "LATTICE_SPACING_SHARE",
    "LATTICE_TOL_M",
    "MAX_LOG10_NFA",
    "MINIMAL_FIT_LEVERAGE",
    "MINIMAL_FIT_QUANTILE",
    "OUTLIER_QUANTILE",
    "TWIN_RADIUS_PX",
    "Refusal",
    "VerifyInputs",
    "chance_support",
    "landmark_spacing_m",
    "lattice_rivals",
    "leave_one_out_chi2",
    "leave_one_out_shifts",
    "minimal_fit_chi2_limit",
    "offset_starts",
    "position_tolerance",
    "predicted_in_image",
    "protection_level",
    "reassociated",
    "rival_search",
    "twin_hypotheses",
    "verify_pose",
    "without_outliers",
]


#: A pose whose support has more false alarms than this (log10 NFA) is refused: 0 means one
#: coincidence expected among the poses a search could try.
MAX_LOG10_NFA = 0.0


#: The position error, m, issue 44 calls a wrong pose below three times the view's bound; a caller
#: that holds poses to it passes it as ``tolerance_m`` (the study does).
CONFIRM_TOLERANCE_M = 1.0


#: The farthest a ghost copy of a detection lies from it, px.
TWIN_RADIUS_PX = 80.0


#: Up to this many pairs, every subset of them moved to their nearest unassigned detection is a
#: twin: four to six pairs leave the fit test two to six degrees of freedom, and a mix of the two
#: copies still fits a pose; more pairs than this, only a mix by one common offset is tried.
_ENUMERATE_PAIRS = 6


#: Most choices of moved pairs enumerated per pose (:func:`_enumerated_swaps`).
_ENUMERATE_CHOICES = 256


#: chi-square 99.9 % quantile, 3 dof: a twin whose camera centre is farther than this from the
#: winner's (squared Mahalanobis distance under the winner's position covariance) is a different
#: pose (:mod:`localization.associate.ambiguity`'s rule).
DISTINCT_POSITION_SQ = 16.27


#: Chi-square quantile a minimal fit's residuals must stay within.
MINIMAL_FIT_QUANTILE = 0.95


#: A minimal fit loose only at the detector's declared sigma stands when no pair moves it farther
#: than this share of the tolerance (``tolerance_m``; below what the loose wrong fits of the train
#: data reach, docs/benchmarks.md).
MINIMAL_FIT_LEVERAGE = 0.4


#: The bias a detector may put on every detection at once, as a share of its fit sigma
#: (:func:`protection_level`): 0.6 refuses every confident wrong pose of the train studies and
#: the synthetic repeating building but one four-pair fit, and no right pose of the paper and
#: random sites (docs/benchmarks.md, session 7).
BIAS_SHARE = 0.6


#: Chi-square quantile (2 dof) a pair's leave-one-out residual must stay within
#: (:func:`leave_one_out_chi2`); a pair beyond it is one the other pairs reject.
OUTLIER_QUANTILE = 0.999


#: A translation of the layout maps a landmark onto another when they lie this close, m.
LATTICE_TOL_M = 0.02


#: A translation of the layout that carries at least this share of the winner's pairs onto other
#: landmarks gives a rival start (:func:`lattice_rivals`, ``share``).
LATTICE_SHARE = 0.5


#: ... within this share of the layout's spacing (the median nearest-landmark distance).
LATTICE_SPACING_SHARE = 0.25


#: Pairs whose landmark anchors the candidate translations of a partial period.
_LATTICE_ANCHORS = 3


#: Chi-square quantile of the twin's fit test (the association's own).
_FIT_QUANTILE = 1.0 - 1e-6


#: Rounds of refinement and re-association that grow a rival (:func:`reassociated`).
_REASSOCIATE_ROUNDS = 6


#: Vote cells whose offsets are counted again by the pairs that agree (:func:`_offset_votes`).
_VOTE_CELLS = 12


#: Common image offsets of the winner's predictions tried as starts (:func:`offset_starts`).
_OFFSET_STARTS = 3


@dataclass(frozen=True, eq=False)
class VerifyInputs:
    """A finished pose and the frame it was found in.

    Attributes:
        detections_uv: (N, 2) the detections, pinhole pixels (NaN rows ignored).
        landmarks_xyz: (M, 3) the model landmarks, project frame, metres.
        K: (3, 3) intrinsics.
        image_size: (W, H) px.
        cam_from_world: (4, 4) the pose to verify.
        assignment: (N,) its landmark per detection, -1 for none.
        covariance: (6, 6) its covariance in ``(C [m], dtheta [rad])``.
        prior_cam_from_world: (4, 4) the frame's prior.
        prior_sigmas: the prior's uncertainty.
        pixel_sigma: detector noise, px (the association's model: its gates and fit test).
        gate_px: the inlier gate, px.
        need: the fewest pairs a pose may rest on.
        miss_cost: cost of a predicted landmark left unmatched (the association's).
        fit_sigma: the detector's own calibrated noise, px, that the minimal-fit and
            leave-one-out tests hold the pairs to (a detector that declares one, e.g.
            :data:`localization.detect.learned.FIT_PIXEL_SIGMA_PX`); None: ``pixel_sigma``.
        tolerance_m: the position error a reported pose must be kept within, m, unless the
            landmarks it predicts cannot locate it that well (then three times their bound): no
            single pair may move it farther (:func:`leave_one_out_shifts`); None: no such test.
        search: the association run again on a subset of the detections: called with an (N,)
            mask of the detections it may use, it returns ``(assignment (N,), cam_from_world)``
            of its best hypothesis, or None when it finds none (:func:`rival_search`); None:
            no second search.
        landmark_spacing_m: :func:`landmark_spacing_m` of ``landmarks_xyz``, when the caller
            keeps it (the :class:`~localization.Localizer` does); None: computed here.
    """

    detections_uv: NDArray[np.float64]
    landmarks_xyz: NDArray[np.float64]
    K: NDArray[np.float64]
    image_size: tuple[int, int]
    cam_from_world: NDArray[np.float64]
    assignment: NDArray[np.int64]
    covariance: NDArray[np.float64]
    prior_cam_from_world: NDArray[np.float64]
    prior_sigmas: PriorSigmas
    pixel_sigma: float
    gate_px: float
    need: int
    miss_cost: float = 4.0
    fit_sigma: float | None = None
    tolerance_m: float | None = None
    search: Callable[[NDArray[np.bool_]], tuple[NDArray[np.int64], NDArray[np.float64]] | None] | None = None
    landmark_spacing_m: float | None = None

    @property
    def fit_sigma_px(self) -> float:
        """The noise the fit tests assume, px: ``fit_sigma``, else ``pixel_sigma``."""
        return self.pixel_sigma if self.fit_sigma is None else self.fit_sigma

    @property
    def spacing_m(self) -> float:
        """``landmark_spacing_m``, else :func:`landmark_spacing_m` of the landmarks."""
        if self.landmark_spacing_m is not None:
            return self.landmark_spacing_m
        return landmark_spacing_m(self.landmarks_xyz)

    @cached_property
    def tolerance(self) -> tuple[float, float, int]:
        """:func:`position_tolerance` of the pose at the detector's noise: ``(tolerance, bound, seen)``.

        Made once per pose for the tests that hold the pose to it (``tolerance_m`` given).
        """
        return position_tolerance(self.K, self.cam_from_world, self.landmarks_xyz, self.image_size,
                                  self.fit_sigma_px, self.tolerance_m or 0.0)

    @cached_property
    def without_outliers(self) -> tuple[NDArray[np.float64], NDArray[np.int64], int]:
        """:func:`without_outliers` of this pose, made once (the outlier test and the localizer read it)."""
        return without_outliers(self)

    @cached_property
    def worst_leverage_m(self) -> float:
        """The farthest one pair moves the camera centre when left out, m (:func:`leave_one_out_shifts`)."""
        rows = np.flatnonzero(self.assignment >= 0)
        X = self.landmarks_xyz[self.assignment[rows]]
        return float(leave_one_out_shifts(self.K, self.cam_from_world, X, self.detections_uv[rows]).max())

    @cached_property
    def winner_score(self) -> float:
        """The pose's own score, as its rivals are scored (:func:`_scores`)."""
        return float(_scores(self, [(self.assignment, self.cam_from_world)])[0])

    @cached_property
    def arrays(self) -> _FrameArrays:
        """The frame's arrays as the compiled kernels take them, made once per pose."""
        det = kernel_array(self.detections_uv, dtype=np.float64)
        P = np.asarray(self.prior_cam_from_world, dtype=np.float64)
        uv, predicted = _predictions(self.K, self.cam_from_world, self.landmarks_xyz, self.image_size)
        return _FrameArrays(
            K=kernel_array(self.K, dtype=np.float64),
            landmarks_xyz=kernel_array(self.landmarks_xyz, dtype=np.float64),
            detections_uv=det,
            good=np.flatnonzero(np.isfinite(det).all(axis=1)).astype(np.int64),
            prior_R=kernel_array(P[:3, :3]),
            prior_C=center(P),
            prior_sigmas=self.prior_sigmas.as_array(),
            centre=center(np.asarray(self.cam_from_world, dtype=np.float64)),
            winner_uv=uv,
            predicted=predicted,
        )


@dataclass(frozen=True, eq=False)
class _FrameArrays:
    """:attr:`VerifyInputs.arrays`, made once per pose.

    Contiguous float64 copies for the kernels; ``good`` the finite detections; the prior's
    rotation, camera centre and sigmas (6,); the winner's camera centre, its projections of every
    landmark and which it predicts in the image (:func:`predicted_in_image`).
    """

    K: NDArray[np.float64]
    landmarks_xyz: NDArray[np.float64]
    detections_uv: NDArray[np.float64]
    good: NDArray[np.int64]
    prior_R: NDArray[np.float64]
    prior_C: NDArray[np.float64]
    prior_sigmas: NDArray[np.float64]
    centre: NDArray[np.float64]
    winner_uv: NDArray[np.float64]
    predicted: NDArray[np.bool_]


@dataclass(frozen=True)
class Refusal:
    """Why a finished pose is not reported: the code for grouping, the reason for people."""

    code: FailureCode
    reason: str


def predicted_in_image(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    image_size: tuple[int, int],
) -> NDArray[np.bool_]:
    """(M,) the landmarks in front of the camera whose projection falls inside the image."""
    return _predictions(K, cam_from_world, landmarks_xyz, image_size)[1]


def _predictions(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    image_size: tuple[int, int],
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """:func:`localization.verify_kernels.predictions` (compiled): ``(uv (M, 2), predicted (M,))``."""
    T = np.asarray(cam_from_world, dtype=np.float64)
    w, h = image_size
    return predictions(kernel_array(K, dtype=np.float64), kernel_array(T[:3, :3]),
                       kernel_array(T[:3, 3]),
                       kernel_array(landmarks_xyz, dtype=np.float64).reshape(-1, 3), int(w), int(h))


def chance_support(
    n_predicted: int, n_matched: int, n_detections: int, image_size: tuple[int, int], gate_px: float
) -> float:
    """log10 of the number of false alarms of a pose matching ``n_matched`` of ``n_predicted``.

    The module docstring's ``NFA``; ``n_detections`` the finite detections spread over the
    image, ``gate_px`` the distance within which a detection matches a projection.
    """
    w, h = image_size
    density = n_detections / float(w * h)
    p = -math.expm1(-density * math.pi * gate_px**2)
    n, k = max(n_predicted, n_matched), n_matched
    tests = math.log10(max(n * (n - 1), 1)) + math.log10(max(n_detections * (n_detections - 1), 1))
    if k <= 2:
        return tests
    return tests + binomial_log_sf(k - 3, n - 2, p) / math.log(10.0)


def minimal_fit_chi2_limit(n_pairs: int, need: int) -> float:
    """The chi-square (residuals over ``pixel_sigma^2``) a pose on ``n_pairs`` may reach.

    ``MINIMAL_FIT_QUANTILE`` of ``2 n - 6`` degrees of freedom for a minimal fit
    (``n_pairs <= need``), inf for more pairs (the association's own test holds them).
    """
    if n_pairs > need:
        return float("inf")
    return chi2_quantile(MINIMAL_FIT_QUANTILE, max(2 * n_pairs - 6, 1))


def _minimal_fit_refusal(inputs: VerifyInputs, k: int) -> Refusal | None:
    """The refusal of a minimal fit beyond its quantile, unless no one pair can have moved it far.

    With a tolerance (``tolerance_m``), a fit loose at the detector's calibrated sigma but within
    the quantile at the association's ``pixel_sigma``, whose pairs each move the camera centre
    at most :data:`MINIMAL_FIT_LEVERAGE` of the tolerance when left out
    (:attr:`VerifyInputs.worst_leverage_m`), stands: a detection a few px off its corner, what
    makes a right fit loose (a blurred or rolling-shutter corner), cannot have carried it that
    far. A fit loose at ``pixel_sigma`` too may rest on two wrong pairs, whose leverage one at a
    time says nothing.
    """
    limit = minimal_fit_chi2_limit(k, inputs.need)
    if not np.isfinite(limit):
        return None
    m = inputs.assignment >= 0
    uv, _ = project(inputs.K, inputs.cam_from_world, inputs.landmarks_xyz[inputs.assignment[m]])
    sigma = inputs.fit_sigma_px
    chi = float(np.sum((uv - inputs.detections_uv[m]) ** 2)) / sigma**2
    if chi <= limit:
        return None
    if inputs.tolerance_m is not None and chi * (sigma / inputs.pixel_sigma) ** 2 <= limit:
        if inputs.worst_leverage_m <= MINIMAL_FIT_LEVERAGE * inputs.tolerance[0]:
            return None
    return Refusal(
        FailureCode.UNSUPPORTED,
        f"unsupported pose: a minimal fit ({k} pairs) with residual chi-square {chi:.1f} above the "
        f"{MINIMAL_FIT_QUANTILE:g} quantile {limit:.1f} (pixel sigma {sigma:g} px): "
        "some four wrong detections fit as loosely by chance",
    )


def leave_one_out_chi2(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    detections_uv: NDArray[np.float64], pixel_sigma: float,
) -> NDArray[np.float64]:
    """(P,) each pair's residual against the pose the other pairs give, as a 2-dof chi-square.

    Linearized at the pose (``J`` the (2P, 6) projection Jacobian, ``H = J (J^T J)^+ J^T``): the
    leave-one-out residual of pair ``i`` is ``(I - H_ii)^-1 e_i`` with covariance
    ``sigma^2 (I - H_ii)^-1``, so ``e_i^T (I - H_ii)^-1 e_i / sigma^2`` is chi-square with two
    degrees of freedom for a right pair under Gaussian pixel noise (the externally studentized
    residual of regression diagnostics, Cook and Weisberg 1982). A wrong pair among a few right
    ones hides in the fit's RMS but not here. Inf for a pair the others cannot predict.
    """
    return _leave_one_out(K, cam_from_world, landmarks_xyz, detections_uv)[0] / pixel_sigma**2


def leave_one_out_shifts(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    detections_uv: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(P,) how far the camera centre moves, m, when each pair is left out of the fit.

    Linearized at the pose as :func:`leave_one_out_chi2`: leaving pair ``i`` out moves the pose
    by ``(J^T J)^-1 J_i^T (I - H_ii)^-1 e_i`` (the parameter change of regression diagnostics
    behind Cook's distance); its first three entries are the centre's move. Inf for a pair the
    others cannot predict.
    """
    return _leave_one_out(K, cam_from_world, landmarks_xyz, detections_uv)[1]


def _leave_one_out(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    detections_uv: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(q px^2, shift m)`` of :func:`localization.verify_kernels.leave_one_out` (compiled)."""
    T = np.asarray(cam_from_world, dtype=np.float64)
    q, shift, _ = leave_one_out(
        kernel_array(K, dtype=np.float64), kernel_array(T[:3, :3]), center(T),
        kernel_array(landmarks_xyz, dtype=np.float64).reshape(-1, 3),
        kernel_array(detections_uv, dtype=np.float64).reshape(-1, 2),
    )
    return q, shift


def position_tolerance(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    image_size: tuple[int, int], pixel_sigma: float, tolerance_m: float,
) -> tuple[float, float, int]:
    """``(tolerance, bound, seen)``: how far a pose may be from the truth and still be right, m.

    ``tolerance`` is ``max(tolerance_m, 3 x bound)`` (issue 44's line between a right pose and a
    confident wrong one), ``bound`` the RMS position std (Cramer-Rao, m; inf below three points or
    for a degenerate layout) at ``pixel_sigma`` of the ``seen`` landmarks the pose predicts in the
    image (:func:`predicted_in_image`).
    """
    seen = predicted_in_image(K, cam_from_world, landmarks_xyz, image_size)
    cov = pose_covariance(K, cam_from_world, landmarks_xyz[seen], pixel_sigma)
    bound = float(np.sqrt(np.trace(cov[:3, :3]))) if np.all(np.isfinite(cov)) else float("inf")
    return max(float(tolerance_m), 3.0 * bound), bound, int(seen.sum())


def _influence_refusal(inputs: VerifyInputs) -> Refusal | None:
    """The refusal when one pair alone moves the pose beyond the tolerance, else None.

    The tolerance is ``max(tolerance_m, 3 x the bound of the landmarks the pose predicts in the
    image)`` (:func:`position_tolerance` at the detector's noise). A pose on few pairs with one
    detection a few px off its corner (on a slab's far edge, beside a hidden corner) fits within
    every residual test -- a minimal fit has two degrees of freedom to hide it in -- yet is
    metres off; the pose without that pair moves by about its error. A pose that one pair moves
    that far is one the detections cannot confirm within the tolerance.
    """
    if inputs.tolerance_m is None:
        return None
    worst = inputs.worst_leverage_m
    tolerance, bound, seen = inputs.tolerance
    if worst <= tolerance:
        return None
    rows = np.flatnonzero(inputs.assignment >= 0)
    return Refusal(
        FailureCode.ILL_CONDITIONED,
        f"unconfirmed pose: leaving out one of its {rows.size} pairs moves the camera centre "
        f"{worst:.2f} m, beyond the tolerance {tolerance:.2f} m (max({inputs.tolerance_m:g} m, 3 x the "
        f"bound {bound:.2f} m of the {seen} landmarks it predicts at "
        f"{inputs.fit_sigma_px:g} px)): "
        "a pair a few px off would make it wrong unseen",
    )


def protection_level(
    K: NDArray[np.float64], cam_from_world: NDArray[np.float64], landmarks_xyz: NDArray[np.float64],
    bias_px: float,
) -> float:
    """How far, m, a bias of at most ``bias_px`` on each coordinate of every pair moves the centre.

    Linearized at the pose: the camera centre moves by ``S b`` for a bias ``b`` (2P,) on the
    pairs' pixels, ``S`` the position rows of ``(J^T J)^+ J^T`` (``J`` the (2P, 6) projection
    Jacobian); over the biases with ``|b_k| <= bias_px`` each axis moves at most ``bias_px sum_k
    |S_ik|``, and the level is the norm of those three (an upper bound of the worst move).
    """
    J, _ = pose_jacobian(K, cam_from_world, landmarks_xyz)
    S = np.linalg.pinv(J.T @ J) @ J.T
    return float(bias_px * np.linalg.norm(np.abs(S[:3]).sum(axis=1)))


def _bias_refusal(inputs: VerifyInputs) -> Refusal | None:
    """The refusal when a pattern of small biases could move the pose beyond the tolerance, else None.

    The bias: :data:`BIAS_SHARE` of the detector's fit sigma on every detection
    (:func:`protection_level`); the tolerance: :func:`position_tolerance`'s, as the one-pair test
    (:func:`_influence_refusal`) holds it.
    """
    if inputs.tolerance_m is None:
        return None
    rows = np.flatnonzero(inputs.assignment >= 0)
    bias = BIAS_SHARE * inputs.fit_sigma_px
    level = protection_level(inputs.K, inputs.cam_from_world, inputs.landmarks_xyz[inputs.assignment[rows]],
                             bias)
    tolerance, bound, seen = inputs.tolerance
    if level <= tolerance:
        return None
    return Refusal(
        FailureCode.ILL_CONDITIONED,
        f"unconfirmed pose: a bias of {bias:.2f} px on each of its {rows.size} detections could move "
        f"the camera centre {level:.2f} m, beyond the tolerance {tolerance:.2f} m (max("
        f"{inputs.tolerance_m:g} m, 3 x the bound {bound:.2f} m of the {seen} landmarks it predicts at "
        f"{inputs.fit_sigma_px:g} px)): too far for its detections to confirm it",
    )


def _refit(
    inputs: VerifyInputs, rows: NDArray[np.int64], ids: NDArray[np.int64]
) -> NDArray[np.float64]:
    """The pose refined on the pairs (detection ``rows``, landmark ``ids``) from the winner's."""
    T0 = inputs.cam_from_world
    R, t, _ = refine_many(
        inputs.K, T0[None, :3, :3].copy(), T0[None, :3, 3].copy(), inputs.landmarks_xyz[ids][None].copy(),
        inputs.detections_uv[rows][None].copy(), np.ones((1, rows.size), dtype=bool), iterations=100,
        tol=1e-8,
    )
    return to_transforms(R, t)[0]


def without_outliers(inputs: VerifyInputs) -> tuple[NDArray[np.float64], NDArray[np.int64], int]:
    """The winner refit without the pairs the others reject: ``(cam_from_world, assignment, dropped)``.

    The worst pair beyond the others' leave-one-out :data:`OUTLIER_QUANTILE`
    (:func:`leave_one_out_chi2` at the detector's fit sigma) is dropped and the pose refitted on
    the rest, again while one is rejected and more than ``need`` pairs remain (a minimal fit has
    its own test, :func:`minimal_fit_chi2_limit`). With nothing dropped, the winner's pose and
    assignment. Made once per pose (:attr:`VerifyInputs.without_outliers`).
    """
    rows = np.flatnonzero(inputs.assignment >= 0)
    ids = inputs.assignment[rows]
    limit = chi2_quantile(OUTLIER_QUANTILE, 2)
    T, dropped = inputs.cam_from_world, 0
    while True:
        t = leave_one_out_chi2(inputs.K, T, inputs.landmarks_xyz[ids], inputs.detections_uv[rows],
                               inputs.fit_sigma_px)
        worst = int(np.argmax(t))
        if not t[worst] > limit:
            break
        if rows.size <= inputs.need:  # a minimal fit: its own test (minimal_fit_chi2_limit) holds it
            break
        keep = np.arange(rows.size) != worst
        rows, ids, dropped = rows[keep], ids[keep], dropped + 1
        T = _refit(inputs, rows, ids)
    a = np.full_like(inputs.assignment, -1)
    a[rows] = ids
    return T, a, dropped


def _outlier_refusal(inputs: VerifyInputs) -> Refusal | None:
    """The refusal when pairs the others reject (:func:`leave_one_out_chi2`) hold the pose up.

    The pose refit without them (:func:`without_outliers`) fails the pose as
    :attr:`~localization.failure.FailureCode.UNSUPPORTED` when its camera centre lies outside
    the winner's 99.9 % position ellipsoid (:data:`DISTINCT_POSITION_SQ`; the winner's
    covariance rescaled from ``pixel_sigma`` to the detector's ``fit_sigma``): the winner then
    rests on wrong pairs. A right pose with a stray pair among many keeps its centre and passes
    (and the localizer reports the refit: :meth:`localization.Localizer.localize`).
    """
    T, _, dropped = inputs.without_outliers
    if dropped == 0:
        return None
    dc = pose_difference(T, inputs.cam_from_world)[:3]
    cov = inputs.covariance[:3, :3]
    if not np.all(np.isfinite(cov)):
        return None
    q = float(dc @ np.linalg.lstsq(cov, dc, rcond=None)[0]) * (inputs.pixel_sigma / inputs.fit_sigma_px) ** 2
    if q <= DISTINCT_POSITION_SQ:
        return None
    return Refusal(
        FailureCode.UNSUPPORTED,
        f"unsupported pose: {dropped} of its pairs lie beyond the others' leave-one-out "
        f"{OUTLIER_QUANTILE:g} quantile (pixel sigma {inputs.fit_sigma_px:g} px), and without them the "
        f"camera centre moves {float(np.linalg.norm(dc)):.2f} m (squared Mahalanobis {q:.1f} > "
        f"{DISTINCT_POSITION_SQ:g}): the pose rests on wrong pairs",
    )


def _offset_votes(
    pair_uv: NDArray[np.float64], free_uv: NDArray[np.float64], tol: float, radius: float
) -> NDArray[np.float64]:
    """Candidate common offsets from the pairs to the free detections, most pairs agreeing first.

    The offsets between ``tol`` and ``radius`` long are binned in ``tol`` cells; the
    :data:`_VOTE_CELLS` cells whose 3 x 3 neighbourhoods hold the most pairs each give a
    candidate: the mean of the offsets within ``tol`` of the cell's first, with the number of
    distinct pairs that have an offset within ``tol`` of it. The three candidates most pairs
    agree with are returned, as (C, 3): offset (2), agreeing pairs. (A neighbourhood sums its
    cells, so on a regular layout one whose cells hold the offsets to a copy's neighbours
    outvotes the copy's own offset: the cells are ranked again by the pairs that agree.)
    Compiled: :func:`localization.verify_kernels.offset_votes`.
    """
    return offset_votes(kernel_array(pair_uv, dtype=np.float64),
                        kernel_array(free_uv, dtype=np.float64), float(tol), float(radius),
                        _VOTE_CELLS, 3)


def _swap_sets(
    pair_uv: NDArray[np.float64], free_uv: NDArray[np.float64], tol: float
) -> tuple[NDArray[np.int64], list[NDArray[np.bool_]]]:
    """Each pair's partner among the free detections, and the sets of pairs to swap to it.

    Returns ``(partner (P,), swaps)``: ``partner[p]`` the nearest free detection (column of ``free_uv``)
    within :data:`TWIN_RADIUS_PX` of pair ``p``, -1 for none; each swap a (P,) mask of pairs that move
    together and the (P,) free detection each moves to. A common offset ``o`` (:func:`_offset_votes`)
    gives the pairs with a free detection at ``+o`` and those at ``-o`` (a winner may hold some copies of
    each), each set alone and both. With at most :data:`_ENUMERATE_PAIRS` pairs (where a mix of copies
    still fits a pose) every choice of pairs moving to one of their nearest free detections within
    :data:`TWIN_RADIUS_PX` (:func:`_enumerated_swaps`), each swap with its own targets.
    """
    n = len(pair_uv)
    d = np.hypot(*(free_uv[None, :, :] - pair_uv[:, None, :]).transpose(2, 0, 1))
    partner = np.where(d.min(axis=1) <= TWIN_RADIUS_PX, d.argmin(axis=1), -1)
    swaps: list[tuple[NDArray[np.bool_], NDArray[np.int64]]] = []
    for ox, oy, _ in _offset_votes(pair_uv, free_uv, tol, TWIN_RADIUS_PX)[:2]:
        sides = []
        for sign in (1.0, -1.0):
            ds = np.hypot(*(free_uv[None, :, :] - (pair_uv + sign * np.array([ox, oy]))[:, None, :])
                          .transpose(2, 0, 1))
            sides.append((ds.min(axis=1) <= tol, ds.argmin(axis=1)))
        (pa, fa), (pb, fb) = sides
        to = np.where(pa, fa, np.where(pb, fb, -1))
        for move in (pa, pb & ~pa, pa | pb):
            if move.any():
                swaps.append((move, to))
    has = np.flatnonzero(partner >= 0)
    if n <= _ENUMERATE_PAIRS and has.size:
        swaps += _enumerated_swaps(d)
    return partner, swaps


def _enumerated_swaps(d: NDArray[np.float64]) -> list[tuple[NDArray[np.bool_], NDArray[np.int64]]]:
    """Every choice, per pair, of staying or moving to one of its nearest free detections.

    ``d`` (P, F) the distances from the pairs to the free detections. Each pair may move to one
    of its ``c`` nearest within :data:`TWIN_RADIUS_PX`, ``c`` the most that keeps the choices
    within :data:`_ENUMERATE_CHOICES` (at least the nearest): a detector that fires beside
    several corners leaves the right detection of a pair not always the nearest free one.
    """
    n = d.shape[0]
    c = 1
    while (c + 2) ** n <= _ENUMERATE_CHOICES and c + 1 <= d.shape[1]:
        c += 1
    order = np.argsort(d, axis=1, kind="stable")[:, :c]
    near = np.take_along_axis(d, order, axis=1) <= TWIN_RADIUS_PX
    options = [[-1] + [int(f) for f, ok in zip(order[p], near[p], strict=True) if ok] for p in range(n)]
    out = []
    for choice in itertools.product(*options):
        to = np.asarray(choice, dtype=np.int64)
        move = to >= 0
        if move.any():
            out.append((move, to))
    return out


def twin_hypotheses(inputs: VerifyInputs) -> list[tuple[NDArray[np.int64], NDArray[np.float64], float]]:
    """The winner's landmarks moved to other detections (module docstring), refined at once.

    Returns ``[(assignment (N,), cam_from_world (4, 4), chi-square), ...]``: each a set of
    pairs moved to their partners (:func:`_swap_sets`), one-to-one, refined from the winner's
    pose (Levenberg-Marquardt, one compiled batch).
    """
    det, a = inputs.detections_uv, inputs.assignment
    pairs = np.flatnonzero(a >= 0)
    free = np.flatnonzero((a < 0) & np.isfinite(det).all(axis=1))
    if free.size == 0 or pairs.size == 0:
        return []
    _, swaps = _swap_sets(det[pairs], det[free], 2.0 * inputs.gate_px)
    alts = []
    for move, to in swaps:
        rows = pairs.copy()
        rows[move] = free[to[move]]
        if np.unique(rows).size == rows.size:  # one-to-one
            alts.append(rows)
    if not alts:
        return []
    rows = np.stack(alts)
    h = rows.shape[0]
    X = np.broadcast_to(inputs.landmarks_xyz[a[pairs]], (h, pairs.size, 3)).copy()
    T0 = inputs.cam_from_world
    R, t, cost = refine_many(
        inputs.K, np.broadcast_to(T0[:3, :3], (h, 3, 3)).copy(), np.broadcast_to(T0[:3, 3], (h, 3)).copy(),
        X, det[rows], np.ones((h, pairs.size), dtype=bool), iterations=100, tol=1e-8,
    )
    out = []
    for k, T in enumerate(to_transforms(R, t)):
        b = np.full(det.shape[0], -1, dtype=np.int64)
        b[rows[k]] = a[pairs]
        out.append((b, T, float(cost[k]) / inputs.pixel_sigma**2))
    return out


def _scores(
    inputs: VerifyInputs, hypotheses: list[tuple[NDArray[np.int64], NDArray[np.float64]]]
) -> NDArray[np.float64]:
    """(H,) the negative log-likelihoods of hypotheses ``(assignment, cam_from_world)``.

    As the association scores them: squared residuals, a clutter cost per unassigned detection, a miss
    cost per predicted landmark left unmatched, the prior's Mahalanobis distance (compiled,
    :func:`_terms`).
    """
    if not hypotheses:
        return np.zeros(0)
    a = kernel_array(np.stack([b for b, _ in hypotheses]), dtype=np.int64)
    T = np.stack([T for _, T in hypotheses])
    chi, missed, prior_sq, far = _terms(inputs, a, T)
    n_free = np.count_nonzero(a[:, inputs.arrays.good] < 0, axis=1)
    for h in np.flatnonzero(far):  # near pi from the prior's rotation: the exact logarithm
        prior_sq[h] = prior_mahalanobis_sq(T[h], inputs.prior_cam_from_world, inputs.prior_sigmas)
    return (chi / inputs.pixel_sigma**2 + n_free * (inputs.gate_px / inputs.pixel_sigma) ** 2
            + missed * inputs.miss_cost + prior_sq)


def _terms(
    inputs: VerifyInputs, a: NDArray[np.int64], T: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_]]:
    """``(chi px^2, missed, prior_sq, far)`` of assignments ``a`` (H, N) at poses ``T`` (H, 4, 4).

    The association's own kernels (:func:`localization.associate.hypothesis_kernels.check_many`
    and :func:`~localization.associate.hypothesis_kernels.missed_many`), one call each.
    """
    f = inputs.arrays
    w, h = inputs.image_size
    R, t = kernel_array(T[:, :3, :3]), kernel_array(T[:, :3, 3])
    prior_sq, chi, far = check_many(f.K, f.landmarks_xyz, f.detections_uv, a, R, t, f.prior_R, f.prior_C,
                                    f.prior_sigmas)
    return chi, missed_many(f.K, f.landmarks_xyz, a, R, t, int(w), int(h)), prior_sq, far


def reassociated(
    inputs: VerifyInputs, hypotheses: list[tuple[NDArray[np.int64], NDArray[np.float64], object]],
    unchanged: bool = False,
) -> list[tuple[int, NDArray[np.int64], NDArray[np.float64], float]]:
    """Rival hypotheses grown whole: every landmark re-associated at the rival's pose.

    A twin or a lattice rival pairs only the winner's landmarks, moved. Where the winner leaves
    detections unexplained (a few pairs of a ghost copy: a copy shifted as a whole fits no pose
    exactly, so only a patch of it pairs; a period of the layout, whose landmarks at the edge
    have no counterpart), the rival at the structure's pose pairs many more landmarks than the
    winner. Each rival is refined and re-associated at the final gate until its pairs are
    stable, as the association refines its hypotheses
    (:func:`localization.associate.assign_kernels.refine_reassign`), to be scored as a
    hypothesis of its own. Returns ``[(k, assignment, cam_from_world, chi-square), ...]`` for
    the rivals (``hypotheses[k]``) that keep at least ``need`` pairs and changed -- with
    ``unchanged``, also those whose pairs the re-association kept (at their refined pose): a
    period of most of the layout that pairs exactly the structure's detections is already whole.
    """
    if not hypotheses:
        return []
    f = inputs.arrays
    a0 = kernel_array(np.stack([b for b, _, _ in hypotheses]), dtype=np.int64)
    T0 = np.stack([T for _, T, _ in hypotheses])
    w, h = inputs.image_size
    a, R, t, alive = refine_reassign(
        f.K, f.landmarks_xyz, f.detections_uv, f.good, a0, kernel_array(T0[:, :3, :3]),
        kernel_array(T0[:, :3, 3]),
        int(w), int(h), 0.0, float(inputs.gate_px), float(4.0 * inputs.gate_px), _REASSOCIATE_ROUNDS,
        int(inputs.need), True,
    )
    changed = np.flatnonzero(alive & (unchanged | np.any(a != a0, axis=1)))
    if changed.size == 0:
        return []
    Ts = to_transforms(R[changed], t[changed])
    chi = _terms(inputs, kernel_array(a[changed]), Ts)[0] / inputs.pixel_sigma**2
    return [(int(k), a[k].copy(), T, float(c)) for k, T, c in zip(changed, Ts, chi, strict=True)]


def offset_starts(inputs: VerifyInputs) -> list[tuple[NDArray[np.int64], NDArray[np.float64], float]]:
    """Hypotheses from the winner's predictions moved by a common image offset.

    A pose that pairs a patch of a ghost copy, or the layout one period over, predicts its
    landmarks where the structure is not: the structure's detections lie near those
    predictions, all moved by about one offset. The offsets from the landmarks the winner
    predicts in the image to the detections are voted as the twins' are (:func:`_offset_votes`,
    up to :data:`TWIN_RADIUS_PX`); each of the :data:`_OFFSET_STARTS` best gives the predicted
    landmarks paired one-to-one with the detection at that offset (within twice the gate), a
    start for :func:`reassociated` at the winner's pose when it holds at least ``need`` pairs.
    Returns ``[(assignment, cam_from_world, nan), ...]``.
    """
    f = inputs.arrays
    det, good = f.detections_uv, f.good
    seen = np.flatnonzero(f.predicted)
    if seen.size < inputs.need or good.size < inputs.need:
        return []
    uv = f.winner_uv[seen]
    tol = 2.0 * inputs.gate_px
    out = []
    det_good = det[good]
    for ox, oy, _ in _offset_votes(uv, det_good, tol, TWIN_RADIUS_PX)[:_OFFSET_STARTS]:
        moved = (uv + [ox, oy])[None]
        local = assign_rounds(det_good, moved, tol, 3)[0]
        if np.count_nonzero(local >= 0) >= inputs.need:
            b = np.full(det.shape[0], -1, dtype=np.int64)
            b[good[local >= 0]] = seen[local[local >= 0]]
            out.append((b, inputs.cam_from_world, float("nan")))
    return out


def _same_centres(inputs: VerifyInputs, Ts: list[NDArray[np.float64]]) -> NDArray[np.bool_]:
    """Whether each pose's camera centre lies inside the winner's 99.9 % position ellipsoid."""
    cov = inputs.covariance[:3, :3]
    if not Ts or not np.all(np.isfinite(cov)):
        return np.zeros(len(Ts), dtype=bool)
    dc = np.stack([center(kernel_array(T)) for T in Ts]) - inputs.arrays.centre
    try:
        x = np.linalg.solve(cov, dc.T)
    except np.linalg.LinAlgError:  # singular: the least-squares solution
        x = np.linalg.lstsq(cov, dc.T, rcond=None)[0]
    return np.sum(dc * x.T, axis=1) <= DISTINCT_POSITION_SQ


def _fits(rivals: list[tuple[NDArray[np.int64], NDArray[np.float64], float]]) -> list[bool]:
    """Whether each rival ``(assignment, cam_from_world, chi-square)`` passes the fit test.

    The association's: :data:`_FIT_QUANTILE` of ``2 k - 6`` degrees of freedom on its ``k`` pairs.
    """
    return [bool(chi <= chi2_quantile(_FIT_QUANTILE, max(2 * int(np.count_nonzero(b >= 0)) - 6, 1)))
            for b, _, chi in rivals]


def _distinct_fits(
    inputs: VerifyInputs, rivals: list[tuple[NDArray[np.int64], NDArray[np.float64], float]]
) -> list[int]:
    """Indices of the rivals ``(assignment, cam_from_world, chi-square)`` that fit, elsewhere.

    Those that pass the fit test (:func:`_fits`) and lie at a distinct camera centre
    (:func:`_same_centres`), in order.
    """
    fit = [k for k, ok in enumerate(_fits(rivals)) if ok]
    same = _same_centres(inputs, [rivals[k][1] for k in fit])
    return [k for k, s in zip(fit, same, strict=True) if not s]


def _contenders(
    inputs: VerifyInputs, rivals: list[tuple[NDArray[np.int64], NDArray[np.float64], float]]
) -> list[tuple[int, float]]:
    """``[(index, score), ...]`` of the rivals that could be the pose as well as the winner.

    Those that fit at a distinct camera centre (:func:`_distinct_fits`) and score within the
    ambiguity margin of the winner, or better; in the rivals' order.
    """
    kept = _distinct_fits(inputs, rivals)
    if not kept:
        return []
    scores = _scores(inputs, [(rivals[k][0], rivals[k][1]) for k in kept])
    best = inputs.winner_score
    return [(k, float(s)) for k, s in zip(kept, scores, strict=True) if s - best < AMBIGUITY_MARGIN]


def _rival_refusal(inputs: VerifyInputs) -> Refusal | None:
    """The twins' refusal (:func:`_twin_refusal`), else the layout periods' (:func:`_lattice_refusal`).

    The twins and the offset starts grow in one batch of re-association (:func:`reassociated`;
    each start's growth is its own, whatever the batch holds), the periods in another, which
    keeps those the re-association leaves as they were: a period of most of the layout (a winner
    one row over, plus a clutter point off the layout's edge, is no exact period) may pair
    exactly the structure's detections already, and it is scored at its refined pose.
    """
    twins = twin_hypotheses(inputs)
    starts = twins + offset_starts(inputs)
    exact = lattice_rivals(inputs)
    periods = exact + lattice_rivals(inputs, LATTICE_SHARE, LATTICE_SPACING_SHARE * inputs.spacing_m,
                                     _LATTICE_ANCHORS)
    return (
        _twin_refusal(inputs, twins + [r[1:] for r in reassociated(inputs, starts)])
        or _lattice_refusal(inputs, exact, periods, reassociated(inputs, periods, unchanged=True))
    )


def _twin_refusal(
    inputs: VerifyInputs, rivals: list[tuple[NDArray[np.int64], NDArray[np.float64], float]]
) -> Refusal | None:
    """The refusal when a twin fits, is a distinct pose and scores about as well, else None.

    ``rivals``: the twins (:func:`twin_hypotheses`) and the twins and offset starts
    (:func:`offset_starts`) grown by re-association (:func:`reassociated`).
    """
    found = _contenders(inputs, rivals)
    if not found:
        return None
    k_rival, s_twin = found[0]
    a_twin, T_twin, _ = rivals[k_rival]
    n = int(np.count_nonzero(inputs.assignment >= 0))
    k = int(np.count_nonzero(a_twin >= 0))
    d = pose_difference(T_twin, inputs.cam_from_world)
    moved = int(np.count_nonzero((a_twin >= 0) & (inputs.assignment < 0)))
    return Refusal(
        FailureCode.DUPLICATED_DETECTIONS,
        f"duplicated detections: the same landmarks ({n} pairs; {k} after re-association) "
        f"with {moved} of their detections moved to unassigned ones within {TWIN_RADIUS_PX:g} px "
        f"fit as well (scores {inputs.winner_score:.1f} and {s_twin:.1f}, margin {AMBIGUITY_MARGIN:.1f}) "
        f"with a camera centre {float(np.linalg.norm(d[:3])):.2f} m and "
        f"{float(np.degrees(np.linalg.norm(d[3:]))):.2f} deg away",
    )


def lattice_rivals(
    inputs: VerifyInputs, share: float = 1.0, tol_m: float = LATTICE_TOL_M, anchors: int = 1,
) -> list[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]]:
    """The winner's pairs moved by a period of the layout: ``[(assignment, cam_from_world, d), ...]``.

    A translation ``d`` (m, project frame) that carries every paired landmark onto another one
    (within ``tol_m``; the candidates are the first pair's landmark onto every other) gives a
    rival that pairs the same detections with the shifted landmarks, seen by the camera moved
    by ``d`` with the same rotation: its residuals are the winner's exactly.

    With ``share < 1`` a translation that carries at least that share of the pairs (and at
    least ``need``) gives a rival of those pairs alone, a start for :func:`reassociated`: a
    winner that pairs the detections with the landmarks one period over on most of the layout
    and otherwise elsewhere at its edges, or on a layout whose spacing is irregular (``tol_m``
    then a share of the spacing), is no exact period of its pairs. The candidates are then the
    first ``anchors`` pairs' landmarks onto every other.
    """
    a = inputs.assignment
    rows = np.flatnonzero(a >= 0)
    if rows.size == 0:
        return []
    X = kernel_array(inputs.landmarks_xyz, dtype=np.float64)
    P = X[a[rows]]
    least = rows.size if share >= 1.0 else max(int(math.ceil(share * rows.size)), inputs.need)
    kept, hit, j = lattice_hits(X, P, min(anchors, rows.size), float(tol_m), int(least),
                                float(max(tol_m, LATTICE_TOL_M)))
    R, t = inputs.cam_from_world[:3, :3], inputs.cam_from_world[:3, 3]
    d = X[kept % len(X)] - P[kept // len(X)]
    T = np.repeat(inputs.cam_from_world[None], kept.size, axis=0)
    T[:, :3, 3] = t - d @ R.T  # camera centre C + d
    b = np.full((kept.size, a.size), -1, dtype=a.dtype)
    b[:, rows] = np.where(hit, j, -1)
    return list(zip(b, T, d, strict=True))


def landmark_spacing_m(landmarks_xyz: NDArray[np.float64]) -> float:
    """The median distance from a landmark to its nearest other landmark, m (0 for one landmark)."""
    if len(landmarks_xyz) < 2:
        return 0.0
    d, _ = cKDTree(landmarks_xyz).query(landmarks_xyz, k=2)
    return float(np.median(d[:, 1]))


def _lattice_refusal(
    inputs: VerifyInputs,
    exact: list[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]],
    rivals: list[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]],
    grown: list[tuple[int, NDArray[np.int64], NDArray[np.float64], float]],
) -> Refusal | None:
    """The refusal when a shift by a period of the layout scores within the ambiguity margin.

    The exact periods of the winner's pairs (``exact``, :func:`lattice_rivals`) are scored as
    they are and re-associated; the periods of most of them (:data:`LATTICE_SHARE` of the pairs,
    within :data:`LATTICE_SPACING_SHARE` of the layout's spacing) re-associated only: ``rivals``
    both, ``grown`` their re-associations (:func:`reassociated`, indices into ``rivals``).
    """
    if not rivals:
        return None
    distinct = [grown[i] for i in _distinct_fits(inputs, [r[1:] for r in grown])]
    hypotheses = [(b, T) for b, T, _ in exact] + [(b, T) for _, b, T, _ in distinct]
    periods = [d for _, _, d in exact] + [rivals[k][2] for k, _, _, _ in distinct]
    if not hypotheses:
        return None
    scores = _scores(inputs, hypotheses)
    best = int(np.argmin(scores))  # the first of equals
    s_rival, d, s_best = float(scores[best]), periods[best], inputs.winner_score
    if s_rival - s_best >= AMBIGUITY_MARGIN:
        return None
    return Refusal(
        FailureCode.AMBIGUOUS,
        f"ambiguous pose: the layout repeats with period ({d[0]:.2f}, {d[1]:.2f}, {d[2]:.2f}) m, and "
        f"the same detections paired with the landmarks one period over (camera moved "
        f"{float(np.linalg.norm(d)):.2f} m) score {s_rival:.1f} against {s_best:.1f} (margin "
        f"{AMBIGUITY_MARGIN:.1f}): only the prior tells them apart",
    )


def rival_search(inputs: VerifyInputs) -> list[tuple[NDArray[np.int64], NDArray[np.float64], float]]:
    """The association's best hypothesis among the detections the winner leaves unexplained.

    A search that settles on a patch of the detections (a few pairs of a ghost copy mixed with
    the structure's own, each paired with the wrong landmark) leaves most of them unassigned,
    and the structure's pose among them is one no start of the winner's reaches: no common
    image offset or period of the layout maps the winner onto it. When the winner explains at
    most half of the detections (its free ones at least as many as its pairs, and ``need``),
    the search (``inputs.search``) runs again over the free ones alone; its hypothesis and the
    same re-associated over every detection (:func:`reassociated`) are the rivals. Returns
    ``[(assignment, cam_from_world, chi-square), ...]``.
    """
    if inputs.search is None:
        return []
    det, a = inputs.detections_uv, inputs.assignment
    free = (a < 0) & np.isfinite(det).all(axis=1)
    n_free, k = int(free.sum()), int(np.count_nonzero(a >= 0))
    if n_free < max(inputs.need, k):
        return []
    found = inputs.search(free)
    if found is None:
        return []
    b, T = found
    m = b >= 0
    if np.count_nonzero(m) < inputs.need:
        return []
    uv, _ = project(inputs.K, T, inputs.landmarks_xyz[b[m]])
    first = (b, T, float(np.sum((uv - det[m]) ** 2)) / inputs.pixel_sigma**2)
    return [first] + [r[1:] for r in reassociated(inputs, [first])]


def _search_refusal(inputs: VerifyInputs) -> Refusal | None:
    """The refusal when the second search's rival (:func:`rival_search`) scores about as well."""
    rivals = rival_search(inputs)
    found = _contenders(inputs, rivals)
    if not found:
        return None
    k_rival, s_rival = found[0]
    b, T, _ = rivals[k_rival]
    k = int(np.count_nonzero(b >= 0))
    n = int(np.count_nonzero(inputs.assignment >= 0))
    dc = pose_difference(T, inputs.cam_from_world)[:3]
    return Refusal(
        FailureCode.AMBIGUOUS,
        f"ambiguous pose: the detections its {n} pairs leave unexplained give another pose of "
        f"{k} pairs, camera centre {float(np.linalg.norm(dc)):.2f} m away, scoring {s_rival:.1f} "
        f"against {inputs.winner_score:.1f} (margin {AMBIGUITY_MARGIN:.1f})",
    )


def verify_pose(inputs: VerifyInputs) -> Refusal | None:
    """None when the detections confirm the pose, else why not (module docstring)."""
    a = inputs.assignment
    k = int(np.count_nonzero(a >= 0))
    predicted = inputs.arrays.predicted
    n = int(predicted.sum())
    n_det = int(np.count_nonzero(np.isfinite(inputs.detections_uv).all(axis=1)))
    log10_nfa = chance_support(n, k, n_det, inputs.image_size, inputs.gate_px)
    if log10_nfa > MAX_LOG10_NFA:
        return Refusal(
            FailureCode.UNSUPPORTED,
            f"unsupported pose: it matches {k} of the {n} landmarks it projects into the image, "
            f"which {n_det} detections over the image match by chance among the poses a search "
            f"tries (false alarms 10^{log10_nfa:.1f} > 10^{MAX_LOG10_NFA:g})",
        )
    return (
        _minimal_fit_refusal(inputs, k)
        or _outlier_refusal(inputs)
        or _influence_refusal(inputs)
        or _rival_refusal(inputs)
        or _search_refusal(inputs)
        or _bias_refusal(inputs)  # last: a rival or a second search names the cause when there is one
    )
