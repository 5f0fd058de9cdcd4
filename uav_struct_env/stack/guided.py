"""The BIM-guided detector: a first pose from the learned detector, then the building model's templates.

:class:`GuidedDetector` follows :class:`localization.Detector` and is what ``detector="guided"``
builds (:func:`uav_struct_env.stack.build_stack`). Per frame:

1. **First pass.** The learned detector runs once for every landmark type. All its candidates
   are localized from the onboard prior against every structural landmark of the stage
   (``anchors``: the building model knows them all, and more landmarks pin the pose better than
   one set's few) by a :class:`localization.Localizer` like the stack's (association, PnP,
   verification); without a pose there, the candidates of the set's type are localized against
   the set by the stack's own. A pose that neither confirms is still worth the templates: the
   first pose a verification refused is kept as an *unconfirmed* pose (the refusal carries it;
   no localization runs twice), typically 1-3 m off where the learned detector found three or
   four of a set's corners and one of its candidates sat a few pixels off its corner.
2. **An unconfirmed pose: a wide pass.** The templates are matched within
   ``probe_search_px`` (16 px) of the landmarks' projections at it; the matches and every
   candidate of the set's type are localized by the set's own localizer, with verification.
   Only a pose confirmed there goes on.
3. **No pose at all: the model aligned at the prior.** Where neither gives a pose (or the
   unconfirmed one leads nowhere), the whole structure drawn at the prior is aligned with the
   image (:class:`localization.detect.prior_align.PriorAligner`: a zoom, a rotation and a shift
   of the picture, coarse to fine); each of its (two) hypotheses is corrected by a pose fitted to
   the template matches of every structural landmark within ``align_search_px`` (24 px) of it
   (:func:`~localization.detect.prior_align.fit_matches`) and is then a start of the wide pass.
   A pose the wide pass confirms from any start must also draw the whole model on the image at
   least ``min_gain`` (1.03) times as well as its start did
   (:meth:`~localization.detect.prior_align.PriorAligner.score`); else the next start is tried.
   Without a confirmed pose, the set's candidates are the detections.
4. **The narrow pass.** At a confirmed pose, the building model is rendered around every
   landmark it shows (:class:`uav_struct_env.sim.templates.SiteTemplates`) and matched in the
   image within a few pixels (:class:`localization.detect.guided.TemplateMatcher`). The
   detections are the set's candidates that lie where a landmark projects at that pose (within
   the search radius; the others fit no landmark there), where no match lies within
   ``merge_px`` of them, and the matches. Without any pose, the set's candidates are the
   detections (the learned detector's result).

The learned detector's run and the starts from the prior do not depend on the landmark set:
:func:`~uav_struct_env.stack.build_stack` gives the guided detectors of a site's sets one
shared seed and one :class:`~uav_struct_env.stack.prior_starts.PriorStarts`, which remember the
frame's (:mod:`uav_struct_env.stack.frame_memo`), so a frame's second set reuses them.

The stack then localizes the detections again from the prior, exactly as for any detector, so
the final pose rests on the association and verification of every detector (the identities the
templates were matched under are not passed on). Ground truth in the context fills
``Detections.true_ids`` for scoring only (:func:`localization.detect.learned.truth_ids`).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from localization import Detections, Localizer
from localization.detect.guided import Matches, TemplateMatcher
from localization.detect.learned import truth_ids
from localization.detect.prior_align import PriorAligner
from localization.geometry.distortion import distort_points
from localization.geometry.transforms import project
from uav_struct_env.stack.prior_starts import PriorStarts

__all__ = ["GuidedDetector", "merged"]

def merged(first: Detections, found: Matches,
           radius: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(uv, scores)``: the matches, then the first pass's detections farther than ``radius`` from them.

    Where both found a landmark the match is kept: it is placed where the building model's
    corner shows, and on buildings unlike its training data the learned detector places its
    corners a few pixels off it (a finish layer, a parapet's edge), close enough to compete with
    the match in the association, too far to fit with it.
    """
    scores = first.scores if first.scores is not None else np.ones(len(first))
    if len(found.uv) == 0:
        return first.uv, scores
    if len(first) == 0:
        return found.uv, found.score
    gap = np.hypot(*(first.uv[:, None, :] - found.uv[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    rest = gap > radius
    return np.vstack([found.uv, first.uv[rest]]), np.concatenate([found.score, scores[rest]])


class GuidedDetector:
    """Learned candidates, a first pose, and the building model's templates at it (module docstring).

    Args:
        seed: the first pass's detector: ``detect_all(image) -> (uv, scores, types)`` over every
            landmark type (a :class:`~localization.detect.learned.LearnedDetector` of ``"all"``).
        types: the ``types`` values of the set's candidates.
        localizer: the localizer of the landmark set (the stack's).
        matcher: the landmark set's :class:`~localization.detect.guided.TemplateMatcher`.
        landmarks: the set's name in ``context["landmarks"]`` (scoring only).
        anchors: a localizer of every structural landmark of the stage, tried on all the
            candidates when the set's own give no pose (None: the set's only).
        merge_px: a first-pass detection this close to a match is the same landmark (the match is
            kept), px.
        match_px: radius of the ground-truth matching that fills ``true_ids``, px.
        probe_search_px: half-size of the template search at an unconfirmed first pose, px.
        aligner: the :class:`~localization.detect.prior_align.PriorAligner` where the first pass
            gives no pose (None: one of the matcher's templates with its defaults).
        align_search_px: half-size of the template search around an alignment's pose, px.
        min_gain: least ratio of a confirmed pose's :meth:`PriorAligner.score` to its start's.
        prior_starts: the starts from the prior (:class:`~uav_struct_env.stack.prior_starts.PriorStarts`),
            shared by the detectors of a site's sets (None: its own, of ``aligner``, the anchors'
            or the set's landmarks, ``align_search_px`` and the localizer's camera; a given one
            must have that camera, and its own aligner and search).

    Raises:
        ValueError: if ``prior_starts`` is for another camera than the localizer's.
    """

    def __init__(self, seed: Any, types: Sequence[int], localizer: Localizer, matcher: TemplateMatcher,
                 landmarks: str, anchors: Localizer | None = None, merge_px: float = 8.0,
                 match_px: float = 3.0, probe_search_px: int = 16, aligner: PriorAligner | None = None,
                 align_search_px: int = 24, min_gain: float = 1.03,
                 prior_starts: PriorStarts | None = None) -> None:
        self.seed = seed
        if prior_starts is None:
            every = matcher.xyz if anchors is None else anchors.landmarks_xyz
            prior_starts = PriorStarts(PriorAligner(matcher.templates) if aligner is None else aligner,
                                       TemplateMatcher(every, matcher.templates), localizer.K,
                                       localizer.distortion, align_search_px)
        elif not prior_starts.same_camera(localizer.K, localizer.distortion):
            raise ValueError("prior_starts must be for the localizer's camera (its K and distortion)")
        self.prior_starts = prior_starts
        self.aligner = prior_starts.aligner
        self.min_gain = float(min_gain)
        self.probe_search_px = probe_search_px
        self.types = tuple(int(t) for t in types)
        self.localizer = localizer
        self.anchors = anchors
        self.matcher = matcher
        self.landmarks = landmarks
        self.merge_px = float(merge_px)
        self.match_px = float(match_px)

    def detect(self, image: Any, context: Mapping[str, Any]) -> Detections:
        """Detections in ``image``.

        ``context`` holds ``prior_cam_from_world`` (and ``landmarks``, for scoring only), as
        :meth:`~uav_struct_env.stack.LocalizationStack.localize` gives it.

        Raises:
            KeyError: if the context lacks the prior.
        """
        if "prior_cam_from_world" not in context:
            raise KeyError(
                f"the guided detector needs context['prior_cam_from_world']; got {sorted(context)}"
            )
        uv, scores, types = self.seed.detect_all(image)
        mine = np.isin(types, self.types)
        first = Detections(uv[mine], scores[mine])
        prior = context["prior_cam_from_world"]
        pose, confirmed = self.first_pose(first, Detections(uv, scores), prior)
        if not confirmed:
            pose = self.confirmed_pose(image, first, prior, pose)
        uv, scores = first.uv, first.scores
        if pose is not None:
            found = self.matcher.find(image, pose, self.localizer.K, self.localizer.distortion)
            uv, scores = merged(self.near(first, pose), found, self.merge_px)
        truth = context.get("landmarks", {}).get(self.landmarks)
        return Detections(uv=uv, scores=scores, true_ids=truth_ids(uv, truth, self.match_px))

    def confirmed_pose(self, image: Any, first: Detections, prior: NDArray[np.float64],
                       unconfirmed: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
        """A pose the set's localizer confirms from a wide template pass, or None.

        The starts are the first pass's unconfirmed pose, then the poses where the building
        model drawn at the prior aligns with the image (:meth:`starts`). At each, the set's
        templates are matched within ``probe_search_px`` and localized with the set's candidates,
        with the verification; a pose so confirmed must also draw the whole model on the image
        at least ``min_gain`` times as well as its start did (:meth:`PriorAligner.score`): the
        matches around a wrong start can be consistent with a wrong pose, which then places the
        rest of the structure off its edges.
        """
        K, distortion = self.localizer.K, self.localizer.distortion
        for start, reference in self._each_start(image, prior, unconfirmed):
            found = self.matcher.find(image, start, K, distortion, search_px=self.probe_search_px)
            uv, scores = merged(first, found, self.merge_px)
            est = self.localizer.localize(Detections(uv, scores), prior)
            if not est.success:
                continue
            if reference is None:
                reference = self.aligner.score(image, start, K)
            if self.aligner.score(image, est.cam_from_world, K) >= self.min_gain * reference:
                return est.cam_from_world
        return None

    def _each_start(self, image: Any, prior: NDArray[np.float64],
                    unconfirmed: NDArray[np.float64] | None) -> Iterator[tuple[NDArray, float | None]]:
        """The first pass's unconfirmed pose (its reference score unknown), then :meth:`starts`, lazily."""
        if unconfirmed is not None:
            yield unconfirmed, None
        yield from self.starts(image, prior)

    def starts(self, image: Any, prior: NDArray[np.float64]) -> Iterator[tuple[NDArray[np.float64], float]]:
        """``(pose, score)`` of each alignment of the model drawn at the prior with the image, best first.

        Each pose corrected by a pose fitted to the template matches of every structural landmark
        around it, when it is reached (:class:`~uav_struct_env.stack.prior_starts.PriorStarts`).
        """
        return self.prior_starts(image, prior)

    def near(self, first: Detections, pose: NDArray[np.float64]) -> Detections:
        """The first-pass detections within the search radius of a landmark's projection at ``pose``.

        The others fit no landmark at the pose the first pass found: kept, they would compete
        with the true detections in the second localization (a set of four corners and the
        learned detector's false candidates near them fit some other pose nearly as well).
        """
        if len(first) == 0:
            return first
        uv, z = project(self.localizer.K, pose, self.matcher.xyz)
        uv = distort_points(uv[z > 0.1], self.localizer.K, self.localizer.distortion)
        if len(uv) == 0:
            return Detections(np.zeros((0, 2)), np.zeros(0))
        gap = np.hypot(*(first.uv[:, None, :] - uv[None, :, :]).transpose(2, 0, 1)).min(axis=1)
        keep = gap <= self.matcher.search_px
        return Detections(first.uv[keep], None if first.scores is None else first.scores[keep])

    def first_pose(self, first: Detections, every: Detections,
                   prior: NDArray[np.float64]) -> tuple[NDArray | None, bool]:
        """``(cam_from_world, confirmed)`` of the first pass, ``(None, False)`` without one.

        All candidates against the anchors, else the set's own against the set: every structural
        landmark the stage has pins the templates' pose better than one set's few (four slab
        corners of a house). Without a confirmed pose, the first pose either verification refused
        is the unconfirmed one (the pose is then only where the wide pass looks: ``confirmed``
        False): the pose that localization gives without the verification, read from the refusal
        (``PoseEstimate.refused_cam_from_world``) rather than localized again.
        """
        tries = [(self.localizer, first)]
        if self.anchors is not None and len(every) > len(first):
            tries.insert(0, (self.anchors, every))
        unconfirmed = None
        for localizer, detections in tries:
            est = localizer.localize(detections, prior)
            if est.success:
                return est.cam_from_world, True
            if unconfirmed is None:
                unconfirmed = est.refused_cam_from_world
        return unconfirmed, False

    def __repr__(self) -> str:
        return f"GuidedDetector(landmarks={self.landmarks!r}, seed={self.seed!r}, matcher={self.matcher!r})"
