"""Stage 2, association: anonymous detections + BIM landmarks + rough prior pose -> identities.

Two methods:

``paper`` (:func:`associate_paper`)
    The paper's method: project the BIM landmarks with the prior pose, keep those in front of the
    camera and near the image, and solve the rectangular minimum-cost one-to-one assignment on
    squared pixel distance (``scipy.optimize.linear_sum_assignment``, Crouse 2016). Every detection
    is assigned whenever there are at least as many projected landmarks; nothing is gated.

``robust`` (:func:`associate_robust`, the search :class:`RobustSearch`)
    Goes beyond it for a detector that misses landmarks and reports clutter and a prior that is off
    by metres and degrees:

    1. *Hypotheses* (:meth:`RobustSearch.search_starts`). An onboard attitude sensor knows the
       camera's tilt far better than its yaw and position; with the prior's tilt, two
       correspondences fix the pose in closed form (:mod:`localization.associate.upright`).
       Four spread-out detections of the dense part of the image give six anchor pairs (with
       detection scores, the four likeliest detections give up to six more: a dense cluster of
       clutter would otherwise hold every anchor); every ordered pair of candidate landmarks
       whose prior image is within a factor 3 in length and 45 degrees in direction of an
       anchor pair's gives a pose (:meth:`RobustSearch.upright_starts`); poses beyond the
       prior's Mahalanobis gate are dropped, and the rest are ranked by the detections they
       explain within the coarse gate (then by the capped squared distances). The best distinct
       ones each give a gated assignment. When the best refined hypothesis leaves a quarter of
       the landmarks it predicts in the image unmatched, or more than one (and a tenth) of the
       detections and some such landmark (:meth:`RobustSearch.needs_layout_vote`), or is
       ambiguous, the layout vote adds its hypotheses (:meth:`RobustSearch.layout_starts`): the
       prior camera centre moved on the grid {-1, 0, +1 sigma}^3, and for each, every
       (detection, projected landmark) pair proposes a 2D shift ranked by how many other pairs
       agree with it (a Hough vote). Small problems (a slab's four corners) enumerate every
       one-to-one assignment instead.
    2. *Re-association* (:meth:`RobustSearch.refine`). Each hypothesis is refined from its start
       pose (Levenberg-Marquardt with Cauchy weights first, as coarse pairs may hold wrong
       ones), the landmarks are re-projected with that pose and re-assigned with the inlier gate
       ``gate_px`` (enumerated assignments, whose starts fit their pairs exactly, with a gate
       tightening from ``coarse_gate_px / 4``), until the assignment is stable. All hypotheses
       of a batch go through these steps in one compiled call
       (:func:`localization.associate.assign_kernels.refine_reassign`).
    3. *Scoring and gating* (:meth:`RobustSearch.nll`, :meth:`RobustSearch.gate`). Each final
       hypothesis is scored by a negative log-likelihood: squared residuals of the inliers over
       ``pixel_sigma^2``, a fixed cost per unassigned detection (clutter) and per landmark
       predicted inside the image but not detected (miss), plus the squared Mahalanobis
       distance of the pose from the prior (sigmas 3 m, 2/2/5 degrees by default). The prior
       term is what decides between assignments that fit equally well, such as the
       permutations of four coplanar corners. With detection scores (probabilities that each
       detection is a landmark, as the learned detector's refiner gives) each assigned detection
       also adds ``-2 log(s / (1 - s))`` (the log-odds of landmark against clutter; ``s`` clipped
       to [0.01, 0.99]): of two detections a landmark fits about alike, the likelier one is
       assigned -- a corner 0.4 px from its projection with score 0.72 rather than a scaffold
       post 20 px away with score 0.10, which four points alone cannot tell apart. A hypothesis
       whose pose is farther from the prior than the Mahalanobis gate, or whose inlier
       residuals fail a chi-square test against ``pixel_sigma`` (``1 - 1e-6`` quantile,
       ``2 n - 6`` dof), is dropped.
    4. *Rivals and ambiguity* (:meth:`RobustSearch.rival_search`,
       :mod:`localization.associate.ambiguity`). The winner's pose moved by the layout's
       self-translations gives rival hypotheses (:meth:`RobustSearch.rivals`), refined and
       scored the same way; a rival with conflicting identities and a distinct pose within
       ``2 ln 100`` of the best score makes the association fail as ``ambiguous`` instead of
       guessing. Each round also tries the winner with one pair's detection swapped for an
       unassigned detection near that landmark's projection (:meth:`RobustSearch.swaps`: a
       wrong pair the pose absorbed hides the right detection outside the inlier gate), and,
       when the winner leaves the frame open (:meth:`RobustSearch.leaves_open`), the winner grown
       again from its own pairs two at a time with its tilt (:meth:`RobustSearch.regrown`): a
       start with most of its pairs wrong (the layout vote's shifts among dense clutter) settles
       on a dozen right pairs and a few wrong ones metres off, and two of its right pairs give
       the pose that every landmark in view confirms.
    5. *Minimal fits* (:meth:`RobustSearch.minimal_fit_reason`). A winner with no more pairs
       than the minimum that leaves at least as many landmarks unmatched as it pairs, of those
       its pose projects into the image, fails as ``no_consistent_association``: four pairs
       leave the fit test two degrees of freedom, and among enough wrong detections some four
       fit some pose near the prior.

    Gating means a detection (clutter) or a landmark (miss, occlusion) may stay unassigned.

    *Warm start* (:meth:`RobustSearch.warm_association`; ``warm_start``: a predicted pose, e.g.
    the previous frame's estimate moved by the commanded motion). Before any hypothesis, the
    landmarks are projected with the predicted pose, paired (mutual nearest neighbours) within
    ``coarse_gate_px / 4`` and refined with re-association as in step 2. The result is accepted
    without a search only when it explains the whole frame: every finite detection paired,
    every landmark its pose projects inside the image detected, the pose within the prior's
    Mahalanobis gate, the residuals within the fit test, and more pairs than the minimum.
    Anything less (a new landmark entering the view, clutter, a miss, a prediction that has
    drifted) runs the full search above. What it accepts passes the search's own tests; the
    rivals of step 4 are not searched, though: the prediction carries the previous frame's
    identities, which is what tells a periodic layout's shifts apart over time. So it may
    localize a frame the search fails (ambiguous on its own, or a prior that projects every
    landmark out of the image), and where both succeed the identities and poses agree
    (``benchmarks/warm_start.py``).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.associate.ambiguity import AMBIGUITY_MARGIN, ambiguity, translation_hypotheses
from localization.associate.assign_kernels import refine_reassign
from localization.associate.hypotheses import (
    exhaustive_hypotheses,
    layout_hypotheses,
    regrowth_hypotheses,
    upright_hypotheses,
)
from localization.associate.hypothesis_kernels import check_many, missed_many, warm_hypothesis
from localization.associate.paper import Association, assign, candidate_landmarks, no_candidates
from localization.budget import Deadline, OutOfTime
from localization.failure import FailureCode
from localization.geometry.kernels import kernel_array
from localization.geometry.transforms import camera_center, make_transform, project
from localization.pose.batch import to_transforms
from localization.pose.covariance import PriorSigmas, prior_mahalanobis_sq
from localization.pose.pnp import refine_pose, reprojection_residuals
from localization.stats import chi2_quantile

__all__ = ["GRID_OFFSETS", "KernelArrays", "RobustSearch", "RobustSettings", "associate_robust"]


#: Prior-centre perturbations (units of the position sigmas): the 3 x 3 x 3 grid {-1, 0, 1}^3,
#: nearest first. (The paper's protocol puts the prior error exactly on a grid corner; the
#: benchmark also reports Gaussian prior errors to show the search does not rely on that.)
GRID_OFFSETS = tuple(
    sorted(itertools.product((-1.0, 0.0, 1.0), repeat=3), key=lambda o: sum(x * x for x in o))
)

#: A coarse hypothesis: (assignment (N,) of every detection row, -1 unassigned; start pose (4, 4)).
Start = tuple[NDArray, NDArray]
#: A refined hypothesis that passed the gates: (assignment (N,), pose (4, 4), chi-square, prior
#: Mahalanobis^2).
Final = tuple[NDArray, NDArray, float, float]
#: A scored hypothesis: (negative log-likelihood, assignment (N,), pose (4, 4), landmarks missed).
Scored = tuple[float, NDArray, NDArray, int]


@dataclass(frozen=True)
class RobustSettings:
    """The settings of one robust association, defaults resolved (:func:`associate_robust`'s Args).

    Built by :meth:`resolve`; ``gate_px`` and ``coarse_gate_px`` are the gates in effect and
    ``need`` the fewest pairs a hypothesis may keep.
    """

    pixel_sigma: float
    gate_px: float
    coarse_gate_px: float
    max_hypotheses: int
    max_iterations: int
    need: int
    miss_cost: float
    sigmas: PriorSigmas
    max_prior_mahalanobis_sq: float | None
    position_offsets: tuple[tuple[float, float, float], ...]
    shifts_per_layout: int
    exhaustive_limit: int
    max_rivals: int
    max_rival_rounds: int
    ambiguity_margin: float
    fit_quantile: float

    @classmethod
    def resolve(
        cls,
        K: NDArray[np.float64],
        *,
        pixel_sigma: float,
        gate_px: float | None,
        coarse_gate_px: float,
        min_correspondences: int,
        prior_sigmas: PriorSigmas | None,
        **rest: object,
    ) -> RobustSettings:
        """The settings for intrinsics ``K`` from :func:`associate_robust`'s keywords.

        ``gate_px`` None: ``max(5 * pixel_sigma, 3)``. The coarse gate never falls below the
        prior's smallest rotation sigma seen through the lens: the prior's attitude error is an
        angle, which through a long lens moves the projections by hundreds of pixels, and a gate
        fixed in pixels would then match only coincidences. ``rest``: the other keywords, as
        they are.
        """
        sig = prior_sigmas or PriorSigmas()
        return cls(
            pixel_sigma=pixel_sigma,
            gate_px=float(gate_px) if gate_px is not None else max(5.0 * pixel_sigma, 3.0),
            coarse_gate_px=max(coarse_gate_px, min(K[0, 0], K[1, 1]) * min(sig.rotation_rad)),
            need=max(min_correspondences, 3),
            sigmas=sig,
            **rest,
        )

    @property
    def batch(self) -> int:
        """Most coarse hypotheses of one source refined in one batch: ``2 * max_hypotheses``."""
        return 2 * max(self.max_hypotheses, 1)


@dataclass(frozen=True)
class KernelArrays:
    """The inputs as the compiled steps take them: contiguous float64, converted once."""

    det: NDArray
    landmarks_xyz: NDArray
    K: NDArray
    prior: NDArray
    #: (3, 3) the prior's rotation.
    prior_R: NDArray
    #: (3,) the prior's camera centre.
    prior_C: NDArray
    #: (6,) the prior's sigmas (position m, rotation rad).
    sigmas: NDArray

    @classmethod
    def of(
        cls, det: NDArray, landmarks_xyz: NDArray, K: NDArray, prior: NDArray, sigmas: PriorSigmas
    ) -> KernelArrays:
        """Contiguous float64 copies (or the arrays themselves when they already are)."""
        f64 = np.float64
        prior = kernel_array(prior, dtype=f64)
        return cls(
            kernel_array(det, dtype=f64), kernel_array(landmarks_xyz, dtype=f64),
            kernel_array(K, dtype=f64), prior, kernel_array(prior[:3, :3]),
            camera_center(prior), sigmas.as_array(),
        )


class RobustSearch:
    """The robust association of one frame: the search's steps, and its state between them.

    The module docstring describes the method; :meth:`run` is the sequence, and each step is a
    method: the warm start (:meth:`warm_association`), the starting hypotheses
    (:meth:`search_starts`, :meth:`upright_starts`, :meth:`layout_starts`), the batched
    re-association (:meth:`explore`, :meth:`refine`), the gates (:meth:`gate`), the scoring
    (:meth:`nll`, :meth:`score`, :meth:`ranked`), the rival search and the ambiguity rule
    (:meth:`rival_search`, :meth:`rivals`, :meth:`swaps`) and the last checks of the winner
    (:meth:`conclude`, :meth:`minimal_fit_reason`). One object searches one frame once.

    Attributes:
        det, landmarks_xyz, K, prior, image_size, margin_px: the inputs as given (the numpy
            steps read them as they are).
        arrays: the same inputs as the compiled steps take them (:class:`KernelArrays`).
        settings: the search's :class:`RobustSettings`.
        good: (G,) the rows of ``det`` with finite coordinates.
        log_odds: (N,) ``2 log(s / (1 - s))`` of each detection's score (the scoring's reward
            for assigning it), or None without scores.
        finals: the refined hypotheses that passed the gates, by assignment bytes, in the order
            found.
        explored: every refined assignment that survived the refinement (passed or not): a
            coarse hypothesis whose pairs all agree with one of them is not refined again.
        rejected: how many refined hypotheses failed the prior's gate (``"prior"``) and the fit
            test (``"fit"``).
        tried: how many coarse hypotheses were refined.
        voted: whether the layout vote (or the enumeration that replaces it) has run.
    """

    def __init__(
        self,
        detections_uv: NDArray[np.float64],
        landmarks_xyz: NDArray[np.float64],
        K: NDArray[np.float64],
        prior_cam_from_world: NDArray[np.float64],
        image_size: tuple[int, int],
        margin_px: float,
        settings: RobustSettings,
        detection_scores: NDArray[np.float64] | None = None,
        deadline: Deadline | None = None,
    ) -> None:
        self.det = detections_uv
        self.landmarks_xyz = landmarks_xyz
        self.K = K
        self.prior = prior_cam_from_world
        self.image_size = image_size
        self.margin_px = margin_px
        self.settings = settings
        self.good = np.flatnonzero(np.isfinite(detections_uv).all(axis=1))
        self.arrays = KernelArrays.of(detections_uv, landmarks_xyz, K, prior_cam_from_world, settings.sigmas)
        self.log_odds = _log_odds(detection_scores)
        self.finals: dict[bytes, Final] = {}
        self.explored: list[NDArray] = []
        self.rejected = {"prior": 0, "fit": 0}
        self.tried = 0
        self.voted = False
        self.deadline = deadline
        self._ranked: dict[int, list[Scored]] = {}

    # ---------------------------------------------------------------- the sequence

    def run(self, warm_start: NDArray[np.float64] | None = None) -> Association:
        """The association: the warm start if it explains the frame, else the search (steps 1-5)."""
        if self.good.size == 0:
            return Association(
                self.unassigned(), self.prior, 0.0, np.inf, 0, "no finite detection",
                FailureCode.TOO_FEW_DETECTIONS,
            )
        if warm_start is not None:
            warm = self.warm_association(warm_start)
            if warm is not None:
                return warm
        # the prior's candidates (only a search needs them: an accepted warm start returns first)
        idx, proj = candidate_landmarks(
            self.landmarks_xyz, self.K, self.prior, self.image_size, self.margin_px
        )
        if idx.size == 0:
            return no_candidates(self.unassigned(), self.prior, np.inf, 0)
        try:
            return self.search(idx, proj)
        except OutOfTime as out:
            n, code = len(self.finals), FailureCode.TIMED_OUT
            return Association(self.unassigned(), self.prior, 0.0, np.inf, n, out.reason, code)

    def search(self, idx: NDArray, proj: NDArray) -> Association:
        """Steps 1-5 from the prior's candidate landmarks ``idx`` (projections ``proj``).

        Raises :class:`localization.budget.OutOfTime` when the deadline passes between steps.
        """
        self.search_starts(idx, proj)
        if not self.finals:
            return self.no_final_failure()
        scored, reason = self.rival_search()
        if reason is not None and not self.voted and self.explore(self.layout_starts(), True):
            scored, reason = self.rival_search()
        if reason is not None:
            return Association(
                self.unassigned(), self.prior, 0.0, np.inf, len(self.finals), reason, FailureCode.AMBIGUOUS
            )
        return self.conclude(scored[0])

    def check_time(self, step: str) -> None:
        """Raise :class:`localization.budget.OutOfTime` before ``step`` if the deadline has passed."""
        if self.deadline is not None:
            self.deadline.check(f"the robust association's {step}")

    def unassigned(self) -> NDArray[np.int64]:
        """(N,) no detection assigned: a failure's assignment."""
        return np.full(self.det.shape[0], -1, dtype=np.int64)

    # ---------------------------------------------------------------- warm start

    def warm_association(self, start: NDArray) -> Association | None:
        """The association of the predicted pose ``start`` alone, or None if it leaves anything open.

        Accepted (module docstring, *Warm start*) when, refined with re-association, it pairs every
        finite detection, detects every landmark its pose projects inside the image, keeps more
        pairs than the minimum, stays within the prior's Mahalanobis gate and passes the fit test.
        One compiled call (:func:`localization.associate.hypothesis_kernels.warm_hypothesis`).
        """
        s, c = self.settings, self.arrays
        if self.good.size <= s.need:
            return None
        w, h = self.image_size
        start = kernel_array(start, dtype=np.float64)
        a, R, t, alive, prior_sq, far, chi, missed = warm_hypothesis(
            c.K, c.landmarks_xyz, c.det, kernel_array(self.good, dtype=np.int64), start[:3, :3],
            start[:3, 3], int(w), int(h), float(self.margin_px), float(s.gate_px), float(s.coarse_gate_px),
            int(s.max_iterations), int(s.need), c.prior_R, c.prior_C, c.sigmas,
        )
        pairs = int(np.count_nonzero(a >= 0))
        if not alive or missed > 0 or pairs != self.good.size or pairs <= s.need:
            return None
        T = make_transform(R, t)
        if far:  # a rotation near pi from the prior's: the exact logarithm
            prior_sq = prior_mahalanobis_sq(T, c.prior, s.sigmas)
        if s.max_prior_mahalanobis_sq is not None and prior_sq > s.max_prior_mahalanobis_sq:
            return None
        chi = chi / s.pixel_sigma**2
        if chi > _chi2_quantiles(s.fit_quantile, 2 * pairs - 6)[2 * pairs - 6]:
            return None
        score, _ = self.nll(a[None], T[None], np.array([chi]), np.array([prior_sq]), np.array([missed]))
        return Association(a, T, chi * s.pixel_sigma**2, float(score[0]), 1, None, warm_started=True)

    # ---------------------------------------------------------------- 1. hypotheses

    def search_starts(self, idx: NDArray, proj: NDArray) -> None:
        """Steps 1-2: make the coarse hypotheses and refine them with re-association.

        Every assignment of a small set (``idx``, the prior's candidate landmarks, ``proj`` their
        projections); else the upright two-point poses, the best half first (when they explain
        the detections the rest would only cost time), and the other half with the layout vote
        when those leave the detections poorly explained (:meth:`needs_layout_vote`).
        """
        s = self.settings
        exhaustive = exhaustive_hypotheses(
            self.det, self.good, idx, self.landmarks_xyz, self.K, self.prior, s.need, s.pixel_sigma,
            s.gate_px, s.sigmas, s.exhaustive_limit, min(max(s.max_hypotheses, 1), 3),
        )
        if exhaustive is not None:
            self.voted = True
            self.explore(exhaustive, False)
            return
        upright = self.upright_starts(idx, proj)
        first = max(s.max_hypotheses, 1)
        self.explore(upright[:first], True)
        if self.needs_layout_vote():
            rest = upright[first:]
            self.explore(rest + self.layout_starts(), True, len(rest))
            self.voted = True

    def upright_starts(self, idx: NDArray, proj: NDArray) -> list[Start]:
        """The upright two-point hypotheses (:func:`localization.associate.hypotheses.upright_hypotheses`)."""
        s = self.settings
        return self.complete(upright_hypotheses(
            self.det[self.good], self.landmarks_xyz, idx, proj, self.K, self.prior, s.sigmas,
            s.max_prior_mahalanobis_sq, s.coarse_gate_px, s.need, 5 * s.max_hypotheses, s.batch,
            None if self.log_odds is None else self.log_odds[self.good],
        ))

    def layout_starts(self) -> list[Start]:
        """The layout vote's hypotheses (:func:`localization.associate.hypotheses.layout_hypotheses`)."""
        self.check_time("layout vote")
        s = self.settings
        return self.complete(
            [(a, T) for _, a, T in layout_hypotheses(
                self.det[self.good], self.landmarks_xyz, self.K, self.prior, self.image_size, self.margin_px,
                s.sigmas, s.position_offsets, s.coarse_gate_px, s.shifts_per_layout, s.need,
            )][: 5 * s.max_hypotheses]
        )

    def needs_layout_vote(self) -> bool:
        """Whether the upright hypotheses need the layout vote's help.

        True when there is no final, or the best leaves a quarter of the landmarks it predicts
        in the image unmatched, or more than one (and a tenth) of the detections and at least
        one such landmark (clutter alone leaves detections, not landmarks, unmatched).
        """
        if not self.finals:
            return True
        _, a, _, missed = self.ranked()[0]
        return self.leaves_open(a, missed)

    def leaves_open(self, a: NDArray, missed: int) -> bool:
        """Whether a hypothesis ``a`` that misses ``missed`` predicted landmarks leaves the frame open.

        It leaves a quarter of the landmarks it predicts in the image unmatched, or more than one
        (and a tenth) of the detections and at least one such landmark.
        """
        pairs = int((a >= 0).sum())
        n_good = self.good.size
        unexplained = n_good - pairs > max(1.0, 0.1 * n_good)
        return (unexplained and missed > 0) or missed > 0.25 * (pairs + missed)

    def complete(self, hyps: list[Start]) -> list[Start]:
        """Hypotheses on the finite detections as assignments of all rows, distinct, >= need pairs."""
        out: list[Start] = []
        if not hyps:
            return out
        A = np.full((len(hyps), self.det.shape[0]), -1, dtype=np.int64)
        A[:, self.good] = np.stack([h[0] for h in hyps])
        enough = ((A >= 0).sum(axis=1) >= self.settings.need).tolist()
        seen = set()
        for a, (_, start), ok in zip(A, hyps, enough, strict=True):
            key = a.tobytes()
            if key not in seen and ok:
                seen.add(key)
                out.append((a, start))
        return out

    # ---------------------------------------------------------------- 2. re-association

    def covered(self, coarse: list[Start]) -> NDArray:
        """(C,) whether each hypothesis' pairs all agree with an explored result.

        Such a hypothesis would converge to that result again.
        """
        if not self.explored or not coarse:
            return np.zeros(len(coarse), dtype=bool)
        A = np.stack([c[0] for c in coarse])[:, None, :]
        return np.any(np.all((A < 0) | (A == np.stack(self.explored)[None]), axis=2), axis=1)

    def explore(self, coarse: list[Start], first_robust: bool, extra: int = 0) -> list[Final]:
        """Refine the not yet covered coarse hypotheses at once; keep those that pass the gates.

        At most ``2 * max_hypotheses + extra`` of them (the first not covered). Returns the new
        finals (those also added to :attr:`finals`).
        """
        chunk = [c for c, done in zip(coarse, self.covered(coarse), strict=True) if not done]
        chunk = chunk[: self.settings.batch + extra]
        self.tried += len(chunk)
        if not chunk:
            return []
        self.check_time(f"refinement of {len(chunk)} hypotheses")
        a, T, alive = self.refine(
            np.stack([c[0] for c in chunk]), np.stack([c[1] for c in chunk]), first_robust
        )
        prior_sq, chi, consistent, ok = self.gate(a, T, alive)
        new = []
        for h in np.flatnonzero(alive):
            self.explored.append(a[h])
            key = a[h].tobytes()
            if not consistent[h]:
                self.rejected["prior"] += 1
            elif not ok[h]:
                self.rejected["fit"] += 1
            elif key not in self.finals:
                self.finals[key] = (a[h], T[h], chi[h], prior_sq[h])
                new.append(self.finals[key])
        return new

    def refine(self, a: NDArray, starts: NDArray, first_robust: bool) -> tuple[NDArray, NDArray, NDArray]:
        """Coarse assignments (H, N) and start poses (H, 4, 4) -> (assignments, poses, alive (H,)).

        Each round refines every pose on its pairs (LM; with ``first_robust``, the first round
        with Cauchy weights at ``coarse_gate_px / 4``, as coarse pairs may hold wrong ones, and
        every re-assignment at ``gate_px``; else with a gate that tightens from
        ``coarse_gate_px / 4`` to ``gate_px``), re-projects the landmarks and re-assigns, until
        the assignments are stable. A hypothesis with fewer than ``need`` pairs, or with a point
        behind its camera, dies. Compiled
        (:func:`localization.associate.assign_kernels.refine_reassign`): one loop per hypothesis.
        """
        s, c = self.settings, self.arrays
        w, h = self.image_size
        a, R, t, alive = refine_reassign(
            c.K, c.landmarks_xyz, c.det, kernel_array(self.good, dtype=np.int64),
            kernel_array(a, dtype=np.int64),
            kernel_array(starts[:, :3, :3]), kernel_array(starts[:, :3, 3]),
            int(w), int(h), float(self.margin_px), float(s.gate_px), float(s.coarse_gate_px),
            int(s.max_iterations), int(s.need), bool(first_robust),
        )
        return a, to_transforms(R, t), alive

    # ---------------------------------------------------------------- 3. gates and scoring

    def gate(self, a: NDArray, T: NDArray, alive: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """The gates of refined hypotheses: ``(prior Mahalanobis^2, chi-square, consistent, ok)``.

        ``consistent``: alive and within the prior's Mahalanobis gate; ``ok``: consistent and
        within the fit test, the residuals' chi-square against the noise model (``2 n - 6``
        dof): every pair within the inlier gate is not enough -- four wrong pairs at 3 px RMS
        each pass a 5 px gate.
        """
        s = self.settings
        prior_sq, chi = self.prior_and_fit(a, T)
        dof = 2 * (a >= 0).sum(axis=1) - 6
        consistent = alive & (
            prior_sq <= s.max_prior_mahalanobis_sq if s.max_prior_mahalanobis_sq is not None else True
        )
        limit = np.where(dof > 0, _chi2_quantiles(s.fit_quantile, int(dof.max()))[np.maximum(dof, 0)], np.inf)
        return prior_sq, chi, consistent, consistent & (chi <= limit)

    def prior_and_fit(self, a: NDArray, T: NDArray) -> tuple[NDArray, NDArray]:
        """(H,) prior Mahalanobis^2 and (H,) chi-square of hypotheses (H, N) at poses (H, 4, 4).

        The squared Mahalanobis distance of each pose from the prior, and the sum of squared
        residuals of its pairs over ``pixel_sigma^2``; compiled
        (:func:`localization.associate.hypothesis_kernels.check_many`).
        """
        c = self.arrays
        R, t = kernel_array(T[:, :3, :3]), kernel_array(T[:, :3, 3])
        prior_sq, chi, far = check_many(
            c.K, c.landmarks_xyz, c.det, kernel_array(a, dtype=np.int64), R, t,
            c.prior_R, c.prior_C, c.sigmas,
        )
        for h in np.flatnonzero(far):  # rotations near pi from the prior's: the exact logarithm
            prior_sq[h] = prior_mahalanobis_sq(T[h], c.prior, self.settings.sigmas)
        return prior_sq, chi / self.settings.pixel_sigma**2

    def missed(self, a: NDArray, T: NDArray) -> NDArray:
        """(H,) landmarks each hypothesis (H, N) at its pose (H, 4, 4) predicts in the image, unmatched."""
        c = self.arrays
        w, h = self.image_size
        return missed_many(
            c.K, c.landmarks_xyz, kernel_array(a, dtype=np.int64),
            kernel_array(T[:, :3, :3]), kernel_array(T[:, :3, 3]), int(w), int(h),
        )

    def nll(
        self, a: NDArray, T: NDArray, chi: NDArray, prior_sq: NDArray, n_missed: NDArray | None = None
    ) -> tuple[NDArray, NDArray]:
        """(H,) negative log-likelihoods (inliers, clutter, misses, prior) and (H,) miss counts.

        ``n_missed``: the miss counts when already known (else counted here).
        """
        s = self.settings
        if n_missed is None:
            n_missed = self.missed(a, T)
        n_unassigned = (a < 0).sum(axis=1)
        nll = chi + n_unassigned * (s.gate_px / s.pixel_sigma) ** 2 + n_missed * s.miss_cost + prior_sq
        if self.log_odds is not None:
            nll = nll - (a >= 0) @ self.log_odds
        return nll, n_missed

    def score(self, hyps: list[Final]) -> list[Scored]:
        """Finals scored by :meth:`nll`, in their order."""
        a = np.stack([h[0] for h in hyps])
        T = np.stack([h[1] for h in hyps])
        nll, missed = self.nll(a, T, np.array([h[2] for h in hyps]), np.array([h[3] for h in hyps]))
        return [(float(nll[i]), a[i], T[i], int(missed[i])) for i in range(len(hyps))]

    def ranked(self) -> list[Scored]:
        """The finals scored, best first (scored again only when finals changed)."""
        if len(self.finals) not in self._ranked:
            self._ranked.clear()
            scored = self.score(list(self.finals.values()))
            self._ranked[len(self.finals)] = sorted(scored, key=lambda h: h[0])
        return self._ranked[len(self.finals)]

    def no_final_failure(self) -> Association:
        """The failure when no hypothesis passed the gates, named by the gate that stopped them."""
        s, rejected = self.settings, self.rejected
        if rejected["fit"] and not rejected["prior"]:
            code = FailureCode.NO_CONSISTENT_ASSOCIATION
            reason = (
                f"all {rejected['fit']} association hypotheses fit worse than pixel_sigma="
                f"{s.pixel_sigma:g} px allows (chi-square quantile {s.fit_quantile})"
            )
        elif rejected["prior"]:
            code = FailureCode.INCONSISTENT_WITH_PRIOR
            reason = (
                f"all {rejected['prior']} association hypotheses give poses inconsistent with "
                f"the prior (Mahalanobis^2 > {s.max_prior_mahalanobis_sq})"
            )
        else:
            code = FailureCode.NO_CONSISTENT_ASSOCIATION
            reason = f"no association hypothesis with {s.need} or more consistent correspondences"
        return Association(self.unassigned(), self.prior, 0.0, np.inf, self.tried, reason, code)

    # ---------------------------------------------------------------- 4. rivals and ambiguity

    def rival_search(self) -> tuple[list[Scored], str | None]:
        """Score the finals, search the winner's rivals, apply the ambiguity rule.

        Each round refines the winner's rivals (:meth:`rivals`) and swaps (:meth:`swaps`); a
        rival that wins gets its own round. Returns the scored finals, best first, and why the
        winner is ambiguous (:func:`localization.associate.ambiguity.ambiguity`), or None.
        """
        s = self.settings
        scored = self.ranked()
        for _ in range(s.max_rival_rounds):
            self.check_time("rival search")
            _, best_a, best_T, best_missed = scored[0]
            chunk = self.rivals(best_a, best_T)
            swapped = self.swaps(best_a, best_T) + self.regrown(best_a, best_T, best_missed)
            new = self.explore(swapped + chunk, True, len(swapped))
            if not new:
                break
            scored = sorted(scored + self.score(new), key=lambda h: h[0])
            if scored[0][1] is best_a:
                break
        return scored, ambiguity(
            [h[:3] for h in scored], self.landmarks_xyz, self.K, s.pixel_sigma, s.ambiguity_margin
        )

    def rivals(self, a: NDArray, T: NDArray) -> list[Start]:
        """The winner ``a`` at pose ``T`` moved by the layout's self-translations, as coarse hypotheses.

        Each moved pose (:func:`localization.associate.ambiguity.translation_hypotheses`) gives
        the coarse-gated assignment of its projections; those with ``need`` pairs or more.
        """
        s = self.settings
        rivals = translation_hypotheses(
            self.det, self.landmarks_xyz, self.K, T, a, self.prior, s.sigmas.as_array()[:3],
            s.max_prior_mahalanobis_sq, s.coarse_gate_px, s.need, s.max_rivals,
        )
        chunk = []
        for idx_r, proj_r, start in rivals:
            local = assign(self.det[self.good], proj_r, s.coarse_gate_px)
            b = np.full(self.det.shape[0], -1, dtype=np.int64)
            b[self.good[local >= 0]] = idx_r[local[local >= 0]]
            chunk.append((b, start))
        return [c for c in chunk if (c[0] >= 0).sum() >= s.need]

    def swaps(self, a: NDArray, T: NDArray) -> list[Start]:
        """The winner with one pair's detection swapped for an unassigned one near its landmark.

        Every unassigned detection within ``coarse_gate_px`` of an assigned landmark's
        projection at the winner's pose replaces that landmark's detection (nearest first, at
        most ``2 * max_hypotheses``). A wrong pair that the pose absorbed hides the right
        detection outside the inlier gate -- with four corners and a scaffold post 20 px from
        one of them, the post can win a fit the corner would have won -- and neither the
        starts nor the rivals (whole-layout moves) revisit one pair.
        """
        s = self.settings
        free = self.good[a[self.good] < 0]
        pairs = np.flatnonzero(a >= 0)
        if free.size == 0 or pairs.size == 0:
            return []
        uv, _ = project(self.K, T, self.landmarks_xyz[a[pairs]])
        d = np.hypot(*(self.det[free][None, :, :] - uv[:, None, :]).transpose(2, 0, 1))
        rows, cols = np.nonzero(d <= s.coarse_gate_px)
        out = []
        for k in np.argsort(d[rows, cols], kind="stable")[: s.batch]:
            b = a.copy()
            b[free[cols[k]]] = a[pairs[rows[k]]]
            b[pairs[rows[k]]] = -1
            out.append((b, T))
        return out

    def regrown(self, a: NDArray, T: NDArray, missed: int) -> list[Start]:
        """The winner ``a`` at ``T`` grown again from its pairs two at a time, if it leaves the frame open.

        :func:`localization.associate.hypotheses.regrowth_hypotheses` with the candidate landmarks
        at ``T``, when the winner (missing ``missed`` of the landmarks it predicts) leaves the
        frame open (:meth:`leaves_open`): a winner refined from a start with most of its pairs
        wrong settles on a dozen right pairs and a few wrong ones, metres from the pose that two
        of its right pairs give and every landmark in view confirms.
        """
        if not self.leaves_open(a, missed):
            return []
        s = self.settings
        local = a[self.good]
        rows = np.flatnonzero(local >= 0)
        idx, _ = candidate_landmarks(self.landmarks_xyz, self.K, T, self.image_size, self.margin_px)
        return self.complete(regrowth_hypotheses(
            self.det[self.good], np.column_stack([rows, local[rows]]), self.landmarks_xyz, idx, self.K, T,
            self.prior, s.sigmas, s.coarse_gate_px, s.need, 5 * s.max_hypotheses, s.batch,
        ))

    # ---------------------------------------------------------------- 5. the winner

    def conclude(self, best: Scored) -> Association:
        """The winner's association: its minimum-cost assignment, unless a minimal fit.

        The batched assignment pairs mutual nearest neighbours; two landmarks projecting within a
        gate of each other can be swapped there, so the winner gets the minimum-cost assignment
        (:meth:`exact_assignment`, refined when it differs).
        """
        s = self.settings
        score_best, a, T, _ = best
        exact = self.exact_assignment(T)
        if not np.array_equal(exact, a) and (exact >= 0).sum() >= s.need:
            a = exact
            T, _ = refine_pose(self.landmarks_xyz[a[a >= 0]], self.det[a >= 0], self.K, T, max_iterations=10)
        m = a >= 0
        reason = self.minimal_fit_reason(a, T)
        if reason is not None:
            return Association(
                self.unassigned(), self.prior, 0.0, np.inf, len(self.finals), reason,
                FailureCode.NO_CONSISTENT_ASSOCIATION,
            )
        res, _ = reprojection_residuals(self.K, T, self.landmarks_xyz[a[m]], self.det[m])
        return Association(a, T, float(np.sum(res**2)), float(score_best), len(self.finals), None)

    def exact_assignment(self, T: NDArray) -> NDArray[np.int64]:
        """(N,) the minimum-cost assignment at pose ``T`` within the inlier gate (-1: unassigned)."""
        cidx, cproj = candidate_landmarks(self.landmarks_xyz, self.K, T, self.image_size, self.margin_px)
        local = assign(self.det[self.good], cproj, self.settings.gate_px)
        exact = self.unassigned()
        exact[self.good[local >= 0]] = cidx[local[local >= 0]]
        return exact

    def minimal_fit_reason(self, a: NDArray, T: NDArray) -> str | None:
        """Why the winner ``a`` at pose ``T`` is a coincidence rather than a pose, or None.

        A hypothesis with no more pairs than the minimum (``need``: four pairs leave the fit test
        two degrees of freedom) that leaves at least as many landmarks unmatched as it pairs, of
        those it projects inside the image, explains at most half of its own prediction. Wrong
        detections form such fits: among enough of them, some four fit some pose near the prior
        (the duplex IFC building's eight slab corners, which the default weights barely detect:
        12 of their 13 wrong poses, 2-6.5 m off, had four pairs and four more corners predicted
        and unmatched). A right pose of that kind needs half of the landmarks it should see
        hidden or undetected; it fails too, for ``NO_CONSISTENT_ASSOCIATION`` is the honest
        answer when the image cannot tell the two apart.
        """
        pairs = int((a >= 0).sum())
        if pairs > self.settings.need:
            return None
        missed = int(self.missed(a[None], T[None])[0])
        if missed < pairs:
            return None
        return (
            f"the best association pairs only {pairs} detections (the minimum) and leaves {missed} of the "
            f"{pairs + missed} landmarks its pose projects into the image unmatched: a minimal fit that "
            "explains at most half of what it predicts is as likely a coincidence of wrong detections"
        )


def associate_robust(
    detections_uv: NDArray[np.float64],
    landmarks_xyz: NDArray[np.float64],
    K: NDArray[np.float64],
    prior_cam_from_world: NDArray[np.float64],
    image_size: tuple[int, int],
    margin_px: float,
    *,
    pixel_sigma: float = 1.0,
    gate_px: float | None = None,
    coarse_gate_px: float = 40.0,
    max_hypotheses: int = 8,
    max_iterations: int = 6,
    min_correspondences: int = 4,
    miss_cost: float = 4.0,
    prior_sigmas: PriorSigmas | None = None,
    max_prior_mahalanobis_sq: float | None = 22.46,
    position_offsets: tuple[tuple[float, float, float], ...] = GRID_OFFSETS,
    shifts_per_layout: int = 2,
    exhaustive_limit: int = 150,
    max_rivals: int = 6,
    max_rival_rounds: int = 2,
    ambiguity_margin: float = AMBIGUITY_MARGIN,
    fit_quantile: float = 1.0 - 1e-6,
    detection_scores: NDArray[np.float64] | None = None,
    warm_start: NDArray[np.float64] | None = None,
    deadline: Deadline | None = None,
) -> Association:
    """Robust association: upright two-point hypotheses, batched re-association, likelihood scoring.

    Resolves the settings (:meth:`RobustSettings.resolve`) and runs one :class:`RobustSearch`
    (the module docstring describes the method).

    Args:
        detections_uv: (N, 2) detections (validated; NaN rows stay unassigned).
        landmarks_xyz: (M, 3) model landmarks.
        K: (3, 3) intrinsics.
        prior_cam_from_world: (4, 4) rough pose.
        image_size: (W, H).
        margin_px: how far outside the image a projection may fall and remain a candidate.
        pixel_sigma: detector noise, px.
        gate_px: final inlier gate, px; default ``max(5 * pixel_sigma, 3)``.
        coarse_gate_px: gate of the first assignment of each shift hypothesis, px; never below
            the prior's smallest rotation sigma seen through the lens (``f * min(sigma_rot)``,
            38.7 px for the paper's camera and default sigmas, 310 px at f = 8900 px).
        max_hypotheses: twice this many distinct coarse assignments of each source (upright
            poses, then the layout vote if needed) are refined and re-associated in one batch
            (those agreeing with an already refined result are skipped); of the upright ones,
            the best half first, the other half only with the layout vote.
        max_iterations: PnP / re-association rounds per hypothesis.
        min_correspondences: a hypothesis needs this many pairs to be turned into a pose.
        miss_cost: cost of a landmark predicted inside the image but not detected (about
            ``-2 log`` of the miss odds).
        prior_sigmas: prior uncertainty (default: 3 m, 2/2/5 degrees).
        max_prior_mahalanobis_sq: hypotheses whose pose is farther from the prior than this
            (squared Mahalanobis distance, 6 dof; default the chi-square 99.9 % quantile 22.46)
            are rejected; None keeps all.
        position_offsets: offsets of the prior camera centre (in units of the prior's position
            sigmas, project axes) that generate the layout vote's hypotheses (used when the
            upright hypotheses leave the detections poorly explained); default the 27-point
            grid ``{-1, 0, 1}^3``.
        shifts_per_layout: best-voted image shifts tried per layout (besides no shift).
        exhaustive_limit: when the number of largest one-to-one assignments between the finite
            detections and the candidate landmarks is at most this, all of them are tried
            (small sets such as four corners) instead of the layout vote.
        max_rivals: most rivals of the winner refined per round (its pose moved by the layout's
            self-translations, :func:`localization.associate.ambiguity.translation_hypotheses`).
        max_rival_rounds: rounds of the rival search (a rival that wins gets its own rivals).
        ambiguity_margin: a rival with conflicting identities, a distinct pose and a score within
            this of the winner's makes the association fail as ``AMBIGUOUS``
            (:func:`localization.associate.ambiguity.ambiguity`).
        fit_quantile: a hypothesis whose inlier residuals exceed this chi-square quantile
            (``2 n - 6`` dof, ``pixel_sigma``) is rejected: it does not fit the noise model. The
            default rejects one correct pose in a million (0.999 would reject one of the
            benchmark's 200 column-top views, chi-square 42.9 on 18 dof).
        detection_scores: (N,) probability in [0, 1] that each detection is a landmark (the
            learned detector's scores), or None; they enter the scoring as log-odds (module
            docstring, step 3). Not validated here (:meth:`Localizer.localize` does).
        warm_start: (4, 4) a predicted ``cam_from_world`` for this frame, or None: tried before
            any hypothesis and accepted only when it explains the whole frame (module docstring,
            *Warm start*); else the full search runs. Not validated here.
        deadline: the call's :class:`localization.budget.Deadline`, or None: checked before each
            step of the search (each batch refined, the layout vote, each rival round); past it
            the association fails as ``TIMED_OUT``.
    """
    settings = RobustSettings.resolve(
        K,
        pixel_sigma=pixel_sigma,
        gate_px=gate_px,
        coarse_gate_px=coarse_gate_px,
        min_correspondences=min_correspondences,
        prior_sigmas=prior_sigmas,
        max_hypotheses=max_hypotheses,
        max_iterations=max_iterations,
        miss_cost=miss_cost,
        max_prior_mahalanobis_sq=max_prior_mahalanobis_sq,
        position_offsets=position_offsets,
        shifts_per_layout=shifts_per_layout,
        exhaustive_limit=exhaustive_limit,
        max_rivals=max_rivals,
        max_rival_rounds=max_rival_rounds,
        ambiguity_margin=ambiguity_margin,
        fit_quantile=fit_quantile,
    )
    search = RobustSearch(
        detections_uv, landmarks_xyz, K, prior_cam_from_world, image_size, margin_px, settings,
        detection_scores, deadline,
    )
    return search.run(warm_start)


def _log_odds(scores: NDArray | None) -> NDArray | None:
    """``2 log(s / (1 - s))`` of scores clipped to [0.01, 0.99] (NaN: 0), or None."""
    if scores is None:
        return None
    s = np.clip(np.nan_to_num(np.asarray(scores, dtype=np.float64), nan=0.5), 0.01, 0.99)
    return 2.0 * np.log(s / (1.0 - s))


@functools.lru_cache(maxsize=64)
def _chi2_quantiles(quantile: float, max_dof: int) -> NDArray[np.float64]:
    """Chi-square ``quantile`` for 0 .. ``max_dof`` degrees of freedom (inf at 0), cached."""
    return np.concatenate([[np.inf], chi2_quantile(quantile, np.arange(1, max(max_dof, 1) + 1))])
