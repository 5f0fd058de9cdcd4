"""Stage 1, detection guided by the building model: render the structure at the prior, match the image.

The building model and the onboard prior are known before the image is seen. :class:`GuidedDetector`
renders the model's structure at the prior pose (through a :class:`TemplateSource`, which the
simulator package implements with its rasterizer: ``uav_struct_env.sim.templates``) and finds each
predicted landmark in the image by matching the structure's edges against the image's gradients
around its predicted position ("render and match", as model-based trackers align wireframes):

1. **Global alignment.** The prior's error moves every prediction by nearly the same shift (up to
   ~150 px at 1280 x 720 for 3 m and 5 deg). The model's edges rendered over the whole frame at
   ``global_scale`` are correlated (normalised, zero-mean) with the image's gradient magnitude at
   the same scale over shifts up to ``global_search_px``; the best shift moves every prediction.
2. **Local matching.** Each landmark the prior sees (in the frame, and not hidden by the model
   itself: the render's depth at its pixel is not in front of it) gets a ``patch_px`` square
   render centred on its prediction (a view whose principal point is moved), and its edge image is
   correlated with the image gradients over ``search_px`` around the shifted prediction. A peak is
   kept when it scores at least ``min_score`` and no other peak farther than ``exclusion_px``
   reaches ``max_second_ratio`` of it (an ambiguous peak is dropped, not guessed); it is placed to
   sub-pixel by a parabola through the scores.
3. **Second pass.** The matches carry the identity of their landmark, so a pose is fitted to them
   (RANSAC over SQPnP, then Levenberg-Marquardt; at least ``min_pose_matches`` inliers); the
   model is rendered again at that pose and every landmark it sees is matched again within
   ``refine_search_px``, where the template and the image agree in perspective too. Without such
   a pose, the first pass's matches are returned.

The output is what every detector returns: anonymous pixels with scores (the correlation); the
association, PnP and verification of :class:`localization.Localizer` take them unchanged. The
identities the matching used are not passed on.

**Context.** :meth:`GuidedDetector.detect` reads ``context["prior_cam_from_world"]`` (4, 4),
``context["intrinsics"]`` (3, 3 K) and ``context.get("distortion")`` (OpenCV coefficients, None
for a pinhole); the templates are pinhole renders, so a lens's distortion moves the predictions
(``distort_points``) but does not bend the templates. Ground truth in ``context["landmarks"]`` is
used only to fill ``Detections.true_ids`` for scoring, as the learned detector does
(:func:`localization.detect.learned.match_detections`); visibility comes from the render at the
prior (or at the first pass's pose), never from the truth.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from localization.checks import check_number
from localization.detect.interface import Detections
from localization.geometry.distortion import distort_points, is_pinhole
from localization.geometry.transforms import as_points, check_intrinsics, check_transform, project

__all__ = ["GuidedDetector", "ModelViews", "TemplateSource", "orientation_field", "structure_edges"]


@dataclass(frozen=True, eq=False)
class ModelViews:
    """Renders of the building model: several views of one pose.

    Attributes:
        shade: (V, H, W) float32 grey shading in 0-1 (flat albedo, lit).
        depth: (V, H, W) float32 depth along the optical axis, m; inf where no surface.
        label: (V, H, W) int32 element (or face) label; -1 where no surface. Edges of the
            structure lie where the label changes.
    """

    shade: NDArray[np.float32]
    depth: NDArray[np.float32]
    label: NDArray[np.int32]


@runtime_checkable
class TemplateSource(Protocol):
    """Renders the building model: ``render(cam_from_world (4, 4), Ks (V, 3, 3), size (W, H)) -> ModelViews``."""

    def render(self, cam_from_world: ArrayLike, Ks: ArrayLike, size: tuple[int, int]) -> ModelViews:
        """The model seen from one pose through each of ``Ks``, at ``size`` (W, H)."""
        ...


def structure_edges(views: ModelViews, blur_px: float = 1.0) -> NDArray[np.float32]:
    """(V, H, W) float32 edges of the structure: where the label changes or the depth jumps, blurred.

    A pixel is an edge when its label differs from its right or lower neighbour's, or its depth
    from theirs by more than 3 %; the binary map is blurred by a Gaussian of ``blur_px``.
    """
    label, depth = views.label, views.depth
    edge = np.zeros(label.shape, np.float32)
    for axis in (1, 2):
        a = np.swapaxes(label, axis, -1)
        d = np.swapaxes(depth, axis, -1)
        with np.errstate(invalid="ignore"):
            jump = (a[..., 1:] != a[..., :-1]) | (np.abs(d[..., 1:] - d[..., :-1]) > 0.03 * d[..., :-1])
        e = np.swapaxes(edge, axis, -1)
        e[..., 1:] = np.maximum(e[..., 1:], jump)
    if blur_px > 0:
        for k in range(len(edge)):
            edge[k] = cv2.GaussianBlur(edge[k], (0, 0), blur_px)
    return edge


def orientation_field(gray: NDArray[np.float32], blur_px: float = 1.0, power: float = 0.5) -> NDArray[np.float32]:
    """(H, W, 2) float32 gradients of a grey image in doubled-angle form, for correlation.

    Each pixel's gradient ``g`` at angle ``theta`` becomes ``|g|^power (cos 2 theta, sin 2 theta)``:
    an edge counts the same whichever side is brighter (the model's shading is not the image's),
    and a random texture, whose orientations scatter, averages out of a correlation where
    straight structural edges add up. ``power`` < 1 evens strong and weak edges out.
    """
    if blur_px > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), blur_px)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    mag2 = gx * gx + gy * gy
    scale = np.power(mag2 + 1e-12, 0.5 * power - 1.0)  # |g|^power / |g|^2
    return np.dstack([(gx * gx - gy * gy) * scale, 2.0 * gx * gy * scale])


def _peak(scores: NDArray[np.float32], exclusion_px: float) -> tuple[float, float, float, float]:
    """``(x, y, best, second)`` of a correlation map: sub-pixel best peak and the best one away from it."""
    _, best, _, (bx, by) = cv2.minMaxLoc(scores)
    h, w = scores.shape
    dx = dy = 0.0
    if 0 < bx < w - 1:
        left, mid, right = scores[by, bx - 1], scores[by, bx], scores[by, bx + 1]
        den = left - 2 * mid + right
        dx = float(np.clip(0.5 * (left - right) / den, -0.5, 0.5)) if den < -1e-9 else 0.0
    if 0 < by < h - 1:
        up, mid, down = scores[by - 1, bx], scores[by, bx], scores[by + 1, bx]
        den = up - 2 * mid + down
        dy = float(np.clip(0.5 * (up - down) / den, -0.5, 0.5)) if den < -1e-9 else 0.0
    r = int(np.ceil(exclusion_px))
    away = scores.copy()
    away[max(0, by - r): by + r + 1, max(0, bx - r): bx + r + 1] = -1.0
    # The second peak must be a local maximum: the slope of the first peak is not a rival.
    is_max = away >= cv2.dilate(away, np.ones((3, 3), np.uint8))
    second = float(away[is_max].max()) if np.any(is_max & (away > -1.0)) else -1.0
    return bx + dx, by + dy, float(best), second


@dataclass(frozen=True, eq=False)
class _Matches:
    """Landmarks found in one pass: ``uv (N, 2)``, ``score (N,)``, model ``index (N,)``."""

    uv: NDArray[np.float64]
    score: NDArray[np.float64]
    index: NDArray[np.int64]


class GuidedDetector:
    """The BIM-guided detector (see the module docstring).

    Args:
        landmarks_xyz: (M, 3) the landmark set's model points, project frame, m.
        templates: the building model's renderer (:class:`TemplateSource`).
        landmarks: the set's name, looked up in ``context["landmarks"]`` for ``true_ids`` only.
        patch_px: side of each landmark's template render, px.
        search_px: half-size of the first pass's local search, px (after the global shift).
        refine_search_px: half-size of the second pass's search, px.
        global_scale: resolution factor of the global alignment.
        global_search_px: largest global shift searched, full-resolution px.
        min_score: least normalised correlation of a kept peak.
        max_second_ratio: a peak is ambiguous when another, farther than ``exclusion_px``,
            reaches this fraction of it.
        exclusion_px: radius around the best peak where a second peak is not a rival, px.
        min_pose_matches: inliers the second pass's pose needs.
        match_px: radius of the ground-truth matching that fills ``true_ids`` (scoring only).

    Raises:
        TypeError: if ``templates`` does not follow :class:`TemplateSource`.
        ValueError: for malformed points or numbers out of range.
    """

    def __init__(
        self,
        landmarks_xyz: ArrayLike,
        templates: TemplateSource,
        *,
        landmarks: str = "slab_corners",
        seed: Any = None,
        vote_px: float = 10.0,
        patch_px: int = 48,
        search_px: int = 24,
        refine_search_px: int = 4,
        global_scale: float = 0.25,
        global_search_px: float = 200.0,
        min_score: float = 0.5,
        max_second_ratio: float = 0.9,
        exclusion_px: float = 4.0,
        min_pose_matches: int = 6,
        match_px: float = 3.0,
    ) -> None:
        if not isinstance(templates, TemplateSource):
            raise TypeError(f"templates must have render(cam_from_world, Ks, size), got {type(templates).__name__}")
        self.xyz = as_points("landmarks_xyz", landmarks_xyz, 3)
        if seed is not None and not callable(getattr(seed, "detect", None)):
            raise TypeError(f"seed must be a detector with detect(image, context), got {type(seed).__name__}")
        self.templates = templates
        self.landmarks = landmarks
        self.seed = seed
        self.vote_px = float(check_number("vote_px", vote_px, 0.0, lo_open=True, type_error=ValueError))
        self.patch_px = check_number("patch_px", patch_px, 8, integer=True, type_error=ValueError)
        self.search_px = check_number("search_px", search_px, 1, integer=True, type_error=ValueError)
        self.refine_search_px = check_number("refine_search_px", refine_search_px, 1, integer=True,
                                             type_error=ValueError)
        self.global_scale = float(check_number("global_scale", global_scale, 0.0, 1.0, lo_open=True,
                                               type_error=ValueError))
        self.global_search_px = float(check_number("global_search_px", global_search_px, 0.0,
                                                   type_error=ValueError))
        self.min_score = float(check_number("min_score", min_score, -1.0, 1.0, type_error=ValueError))
        self.max_second_ratio = float(check_number("max_second_ratio", max_second_ratio, 0.0, 1.0,
                                                   type_error=ValueError))
        self.exclusion_px = float(check_number("exclusion_px", exclusion_px, 0.0, type_error=ValueError))
        self.min_pose_matches = check_number("min_pose_matches", min_pose_matches, 4, integer=True,
                                             type_error=ValueError)
        self.match_px = float(check_number("match_px", match_px, 0.0, lo_open=True, type_error=ValueError))

    # ------------------------------------------------------------------------------ the steps
    def align(self, gray: NDArray[np.float32], cam_from_world: NDArray, K: NDArray) -> NDArray[np.float64]:
        """(3, 3) homography taking the model's pixels at ``cam_from_world`` to where ``gray`` shows them.

        A shift searched exhaustively (normalised correlation of the orientation fields), then
        refined to a homography by ECC on the edge magnitudes, both at ``global_scale``; the
        identity when the model shows no edge, the shift alone when ECC does not converge.
        """
        h, w = gray.shape
        s = self.global_scale
        sw, sh = max(8, round(w * s)), max(8, round(h * s))
        S = np.array([[sw / w, 0.0, 0.5 * sw / w - 0.5], [0.0, sh / h, 0.5 * sh / h - 0.5], [0.0, 0.0, 1.0]])
        edges = structure_edges(self.templates.render(cam_from_world, (S @ K)[None], (sw, sh)))[0]
        template = orientation_field(edges, 0.0, 1.0)
        if float(np.abs(template).max()) < 1e-6:
            return np.eye(3)
        small = cv2.resize(gray, (sw, sh), interpolation=cv2.INTER_AREA)
        field = orientation_field(small, 0.0)
        mx, my = int(np.ceil(self.global_search_px * S[0, 0])), int(np.ceil(self.global_search_px * S[1, 1]))
        padded = cv2.copyMakeBorder(field, my, my, mx, mx, cv2.BORDER_CONSTANT, value=0.0)
        x, y, _, _ = _peak(cv2.matchTemplate(padded, template, cv2.TM_CCOEFF_NORMED), 1.0)
        H = np.array([[1.0, 0.0, x - mx], [0.0, 1.0, y - my], [0.0, 0.0, 1.0]])
        magnitude = cv2.GaussianBlur(np.hypot(field[..., 0], field[..., 1]), (0, 0), 1.0)
        warp = H.astype(np.float32)
        try:
            _, warp = cv2.findTransformECC(cv2.GaussianBlur(edges, (0, 0), 1.0), magnitude, warp,
                                           cv2.MOTION_HOMOGRAPHY,
                                           (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4), None, 1)
            H = warp.astype(np.float64)
        except cv2.error:
            pass
        return np.linalg.inv(S) @ H @ S

    def match(self, edges: NDArray[np.float32], cam_from_world: NDArray, K: NDArray,
              distortion: NDArray | None, warp: NDArray, search_px: int) -> _Matches:
        """Find every landmark the model shows at ``cam_from_world`` within ``search_px`` of its prediction moved by ``warp``.

        ``warp`` (3, 3) is the homography of :meth:`align` (the identity at a pose already aligned).
        """
        h, w = edges.shape[:2]
        uv, z = project(K, cam_from_world, self.xyz)
        inside = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            return _Matches(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
        P = self.patch_px
        corner = np.floor(uv[idx]).astype(np.int64) - P // 2  # patch pixel (i, j) is image pixel corner + (i, j)
        Ks = np.repeat(K[None], len(idx), axis=0)
        Ks[:, 0, 2] -= corner[:, 0]
        Ks[:, 1, 2] -= corner[:, 1]
        views = self.templates.render(cam_from_world, Ks, (P, P))
        at = uv[idx] - corner  # the landmark in its patch
        seen = self._unhidden(views.depth, at, z[idx])
        templates = structure_edges(views)
        moved = cv2.perspectiveTransform(uv[idx].reshape(-1, 1, 2), warp).reshape(-1, 2)
        pred = moved if is_pinhole(distortion) else distort_points(moved, K, distortion)
        margin = P + search_px
        padded = cv2.copyMakeBorder(edges, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=0.0)
        out_uv, out_s, out_i = [], [], []
        for k in np.flatnonzero(seen):
            template = orientation_field(templates[k], 0.0, 1.0)
            if float(np.abs(template).max()) < 1e-3:
                continue
            x0, y0 = (np.round(pred[k] - at[k]).astype(np.int64) - search_px + margin)
            window = padded[y0: y0 + P + 2 * search_px, x0: x0 + P + 2 * search_px]
            if window.shape[:2] != (P + 2 * search_px, P + 2 * search_px):
                continue
            scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
            x, y, best, second = _peak(scores, self.exclusion_px)
            if best < self.min_score or second > self.max_second_ratio * best:
                continue
            out_uv.append((x0 - margin + x + at[k, 0], y0 - margin + y + at[k, 1]))
            out_s.append(best)
            out_i.append(idx[k])
        return _Matches(np.array(out_uv, dtype=np.float64).reshape(-1, 2), np.array(out_s, dtype=np.float64),
                        np.array(out_i, dtype=np.int64))

    @staticmethod
    def _unhidden(depth: NDArray[np.float32], at: NDArray, z: NDArray) -> NDArray[np.bool_]:
        """(V,) True where no model surface lies in front of the landmark around its pixel (3 x 3)."""
        out = np.zeros(len(at), bool)
        h, w = depth.shape[1:]
        for k, (u, v) in enumerate(np.round(at).astype(np.int64)):
            if not (1 <= u < w - 1 and 1 <= v < h - 1):
                continue
            nearest = float(depth[k, v - 1: v + 2, u - 1: u + 2].min())
            out[k] = nearest >= 0.98 * z[k] - 0.05
        return out

    def seed_pairs(self, seed_uv: NDArray[np.float64], cam_from_world: NDArray, K: NDArray,
                   distortion: NDArray | None) -> _Matches:
        """Seed detections paired with the landmarks they most likely are, by the prior's common shift.

        Every (landmark prediction, seed) offset within ``global_search_px`` votes in a histogram of
        ``vote_px`` bins; the densest offset (averaged over the votes near it) is the prior's common
        shift, and each landmark takes the seed nearest its shifted prediction within ``vote_px``
        (one-to-one). The pairs carry identities for :meth:`pose` only.
        """
        empty = _Matches(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
        uv, z = project(K, cam_from_world, self.xyz)
        idx = np.flatnonzero(z > 0.1)
        if len(idx) == 0 or len(seed_uv) == 0:
            return empty
        pred = uv[idx] if is_pinhole(distortion) else distort_points(uv[idx], K, distortion)
        offsets = (seed_uv[None, :, :] - pred[:, None, :]).reshape(-1, 2)
        offsets = offsets[np.hypot(offsets[:, 0], offsets[:, 1]) < self.global_search_px]
        if len(offsets) == 0:
            return empty
        r, bin_px = self.global_search_px, self.vote_px
        n_bins = int(np.ceil(2 * r / bin_px))
        votes, _, _ = np.histogram2d(offsets[:, 0], offsets[:, 1], bins=n_bins, range=[[-r, r], [-r, r]])
        votes = cv2.boxFilter(votes.astype(np.float32), -1, (3, 3), normalize=False)
        i, j = np.unravel_index(int(np.argmax(votes)), votes.shape)
        centre = np.array([-r + (i + 0.5) * bin_px, -r + (j + 0.5) * bin_px])
        near = np.hypot(*(offsets - centre).T) < 1.5 * bin_px
        shift = offsets[near].mean(axis=0)
        gap = np.hypot(*(seed_uv[None, :, :] - (pred + shift)[:, None, :]).transpose(2, 0, 1))
        rows, cols = linear_sum_assignment(np.where(gap < bin_px, gap, 1e6))
        ok = gap[rows, cols] < bin_px
        return _Matches(seed_uv[cols[ok]], np.ones(int(ok.sum())), idx[rows[ok]])

    def pose(self, found: _Matches, K: NDArray, distortion: NDArray | None,
             prior: NDArray) -> NDArray | None:
        """A ``cam_from_world`` fitted to identified matches, or None.

        RANSAC over SQPnP (3 px), then Levenberg-Marquardt on the inliers; None with fewer than
        ``min_pose_matches`` inliers, or for a pose farther from the prior than it can be wrong
        by (10 m, 20 deg): such a pose would only misplace the templates.
        """
        if len(found.index) < self.min_pose_matches:
            return None
        dist = None if is_pinhole(distortion) else np.asarray(distortion, dtype=np.float64)
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            self.xyz[found.index], found.uv, K, dist, reprojectionError=3.0, iterationsCount=200,
            confidence=0.999, flags=cv2.SOLVEPNP_SQPNP,
        )
        if not ok or inliers is None or len(inliers) < self.min_pose_matches:
            return None
        keep = inliers.ravel()
        rvec, tvec = cv2.solvePnPRefineLM(self.xyz[found.index[keep]], found.uv[keep], K, dist, rvec, tvec)
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        if not np.isfinite(T).all():
            return None
        moved = np.linalg.norm(T[:3, :3].T @ T[:3, 3] - prior[:3, :3].T @ prior[:3, 3])
        turned = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3] @ prior[:3, :3].T) - 1) / 2, -1, 1)))
        return T if moved < 10.0 and turned < 20.0 else None

    # ------------------------------------------------------------------------------ the detector
    def detect(self, image: Any, context: Mapping[str, Any]) -> Detections:
        """Detections of the model's landmarks in ``image`` ((H, W, 3) uint8 RGB); context: module docstring.

        Raises:
            KeyError: if the context lacks the prior or the intrinsics.
            ValueError: for a malformed image, prior or intrinsics.
        """
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ValueError(f"image must be an (H, W, 3) uint8 RGB array, got shape {img.shape}, dtype {img.dtype}")
        for key in ("prior_cam_from_world", "intrinsics"):
            if key not in context:
                raise KeyError(f"the guided detector needs context[{key!r}]; the context has {sorted(context)}")
        prior = check_transform("context['prior_cam_from_world']", context["prior_cam_from_world"])
        K = check_intrinsics("context['intrinsics']", context["intrinsics"])
        distortion = context.get("distortion")
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
        edges = orientation_field(gray)
        seed = self.seed.detect(img, context) if self.seed is not None else None
        if seed is not None:
            pose = self.pose(self.seed_pairs(seed.uv, prior, K, distortion), K, distortion, prior)
        else:
            warp = self.align(gray, prior, K)
            found = self.match(edges, prior, K, distortion, warp, self.search_px)
            pose = self.pose(found, K, distortion, prior)
        found = (self.match(edges, pose, K, distortion, np.eye(3), self.refine_search_px) if pose is not None
                 else _Matches(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64)))
        uv, scores = _merged(found, seed, self.exclusion_px)
        return Detections(uv=uv, scores=scores, true_ids=self._true_ids(uv, context))

    def _true_ids(self, uv: NDArray[np.float64], context: Mapping[str, Any]) -> NDArray[np.int64] | None:
        """Scoring bookkeeping: the visible true landmark within ``match_px`` of each detection, else -1."""
        from localization.detect.learned import match_detections

        truth = context.get("landmarks", {}).get(self.landmarks)
        if truth is None:
            return None
        visible = np.asarray(truth["visible"], dtype=bool).reshape(-1)
        ids = np.asarray(truth["ids"]).astype(np.int64).reshape(-1)
        gt_uv = np.asarray(truth["uv"], dtype=np.float64).reshape(-1, 2)
        match, _ = match_detections(uv, gt_uv[visible], self.match_px)
        true_ids = np.full(len(match), -1, dtype=np.int64)
        true_ids[match >= 0] = ids[visible][match[match >= 0]]
        return true_ids

    def __repr__(self) -> str:
        return (f"GuidedDetector(landmarks={self.landmarks!r}, M={len(self.xyz)}, patch_px={self.patch_px}, "
                f"search_px={self.search_px}, min_score={self.min_score}, "
                f"max_second_ratio={self.max_second_ratio})")


def _merged(found: _Matches, seed: Detections | None, radius: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The seed's detections and the matches farther than ``radius`` from every one of them.

    A landmark both found keeps the seed's position (the learned refiner places corners to
    about half a pixel); the matches add the landmarks the seed missed.
    """
    if seed is None or len(seed) == 0:
        order = np.argsort(-found.score, kind="stable")
        return found.uv[order], found.score[order]
    seed_scores = seed.scores if seed.scores is not None else np.ones(len(seed))
    if len(found.uv) == 0:
        return seed.uv, seed_scores
    gap = np.hypot(*(found.uv[:, None, :] - seed.uv[None, :, :]).transpose(2, 0, 1)).min(axis=1)
    new = gap > radius
    return np.vstack([seed.uv, found.uv[new]]), np.concatenate([seed_scores, found.score[new]])
