"""Stage 2, association: anonymous detections + BIM landmarks + rough prior pose -> identities.

Two methods:

``paper`` (:func:`associate_paper`)
    The paper's method: project the BIM landmarks with the prior pose, keep those in front of the
    camera and near the image, and solve the rectangular minimum-cost one-to-one assignment on
    squared pixel distance (``scipy.optimize.linear_sum_assignment``, Crouse 2016). Every detection
    is assigned whenever there are at least as many projected landmarks; nothing is gated.

``robust`` (:func:`associate_robust`)
    Goes beyond it for a detector that misses landmarks and reports clutter and a prior that is off
    by metres and degrees:

    1. *Hypotheses.* An onboard attitude sensor knows the camera's tilt far better than its yaw
       and position; with the prior's tilt, two correspondences fix the pose in closed form
       (:mod:`localization.associate.upright`). Four spread-out detections of the dense part of the image
       give six anchor pairs (with detection scores, the four likeliest detections give up to six
       more: a dense cluster of clutter would otherwise hold every anchor); every ordered pair of
       candidate landmarks whose prior image is within a factor 3 in length and 45 degrees in
       direction of an anchor pair's gives a pose;
       poses beyond the prior's Mahalanobis gate are dropped, and the rest are ranked by the
       detections they explain within the coarse gate (then by the capped squared distances).
       The best distinct ones each give a gated assignment. When the best refined hypothesis
       leaves a quarter of the landmarks it predicts in the image unmatched, or more than one
       (and a tenth) of the detections and some such landmark (or is ambiguous), the layout
       vote adds its
       hypotheses: the prior camera centre moved on the grid {-1, 0, +1 sigma}^3, and for each,
       every (detection, projected landmark) pair proposes a 2D shift ranked by how many other
       pairs agree with it (a Hough vote). Small problems (a slab's four corners) enumerate
       every one-to-one assignment instead.
    2. *Re-association.* Each hypothesis is refined from its start pose (Levenberg-Marquardt
       with Cauchy weights first, as coarse pairs may hold wrong ones), the landmarks are
       re-projected with that pose and re-assigned with the inlier gate ``gate_px`` (enumerated
       assignments, whose starts fit their pairs exactly, with a gate tightening from
       ``coarse_gate_px / 4``), until the assignment is stable. All hypotheses go through these steps together
       (:mod:`localization.pose.batch`): one set of numpy calls per step, not one per hypothesis.
    3. *Scoring.* Each final hypothesis is scored by a negative log-likelihood: squared residuals
       of the inliers over ``pixel_sigma^2``, a fixed cost per unassigned detection (clutter) and
       per landmark predicted inside the image but not detected (miss), plus the squared
       Mahalanobis distance of the pose from the prior (sigmas 3 m, 2/2/5 degrees by default).
       The prior term is what decides between assignments that fit equally well, such as the
       permutations of four coplanar corners. With detection scores (probabilities that each
       detection is a landmark, as the learned detector's refiner gives) each assigned detection
       also adds ``-2 log(s / (1 - s))`` (the log-odds of landmark against clutter; ``s`` clipped to
       [0.01, 0.99]): of two detections a landmark fits about alike, the likelier one is
       assigned -- a corner 0.4 px from its projection with score 0.72 rather than a scaffold
       post 20 px away with score 0.10, which four points alone cannot tell apart. A hypothesis
       whose pose is farther from the prior than the Mahalanobis gate, or whose inlier
       residuals fail a chi-square test against ``pixel_sigma`` (``1 - 1e-6`` quantile,
       ``2 n - 6`` dof), is dropped.
    4. *Rivals and ambiguity* (:mod:`localization.associate.ambiguity`). The winner's pose moved by the
       layout's self-translations gives rival hypotheses, refined and scored the same way; a
       rival with conflicting identities and a distinct pose within ``2 ln 100`` of the best
       score makes the association fail as ``ambiguous`` instead of guessing. Each round also
       tries the winner with one pair's detection swapped for an unassigned detection near that
       landmark's projection (a wrong pair the pose absorbed hides the right detection outside
       the inlier gate).
    5. *Minimal fits.* A winner with no more pairs than the minimum that leaves at least as many
       landmarks unmatched as it pairs, of those its pose projects into the image, fails as
       ``no_consistent_association``: four pairs leave the fit test two degrees of freedom, and
       among enough wrong detections some four fit some pose near the prior.

    Gating means a detection (clutter) or a landmark (miss, occlusion) may stay unassigned.

    *Warm start* (``warm_start``: a predicted pose, e.g. the previous frame's estimate moved by
    the commanded motion). Before any hypothesis, the landmarks are projected with the predicted
    pose, paired (mutual nearest neighbours) within ``coarse_gate_px / 4`` and refined with
    re-association as in step 2.
    The result is accepted without a search only when it explains the whole frame: every finite
    detection paired, every landmark its pose projects inside the image detected, the pose
    within the prior's Mahalanobis gate, the residuals within the fit test, and more pairs than
    the minimum. Anything less (a new landmark entering the view, clutter, a miss, a prediction
    that has drifted) runs the full search above. What it accepts passes the search's own tests;
    the rivals of step 4 are not searched, though: the prediction carries the previous frame's
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
from scipy.stats import chi2

from localization.associate.ambiguity import AMBIGUITY_MARGIN, ambiguity, translation_hypotheses
from localization.associate.assign_kernels import refine_reassign
from localization.associate.hypotheses import exhaustive_hypotheses, layout_hypotheses, upright_hypotheses
from localization.associate.hypothesis_kernels import check_many, missed_many, warm_hypothesis
from localization.associate.paper import Association, assign, candidate_landmarks, no_candidates
from localization.failure import FailureCode
from localization.geometry.transforms import camera_center, make_transform, project
from localization.pose.batch import to_transforms
from localization.pose.covariance import PriorSigmas, prior_mahalanobis_sq
from localization.pose.pnp import refine_pose, reprojection_residuals

__all__ = ["associate_robust"]


#: Prior-centre perturbations (units of the position sigmas): the 3 x 3 x 3 grid {-1, 0, 1}^3,
#: nearest first. (The paper's protocol puts the prior error exactly on a grid corner; the
#: benchmark also reports Gaussian prior errors to show the search does not rely on that.)
GRID_OFFSETS = tuple(
    sorted(itertools.product((-1.0, 0.0, 1.0), repeat=3), key=lambda o: sum(x * x for x in o))
)


@dataclass(frozen=True)
class _Problem:
    """The fixed inputs of one robust association, shared by its batched steps."""

    det: NDArray
    good: NDArray
    landmarks_xyz: NDArray
    K: NDArray
    prior: NDArray
    image_size: tuple[int, int]
    margin_px: float
    pixel_sigma: float
    sig: PriorSigmas
    gate_px: float
    coarse_gate_px: float
    max_iterations: int
    need: int
    #: (N,) ``2 log(s / (1 - s))`` of each detection's score (the scoring's reward for assigning
    #: it), or None without scores.
    log_odds: NDArray | None = None

    @functools.cached_property
    def prior_R(self) -> NDArray:
        """(3, 3) the prior's rotation, contiguous (the compiled checks take it)."""
        return np.ascontiguousarray(self.prior[:3, :3])

    @functools.cached_property
    def prior_C(self) -> NDArray:
        """(3,) the prior's camera centre."""
        return camera_center(self.prior)

    @functools.cached_property
    def sig_array(self) -> NDArray:
        """(6,) the prior's sigmas (position m, rotation rad)."""
        return self.sig.as_array()

    def refine(self, a: NDArray, starts: NDArray, first_robust: bool) -> tuple[NDArray, NDArray, NDArray]:
        """Coarse assignments (H, N) and start poses (H, 4, 4) -> (assignments, poses, alive (H,)).

        Each round refines every pose on its pairs (LM; with ``first_robust``, the first round
        with Cauchy weights at ``coarse_gate_px / 4``, as coarse pairs may hold wrong ones, and
        every re-assignment at ``gate_px``; else with a gate that tightens from
        ``coarse_gate_px / 4`` to ``gate_px``), re-projects the landmarks and re-assigns, until
        the assignments are stable. A hypothesis
        with fewer than ``need`` pairs, or with a point behind its camera, dies. Compiled
        (:func:`localization.associate.assign_kernels.refine_reassign`): one loop per hypothesis.
        """
        w, h = self.image_size
        a, R, t, alive = refine_reassign(
            self.K, self.landmarks_xyz, self.det, np.ascontiguousarray(self.good, dtype=np.int64),
            np.ascontiguousarray(a, dtype=np.int64),
            np.ascontiguousarray(starts[:, :3, :3]), np.ascontiguousarray(starts[:, :3, 3]),
            int(w), int(h), float(self.margin_px), float(self.gate_px), float(self.coarse_gate_px),
            int(self.max_iterations), int(self.need), bool(first_robust),
        )
        return a, to_transforms(R, t), alive

    def checks(self, a: NDArray, T: NDArray) -> tuple[NDArray, NDArray]:
        """(H,) prior Mahalanobis^2 and (H,) chi-square of hypotheses (H, N) at poses (H, 4, 4).

        The squared Mahalanobis distance of each pose from the prior, and the sum of squared
        residuals of its pairs over ``pixel_sigma^2``; compiled
        (:func:`localization.associate.hypothesis_kernels.check_many`).
        """
        R, t = np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])
        prior_sq, chi, far = check_many(
            self.K, self.landmarks_xyz, self.det, np.ascontiguousarray(a, dtype=np.int64), R, t,
            self.prior_R, self.prior_C, self.sig_array,
        )
        for h in np.flatnonzero(far):  # rotations near pi from the prior's: the exact logarithm
            prior_sq[h] = prior_mahalanobis_sq(T[h], self.prior, self.sig)
        return prior_sq, chi / self.pixel_sigma**2

    def nll(
        self, a: NDArray, T: NDArray, chi: NDArray, prior_sq: NDArray, miss_cost: float,
        n_missed: NDArray | None = None,
    ) -> tuple[NDArray, NDArray]:
        """(H,) negative log-likelihoods (inliers, clutter, misses, prior) and (H,) miss counts.

        ``n_missed``: the miss counts when already known (else counted here).
        """
        if n_missed is None:
            w, h = self.image_size
            n_missed = missed_many(
                self.K, self.landmarks_xyz, np.ascontiguousarray(a, dtype=np.int64),
                np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3]), int(w), int(h),
            )
        n_unassigned = (a < 0).sum(axis=1)
        nll = chi + n_unassigned * (self.gate_px / self.pixel_sigma) ** 2 + n_missed * miss_cost + prior_sq
        if self.log_odds is not None:
            nll = nll - (a >= 0) @ self.log_odds
        return nll, n_missed


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
) -> Association:
    """Robust association: upright two-point hypotheses, batched re-association, likelihood scoring.

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
            default rejects one correct pose in a million (0.999 lost one of the benchmark's
            200 column-top views, chi-square 42.9 on 18 dof).
        detection_scores: (N,) probability in [0, 1] that each detection is a landmark (the
            learned detector's scores), or None; they enter the scoring as log-odds (module
            docstring, step 3). Not validated here (:meth:`Localizer.localize` does).
        warm_start: (4, 4) a predicted ``cam_from_world`` for this frame, or None: tried before
            any hypothesis and accepted only when it explains the whole frame (module docstring,
            *Warm start*); else the full search runs. Not validated here.
    """
    sig = prior_sigmas or PriorSigmas()
    gate = float(gate_px) if gate_px is not None else max(5.0 * pixel_sigma, 3.0)
    # The prior's attitude error is an angle: through a long lens it moves the projections by
    # hundreds of pixels, and a gate fixed in pixels would then match only coincidences.
    coarse_gate_px = max(coarse_gate_px, min(K[0, 0], K[1, 1]) * min(sig.rotation_rad))
    n = detections_uv.shape[0]
    prior = prior_cam_from_world
    good = np.flatnonzero(np.isfinite(detections_uv).all(axis=1))
    if good.size == 0:
        return Association(
            np.full(n, -1, dtype=np.int64), prior, 0.0, np.inf, 0, "no finite detection",
            FailureCode.TOO_FEW_DETECTIONS,
        )
    det = detections_uv
    need = max(min_correspondences, 3)
    f64 = np.float64
    P = _Problem(  # contiguous float64 once: the compiled steps take them as they are
        np.ascontiguousarray(det, dtype=f64), good, np.ascontiguousarray(landmarks_xyz, dtype=f64),
        np.ascontiguousarray(K, dtype=f64), np.ascontiguousarray(prior, dtype=f64), image_size, margin_px,
        pixel_sigma, sig, gate, coarse_gate_px, max_iterations, need, _log_odds(detection_scores),
    )

    if warm_start is not None:
        warm = _warm_association(P, warm_start, max_prior_mahalanobis_sq, fit_quantile, miss_cost)
        if warm is not None:
            return warm
    empty = np.full(n, -1, dtype=np.int64)  # the failures' assignment
    # the prior's candidates (only a search needs them: an accepted warm start returns first)
    idx, proj = candidate_landmarks(landmarks_xyz, K, prior, image_size, margin_px)
    if idx.size == 0:
        return no_candidates(empty, prior, np.inf, 0)

    def covered(coarse: list[tuple[NDArray, NDArray]]) -> NDArray:
        """(C,) whether each hypothesis' pairs all agree with an explored result.

        Such a hypothesis would converge to that result again.
        """
        if not explored or not coarse:
            return np.zeros(len(coarse), dtype=bool)
        A = np.stack([c[0] for c in coarse])[:, None, :]
        return np.any(np.all((A < 0) | (A == np.stack(explored)[None]), axis=2), axis=1)

    def check(a: NDArray, T: NDArray, alive: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
        """(prior Mahalanobis^2, chi-square, consistent, consistent & fits) of refined hypotheses."""
        prior_sq, chi = P.checks(a, T)
        dof = 2 * (a >= 0).sum(axis=1) - 6
        consistent = alive & (
            prior_sq <= max_prior_mahalanobis_sq if max_prior_mahalanobis_sq is not None else True
        )
        # The residuals' chi-square against the noise model (2n - 6 dof): every pair within
        # the gate is not enough -- four wrong pairs at 3 px RMS each pass a 5 px gate.
        limit = np.where(dof > 0, _chi2_quantiles(fit_quantile, int(dof.max()))[np.maximum(dof, 0)], np.inf)
        return prior_sq, chi, consistent, consistent & (chi <= limit)

    finals: dict[bytes, tuple[NDArray, NDArray, float, float]] = {}
    rejected = {"prior": 0, "fit": 0}
    explored: list[NDArray] = []
    tried = [0]

    def explore(coarse: list[tuple[NDArray, NDArray]], first_robust: bool, extra: int = 0) -> list[tuple]:
        """Refine the not yet covered coarse hypotheses at once; keep those that pass the tests.

        At most ``2 * max_hypotheses + extra`` of them (the first not covered).
        """
        chunk = [c for c, done in zip(coarse, covered(coarse), strict=True) if not done]
        chunk = chunk[: 2 * max(max_hypotheses, 1) + extra]
        tried[0] += len(chunk)
        if not chunk:
            return []
        a, T, alive = P.refine(np.stack([c[0] for c in chunk]), np.stack([c[1] for c in chunk]), first_robust)
        prior_sq, chi, consistent, ok = check(a, T, alive)
        new = []
        for h in np.flatnonzero(alive):
            explored.append(a[h])
            key = a[h].tobytes()
            if not consistent[h]:
                rejected["prior"] += 1
            elif not ok[h]:
                rejected["fit"] += 1
            elif key not in finals:
                finals[key] = (a[h], T[h], chi[h], prior_sq[h])
                new.append(finals[key])
        return new

    def full(hyps: list[tuple[NDArray, NDArray]]) -> list[tuple[NDArray, NDArray]]:
        """Hypotheses on the finite detections as assignments of all rows, distinct, >= need pairs."""
        out: list[tuple[NDArray, NDArray]] = []
        if not hyps:
            return out
        A = np.full((len(hyps), n), -1, dtype=np.int64)
        A[:, good] = np.stack([h[0] for h in hyps])
        enough = ((A >= 0).sum(axis=1) >= need).tolist()
        seen = set()
        for a, (_, start), ok in zip(A, hyps, enough, strict=True):
            key = a.tobytes()
            if key not in seen and ok:
                seen.add(key)
                out.append((a, start))
        return out

    def score(hyps: list[tuple]) -> list[tuple[float, NDArray, NDArray, int]]:
        a = np.stack([h[0] for h in hyps])
        T = np.stack([h[1] for h in hyps])
        s, missed = P.nll(a, T, np.array([h[2] for h in hyps]), np.array([h[3] for h in hyps]), miss_cost)
        return [(float(s[i]), a[i], T[i], int(missed[i])) for i in range(len(hyps))]

    def decide() -> tuple[list[tuple], str | None]:
        """Score the finals, search the winner's rivals, apply the ambiguity rule."""
        scored = ranked()
        for _ in range(max_rival_rounds):
            best_a, best_T = scored[0][1], scored[0][2]
            rivals = translation_hypotheses(
                det, landmarks_xyz, K, best_T, best_a, prior, sig.as_array()[:3],
                max_prior_mahalanobis_sq, coarse_gate_px, need, max_rivals,
            )
            chunk = []
            for idx_r, proj_r, start in rivals:
                local = assign(det[good], proj_r, coarse_gate_px)
                a = np.full(n, -1, dtype=np.int64)
                a[good[local >= 0]] = idx_r[local[local >= 0]]
                chunk.append((a, start))
            chunk = [c for c in chunk if (c[0] >= 0).sum() >= need]
            swapped = swaps(best_a, best_T)
            new = explore(swapped + chunk, True, len(swapped))
            if not new:
                break
            scored = sorted(scored + score(new), key=lambda h: h[0])
            if scored[0][1] is best_a:
                break
        return scored, ambiguity([h[:3] for h in scored], landmarks_xyz, K, pixel_sigma, ambiguity_margin)

    def swaps(a: NDArray, T: NDArray) -> list[tuple[NDArray, NDArray]]:
        """The winner with one pair's detection swapped for an unassigned one near its landmark.

        Every unassigned detection within ``coarse_gate_px`` of an assigned landmark's
        projection at the winner's pose replaces that landmark's detection (nearest first, at
        most ``2 * max_hypotheses``). A wrong pair that the pose absorbed hides the right
        detection outside the inlier gate -- with four corners and a scaffold post 20 px from
        one of them, the post can win a fit the corner would have won -- and neither the
        starts nor the rivals (whole-layout moves) revisit one pair.
        """
        free = good[a[good] < 0]
        pairs = np.flatnonzero(a >= 0)
        if free.size == 0 or pairs.size == 0:
            return []
        uv, _ = project(K, T, landmarks_xyz[a[pairs]])
        d = np.hypot(*(det[free][None, :, :] - uv[:, None, :]).transpose(2, 0, 1))
        rows, cols = np.nonzero(d <= coarse_gate_px)
        out = []
        for k in np.argsort(d[rows, cols], kind="stable")[: 2 * max(max_hypotheses, 1)]:
            b = a.copy()
            b[free[cols[k]]] = a[pairs[rows[k]]]
            b[pairs[rows[k]]] = -1
            out.append((b, T))
        return out

    cache: dict[int, list[tuple]] = {}

    def ranked() -> list[tuple]:
        """The finals scored, best first (scored again only when finals changed)."""
        if len(finals) not in cache:
            cache.clear()
            cache[len(finals)] = sorted(score(list(finals.values())), key=lambda h: h[0])
        return cache[len(finals)]

    def weak() -> bool:
        """Whether the upright hypotheses need the layout vote's help.

        True when there is no final, or the best leaves a quarter of the landmarks it predicts
        in the image unmatched, or more than one (and a tenth) of the detections and at least
        one such landmark (clutter alone leaves detections, not landmarks, unmatched).
        """
        if not finals:
            return True
        _, a, _, missed = ranked()[0]
        pairs = int((a >= 0).sum())
        unexplained = good.size - pairs > max(1.0, 0.1 * good.size)
        return (unexplained and missed > 0) or missed > 0.25 * (pairs + missed)

    def layouts() -> list[tuple[NDArray, NDArray]]:
        return full(
            [(a, T) for _, a, T in layout_hypotheses(
                det[good], landmarks_xyz, K, prior, image_size, margin_px, sig, position_offsets,
                coarse_gate_px, shifts_per_layout, need,
            )][: 5 * max_hypotheses]
        )

    # 1-2. coarse hypotheses, refined with re-association: every assignment of a small set;
    # else upright two-point poses, and the prior's layout vote when those leave the detections
    # poorly explained (or, below, ambiguous)
    exhaustive = exhaustive_hypotheses(
        det, good, idx, landmarks_xyz, K, prior, need, pixel_sigma, gate, sig, exhaustive_limit,
        min(max(max_hypotheses, 1), 3),
    )
    voted = exhaustive is not None
    if exhaustive is not None:
        explore(exhaustive, False)
    else:
        upright = full(upright_hypotheses(
            det[good], landmarks_xyz, idx, proj, K, prior, sig, max_prior_mahalanobis_sq, coarse_gate_px,
            need, 5 * max_hypotheses, 2 * max(max_hypotheses, 1),
            None if P.log_odds is None else P.log_odds[good],
        ))
        # the best half first: when they explain the detections the rest would only cost time;
        # else the other half joins the layout vote's batch
        first = max(max_hypotheses, 1)
        explore(upright[:first], True)
        if weak():
            rest = upright[first:]
            explore(rest + layouts(), True, len(rest))
            voted = True

    if not finals:
        if rejected["fit"] and not rejected["prior"]:
            code = FailureCode.NO_CONSISTENT_ASSOCIATION
            reason = (
                f"all {rejected['fit']} association hypotheses fit worse than pixel_sigma="
                f"{pixel_sigma:g} px allows (chi-square quantile {fit_quantile})"
            )
        elif rejected["prior"]:
            code = FailureCode.INCONSISTENT_WITH_PRIOR
            reason = (
                f"all {rejected['prior']} association hypotheses give poses inconsistent with "
                f"the prior (Mahalanobis^2 > {max_prior_mahalanobis_sq})"
            )
        else:
            code = FailureCode.NO_CONSISTENT_ASSOCIATION
            reason = f"no association hypothesis with {need} or more consistent correspondences"
        return Association(empty, prior, 0.0, np.inf, tried[0], reason, code)

    # 3-4. scoring, rivals of the winner under the layout's self-translations, ambiguity
    scored, reason = decide()
    if reason is not None and not voted and explore(layouts(), True):
        scored, reason = decide()
    if reason is not None:
        return Association(empty, prior, 0.0, np.inf, len(finals), reason, FailureCode.AMBIGUOUS)
    score_best, a, T, _ = scored[0]
    # The batched assignment pairs mutual nearest neighbours; two landmarks projecting within a
    # gate of each other can be swapped there, so the winner gets the minimum-cost assignment.
    cidx, cproj = candidate_landmarks(landmarks_xyz, K, T, image_size, margin_px)
    local = assign(det[good], cproj, gate)
    exact = np.full(n, -1, dtype=np.int64)
    exact[good[local >= 0]] = cidx[local[local >= 0]]
    if not np.array_equal(exact, a) and (exact >= 0).sum() >= need:
        a = exact
        T, _ = refine_pose(landmarks_xyz[a[a >= 0]], det[a >= 0], K, T, max_iterations=10)
    m = a >= 0
    reason = _minimal_fit_reason(P, a, T)
    if reason is not None:
        return Association(empty, prior, 0.0, np.inf, len(finals), reason,
                           FailureCode.NO_CONSISTENT_ASSOCIATION)
    res, _ = reprojection_residuals(K, T, landmarks_xyz[a[m]], det[m])
    return Association(a, T, float(np.sum(res**2)), float(score_best), len(finals), None)


def _warm_association(
    P: _Problem, start: NDArray, max_prior_mahalanobis_sq: float | None, fit_quantile: float,
    miss_cost: float,
) -> Association | None:
    """The association of the predicted pose ``start`` alone, or None if it leaves anything open.

    Accepted (module docstring, *Warm start*) when, refined with re-association, it pairs every
    finite detection, detects every landmark its pose projects inside the image, keeps more
    pairs than the minimum, stays within the prior's Mahalanobis gate and passes the fit test.
    One compiled call (:func:`localization.associate.hypothesis_kernels.warm_hypothesis`).
    """
    if P.good.size <= P.need:
        return None
    w, h = P.image_size
    start = np.ascontiguousarray(start, dtype=np.float64)
    a, R, t, alive, prior_sq, far, chi, missed = warm_hypothesis(
        P.K, P.landmarks_xyz, P.det, np.ascontiguousarray(P.good, dtype=np.int64), start[:3, :3],
        start[:3, 3], int(w), int(h), float(P.margin_px), float(P.gate_px), float(P.coarse_gate_px),
        int(P.max_iterations), int(P.need), P.prior_R, P.prior_C, P.sig_array,
    )
    pairs = int(np.count_nonzero(a >= 0))
    if not alive or missed > 0 or pairs != P.good.size or pairs <= P.need:
        return None
    T = make_transform(R, t)
    if far:  # a rotation near pi from the prior's: the exact logarithm
        prior_sq = prior_mahalanobis_sq(T, P.prior, P.sig)
    if max_prior_mahalanobis_sq is not None and prior_sq > max_prior_mahalanobis_sq:
        return None
    chi = chi / P.pixel_sigma**2
    if chi > _chi2_quantiles(fit_quantile, 2 * pairs - 6)[2 * pairs - 6]:
        return None
    score, _ = P.nll(a[None], T[None], np.array([chi]), np.array([prior_sq]), miss_cost, np.array([missed]))
    return Association(a, T, chi * P.pixel_sigma**2, float(score[0]), 1, None, warm_started=True)


def _minimal_fit_reason(P: _Problem, a: NDArray, T: NDArray) -> str | None:
    """Why the winner ``a`` at pose ``T`` is a coincidence rather than a pose, or None.

    A hypothesis with no more pairs than the minimum (``P.need``: four pairs leave the fit test
    two degrees of freedom) that leaves at least as many landmarks unmatched as it pairs, of
    those it projects inside the image, explains at most half of its own prediction. Wrong
    detections form such fits: among enough of them, some four fit some pose near the prior
    (the duplex IFC building's eight slab corners, which the default weights barely detect: 12
    of their 13 wrong poses, 2-6.5 m off, had four pairs and four more corners predicted and
    unmatched). A right pose of that kind needs half of the landmarks it should see hidden or
    undetected; it fails too, for ``NO_CONSISTENT_ASSOCIATION`` is the honest answer when the
    image cannot tell the two apart.
    """
    pairs = int((a >= 0).sum())
    if pairs > P.need:
        return None
    w, h = P.image_size
    missed = int(missed_many(
        P.K, P.landmarks_xyz, np.ascontiguousarray(a[None], dtype=np.int64),
        np.ascontiguousarray(T[None, :3, :3]), np.ascontiguousarray(T[None, :3, 3]), int(w), int(h),
    )[0])
    if missed < pairs:
        return None
    return (
        f"the best association pairs only {pairs} detections (the minimum) and leaves {missed} of the "
        f"{pairs + missed} landmarks its pose projects into the image unmatched: a minimal fit that "
        "explains at most half of what it predicts is as likely a coincidence of wrong detections"
    )


def _log_odds(scores: NDArray | None) -> NDArray | None:
    """``2 log(s / (1 - s))`` of scores clipped to [0.01, 0.99] (NaN: 0), or None."""
    if scores is None:
        return None
    s = np.clip(np.nan_to_num(np.asarray(scores, dtype=np.float64), nan=0.5), 0.01, 0.99)
    return 2.0 * np.log(s / (1.0 - s))


@functools.lru_cache(maxsize=64)
def _chi2_quantiles(quantile: float, max_dof: int) -> NDArray[np.float64]:
    """Chi-square ``quantile`` for 0 .. ``max_dof`` degrees of freedom (inf at 0), cached."""
    return np.concatenate([[np.inf], chi2.ppf(quantile, np.arange(1, max(max_dof, 1) + 1))])
