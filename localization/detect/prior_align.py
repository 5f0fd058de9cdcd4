"""Stage 1, the building model aligned with the image from the onboard prior alone.

Where no detection gives a first pose, the prior (GNSS and attitude: metres of position, a few
degrees of attitude) still says roughly where the building stands in the frame: its landmarks
project tens to a couple of hundred pixels off, too far for a template search around each, but
the whole structure drawn at the prior is one large, known pattern. :class:`PriorAligner` finds
where that pattern lies in the image (the way model-based trackers and LoD-Loc align a
wireframe, coarse to fine):

* the model is rendered once at the prior at a reduced resolution (``scale``, a quarter), as the
  label-shaded structure whose gradients lie on the model's edges
  (:func:`~localization.detect.guided.structure_shading`);
* its orientation field (:func:`~localization.detect.guided.orientation_field`), cropped to the
  structure, zoomed and turned about the principal point (the prior's error along the line of
  sight changes the building's size in the frame by up to ~15 %, its attitude error turns it by
  a few degrees, up to ~13 on the train buildings), is correlated with the image's over shifts up
  to ``search_px``: first at half that resolution over a grid of ``zooms`` x ``angles_deg``, then
  twice more finely around the best peaks (zoom 3.3 % and 4 deg steps, then 1.6 % and 2 deg),
  and last for the shift alone at the alignment's resolution;
* the best peaks, distinct in shift, are the hypotheses: each is an image motion
  ``u' = c + d + s R (u - c)`` (zoom ``s`` and rotation ``R`` about the principal point ``c``,
  shift ``d``) of the structure drawn at the prior, turned into a camera pose by PnP from points
  of the model's surface (read from the render's depth) to where that motion moves them,
  starting at the prior.

A hypothesis only says where to look: its pose is the prior's moved as one picture, so the
building's depth (parallax) still leaves its landmarks ten to thirty pixels off. The guided
detector (``uav_struct_env.stack.guided``) searches the templates around them from it and fits a
pose to their matches (:func:`fit_matches`) before its wide pass; what it reports still comes
from the association, PnP and verification of the stack. :meth:`PriorAligner.score` measures how
well the model drawn at any pose lies on the image, the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.detect.guided import Matches, TemplateSource, orientation_field, structure_shading
from localization.detect.interface import check_rgb_image
from localization.geometry.transforms import (
    as_points,
    check_intrinsics,
    check_transform,
    project,
    scaled_intrinsics,
)
from localization.pose.pnp import pose_from_rt

__all__ = ["Alignment", "PriorAligner", "fit_matches"]

#: Blur of the model's shading before its orientation field, px at the reduced resolution.
_MODEL_BLUR_PX = 0.7
#: Most model surface points the pose of a hypothesis is fitted to.
_SURFACE_POINTS = 64


@dataclass(frozen=True)
class Alignment:
    """One hypothesis of where the model lies in the image.

    Attributes:
        cam_from_world: (4, 4) the pose that draws the model there.
        score: normalised correlation of the model's and the image's orientation fields, [-1, 1].
        zoom: the hypothesis's zoom of the structure drawn at the prior.
        angle_deg: its rotation in the image, deg.
        shift_px: (2,) its shift, full-resolution px.
    """

    cam_from_world: NDArray[np.float64]
    score: float
    zoom: float
    angle_deg: float
    shift_px: NDArray[np.float64]


class PriorAligner:
    """Aligns the building model drawn at the prior with the image (see the module docstring).

    Args:
        templates: the building model's renderer (a
            :class:`~localization.detect.guided.TemplateSource`).
        scale: resolution of the alignment, a fraction of the frame's.
        zooms: the zooms of the structure tried.
        angles_deg: its rotations in the image tried, deg (the prior's roll, and its yaw and pitch
            seen obliquely, turn the building in the frame by up to ~13 deg).
        search_px: largest shift searched, full-resolution px.
        n_hypotheses: most hypotheses returned.
        min_separation_px: least shift between two hypotheses, full-resolution px.
        min_score: least correlation of a hypothesis.

    Raises:
        TypeError: if ``templates`` does not follow the TemplateSource protocol.
        ValueError: for numbers out of range.
    """

    def __init__(self, templates: TemplateSource, *, scale: float = 0.25,
                 zooms: tuple[float, ...] = (0.84, 0.92, 1.0, 1.08, 1.16),
                 angles_deg: tuple[float, ...] = (-8.0, 0.0, 8.0), search_px: int = 320,
                 n_hypotheses: int = 2, min_separation_px: float = 24.0, min_score: float = 0.05) -> None:
        if not isinstance(templates, TemplateSource):
            raise TypeError(
                f"templates must have render(cam_from_world, Ks, size), got {type(templates).__name__}"
            )
        self.templates = templates
        self.scale = float(check_number("scale", scale, 0.05, 1.0, type_error=ValueError))
        self.zooms = tuple(float(check_number("zoom", z, 0.5, 2.0, type_error=ValueError)) for z in zooms)
        self.angles_deg = tuple(float(check_number("angle_deg", a, -45.0, 45.0, type_error=ValueError))
                                for a in angles_deg)
        self.angles = tuple(np.radians(a) for a in self.angles_deg)
        if not self.zooms or not self.angles:
            raise ValueError(f"zooms and angles_deg must hold a value each, got {zooms}, {angles_deg}")
        self.search_px = check_number("search_px", search_px, 1, integer=True, type_error=ValueError)
        self.n_hypotheses = check_number("n_hypotheses", n_hypotheses, 1, integer=True, type_error=ValueError)
        self.min_separation_px = float(check_number("min_separation_px", min_separation_px, 0.0,
                                                    type_error=ValueError))
        self.min_score = float(check_number("min_score", min_score, -1.0, 1.0, type_error=ValueError))
        self._last: tuple[NDArray[np.uint8], tuple[int, int], NDArray[np.float32]] | None = None

    def align(self, image: ArrayLike, prior_cam_from_world: ArrayLike, K: ArrayLike) -> list[Alignment]:
        """Hypotheses of the model's place in ``image`` ((H, W, 3) uint8 RGB), best first; [] without any.

        Args:
            image: the frame.
            prior_cam_from_world: (4, 4) the onboard prior.
            K: (3, 3) the frame's intrinsics.

        Raises:
            ValueError: for a malformed image, pose or intrinsics.
        """
        img = check_rgb_image(image)
        prior = check_transform("prior_cam_from_world", prior_cam_from_world)
        K = check_intrinsics("K", K)
        level, surface = self._level(img, prior, K)
        if level is None:  # the model is (almost) out of the frame at the prior
            return []
        q = level.field.shape[1] / img.shape[1]
        half = level.halved()
        out: list[Alignment] = []
        for motion in self._coarse(half, q / 2):
            for steps in _FINE_STEPS:
                _, motion = half.refine(motion, steps, _FINE_RADIUS)
            score, motion = level.refine(motion.scaled(2.0), _SHIFT_ONLY, _FINE_RADIUS)
            full = _Motion(motion.zoom, motion.angle, motion.shift / q)
            if score < self.min_score or any(
                    np.hypot(*(full.shift - a.shift_px)) < self.min_separation_px for a in out):
                continue
            pose = _moved_pose(prior, K, surface, full)
            if pose is not None:
                out.append(Alignment(pose, score, full.zoom, float(np.degrees(full.angle)), full.shift))
            if len(out) == self.n_hypotheses:
                break
        out.sort(key=lambda a: -a.score)
        return out

    def score(self, image: ArrayLike, cam_from_world: ArrayLike, K: ArrayLike) -> float:
        """How well the model drawn at ``cam_from_world`` lies on the image (-1 without the model).

        The correlation of the two orientation fields at the alignment's resolution, within one of
        its pixels; the same measure as a hypothesis's ``score``, so a pose that places the model
        better than a hypothesis did scores higher.
        """
        img = check_rgb_image(image)
        T = check_transform("cam_from_world", cam_from_world)
        K = check_intrinsics("K", K)
        level, _ = self._level(img, T, K)
        if level is None:
            return -1.0
        peaks = level.peaks(_Motion(1.0, 0.0, np.zeros(2)), 1, np.inf)
        return peaks[0][0] if peaks else -1.0

    def _level(self, img: NDArray[np.uint8], cam_from_world: NDArray[np.float64],
               K: NDArray[np.float64]) -> tuple[_Level | None, NDArray[np.float64]]:
        """The fields of the image and of the model drawn at ``cam_from_world``, and points of its surface.

        ``(None, empty)`` when the model covers fewer than 16 pixels of the frame at the alignment's
        resolution.
        """
        h, w = img.shape[:2]
        size = (max(int(round(w * self.scale)), 16), max(int(round(h * self.scale)), 16))
        Kq = scaled_intrinsics(K, size[0] / w, size[1] / h)
        views = self.templates.render(cam_from_world, Kq[None], size)
        model = views.label[0] >= 0
        if model.sum() < 16:
            return None, np.zeros((0, 3))
        ys, xs = np.nonzero(model)
        x0, y0 = max(int(xs.min()) - 2, 0), max(int(ys.min()) - 2, 0)
        x1, y1 = min(int(xs.max()) + 3, size[0]), min(int(ys.max()) + 3, size[1])
        crop = orientation_field(structure_shading(views)[0], _MODEL_BLUR_PX)[y0:y1, x0:x1]
        level = _Level(self._image_field(img, size), crop, np.array([x0, y0], dtype=np.float64), Kq[:2, 2])
        return level, _surface_points(views.depth[0], model, Kq, cam_from_world)

    def _image_field(self, img: NDArray[np.uint8], size: tuple[int, int]) -> NDArray[np.float32]:
        """The orientation field of ``img`` at ``size``; the last one is kept (one frame's calls share it)."""
        if self._last is not None and self._last[0] is img and self._last[1] == size:
            return self._last[2]
        small = cv2.cvtColor(cv2.resize(img, size, interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
        field = orientation_field(small.astype(np.float32))
        self._last = (img, size, field)
        return field

    def _coarse(self, level: _Level, q: float) -> list[_Motion]:
        """The best motions at ``level`` (``q`` of the frame's resolution), distinct in shift, best first."""
        R = max(int(round(self.search_px * q)), 1)
        sep = self.min_separation_px * q
        peaks = []
        for zoom in self.zooms:
            for angle in self.angles:
                peaks += level.peaks(_Motion(zoom, angle, np.zeros(2)), R, sep)
        peaks.sort(key=lambda p: -p[0])
        out: list[_Motion] = []
        for _, m in peaks:
            if all(np.hypot(*(m.shift - o.shift)) >= 2 * sep for o in out):
                out.append(m)
        return out[: self.n_hypotheses]

    def __repr__(self) -> str:
        return (f"PriorAligner(scale={self.scale}, zooms={self.zooms}, angles_deg={self.angles_deg}, "
                f"search_px={self.search_px}, n_hypotheses={self.n_hypotheses})")


#: The fine level's steps around a coarse peak (zoom factor, rotation in rad), and its shift
#: radius (alignment px).
_FINE_STEPS = tuple(tuple((1.0 + z, np.radians(a)) for z in (-dz, 0.0, dz) for a in (-da, 0.0, da))
                    for dz, da in ((0.033, 4.0), (0.016, 2.0)))
_FINE_RADIUS = 2
_SHIFT_ONLY = ((1.0, 0.0),)


@dataclass(frozen=True, eq=False)
class _Motion:
    """An image motion of the structure drawn at the prior: ``u' = c + shift + zoom R(angle) (u - c)``."""

    zoom: float
    angle: float  # rad, image coordinates (x right, y down)
    shift: NDArray[np.float64]

    def scaled(self, factor: float) -> _Motion:
        """The same motion at ``factor`` times the resolution."""
        return _Motion(self.zoom, self.angle, factor * self.shift)

    def matrix(self) -> NDArray[np.float64]:
        """(2, 2) ``zoom R(angle)``."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        return self.zoom * np.array([[c, -s], [s, c]])

    def apply(self, uv: NDArray[np.float64], centre: NDArray[np.float64]) -> NDArray[np.float64]:
        """(N, 2) the motion of ``uv`` (N, 2) about ``centre``."""
        return centre + self.shift + (uv - centre) @ self.matrix().T


@dataclass(frozen=True, eq=False)
class _Level:
    """The image's and the model's orientation fields at one resolution.

    Attributes:
        field: (H, W, 2) the image's.
        crop: (h, w, 2) the model's, cropped to the structure.
        origin: (2,) the crop's top-left in the frame at this resolution, px.
        centre: (2,) the principal point at this resolution, px.
    """

    field: NDArray[np.float32]
    crop: NDArray[np.float32]
    origin: NDArray[np.float64]
    centre: NDArray[np.float64]

    def halved(self) -> _Level:
        """The same at half the resolution."""
        def half(a: NDArray[np.float32]) -> NDArray[np.float32]:
            size = (max(a.shape[1] // 2, 1), max(a.shape[0] // 2, 1))
            return cv2.resize(a, size, interpolation=cv2.INTER_AREA)
        # pixel x here is (x + 0.5) / 2 - 0.5 there; the crop's pixel pairs start at its origin
        return _Level(half(self.field), half(self.crop), self.origin / 2, (self.centre + 0.5) / 2 - 0.5)

    def template(self, motion: _Motion) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
        """The crop moved by ``motion`` without its shift: ``(template, its top-left in the frame)``.

        The orientation field's vectors are doubled angles: a rotation by ``a`` turns them by ``2 a``.
        """
        M = motion.matrix()
        h, w = self.crop.shape[:2]
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
        moved = self.centre + (corners + self.origin - self.centre) @ M.T
        top_left = np.floor(moved.min(axis=0))
        tw, th = (max(int(v), 4) for v in np.ceil(moved.max(axis=0) - top_left) + 1)
        offset = M @ (self.origin - self.centre) + self.centre - top_left
        warped = cv2.warpAffine(self.crop, np.hstack([M, offset[:, None]]), (tw, th), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        if motion.angle != 0.0:
            c, s = np.cos(2 * motion.angle), np.sin(2 * motion.angle)
            a, b = warped[..., 0].copy(), warped[..., 1].copy()
            warped[..., 0], warped[..., 1] = c * a - s * b, s * a + c * b
        return warped, top_left

    def peaks(self, motion: _Motion, radius: int, sep: float) -> list[tuple[float, _Motion]]:
        """``(score, motion)``: the best peak within ``radius`` of ``motion``'s shift, one ``sep`` away."""
        template, top_left = self.template(motion)
        th, tw = template.shape[:2]
        ex, ey = (int(v) for v in np.round(top_left + motion.shift))
        H, W = self.field.shape[:2]
        # the window: the template within radius of its place, clipped to the field padded by radius
        px0, py0 = max(ex - radius, -radius), max(ey - radius, -radius)
        px1, py1 = min(ex + radius + tw, W + radius), min(ey + radius + th, H + radius)
        if px1 - px0 < tw or py1 - py0 < th:
            return []
        scores = cv2.matchTemplate(_padded(self.field, px0, py0, px1, py1), template, cv2.TM_CCOEFF_NORMED)
        return [(best, _Motion(motion.zoom, motion.angle, np.array([px0 + bx, py0 + by], dtype=np.float64)
                               - top_left)) for bx, by, best in _two_peaks(scores, sep)]

    def refine(self, motion: _Motion, steps: tuple[tuple[float, float], ...],
               radius: int) -> tuple[float, _Motion]:
        """The best ``(score, motion)`` near a coarse one.

        ``steps``: (zoom factor, added angle) pairs; shifts within ``radius``.
        """
        best: tuple[float, _Motion] = (-2.0, motion)
        for zoom, angle in steps:
            near = _Motion(motion.zoom * zoom, motion.angle + angle, motion.shift)
            for score, m in self.peaks(near, radius, np.inf):
                if score > best[0]:
                    best = (score, m)
        return best


def _padded(field: NDArray[np.float32], x0: int, y0: int, x1: int, y1: int) -> NDArray[np.float32]:
    """``field[y0:y1, x0:x1]``, zeros where that lies outside it."""
    H, W = field.shape[:2]
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    inner = field[cy0:cy1, cx0:cx1]
    pads = (cy0 - y0, y1 - cy1, cx0 - x0, x1 - cx1)
    if not any(pads):
        return np.ascontiguousarray(inner)
    return cv2.copyMakeBorder(np.ascontiguousarray(inner), *pads, cv2.BORDER_CONSTANT, value=0)


def _two_peaks(scores: NDArray[np.float32], sep: float) -> list[tuple[int, int, float]]:
    """The best ``(x, y, score)`` of a correlation map and the best one farther than ``sep`` from it."""
    _, best, _, (bx, by) = cv2.minMaxLoc(scores)
    if not np.isfinite(sep):
        return [(bx, by, float(best))]
    r = int(np.ceil(sep))
    away = scores.copy()
    away[max(0, by - r): by + r + 1, max(0, bx - r): bx + r + 1] = -1.0
    _, second, _, (sx, sy) = cv2.minMaxLoc(away)
    return [(bx, by, float(best)), (sx, sy, float(second))]


def _surface_points(depth: NDArray[np.float32], model: NDArray[np.bool_], Kq: NDArray[np.float64],
                    cam_from_world: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 3) points of the model's surface seen in a render (up to ``_SURFACE_POINTS``), project frame."""
    ys, xs = np.nonzero(model)
    pick = np.linspace(0, len(xs) - 1, min(_SURFACE_POINTS, len(xs))).astype(np.int64)
    x, y = xs[pick].astype(np.float64), ys[pick].astype(np.float64)
    z = depth[ys[pick], xs[pick]].astype(np.float64)
    cam = np.stack([(x - Kq[0, 2]) / Kq[0, 0] * z, (y - Kq[1, 2]) / Kq[1, 1] * z, z], axis=1)
    R, t = cam_from_world[:3, :3], cam_from_world[:3, 3]
    return (cam - t) @ R


def _moved_pose(prior: NDArray[np.float64], K: NDArray[np.float64], xyz: NDArray[np.float64],
                motion: _Motion) -> NDArray[np.float64] | None:
    """The pose that moves the projections of ``xyz`` at ``prior`` by ``motion`` (about ``K``'s centre)."""
    uv, _ = project(K, prior, xyz)
    target = motion.apply(uv, K[:2, 2])
    rvec, _ = cv2.Rodrigues(prior[:3, :3])
    tvec = prior[:3, 3].reshape(3, 1).copy()
    ok, rvec, tvec = cv2.solvePnP(xyz, target, K, None, rvec, tvec, useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or not np.all(np.isfinite(tvec)):
        return None
    return pose_from_rt(rvec, tvec)


def fit_matches(landmarks_xyz: ArrayLike, found: Matches, K: ArrayLike, distortion: ArrayLike | None,
                guess_cam_from_world: ArrayLike, reprojection_px: float = 3.0,
                min_inliers: int = 4) -> NDArray[np.float64] | None:
    """The pose that fits the matched landmarks (RANSAC PnP from ``guess``), or None with too few inliers.

    Args:
        landmarks_xyz: (M, 3) the matcher's model points, project frame, m.
        found: matches of those points (their ``index``), as delivered (distorted).
        K: (3, 3) intrinsics.
        distortion: the frame's OpenCV distortion coefficients, or None.
        guess_cam_from_world: (4, 4) the pose the matches were searched around.
        reprojection_px: inlier threshold, px.
        min_inliers: least inliers of a pose.
    """
    xyz = as_points("landmarks_xyz", landmarks_xyz, 3)
    if len(found.index) < max(min_inliers, 4):
        return None
    guess = check_transform("guess_cam_from_world", guess_cam_from_world)
    rvec, _ = cv2.Rodrigues(guess[:3, :3])
    tvec = guess[:3, 3].reshape(3, 1).copy()
    dist = None if distortion is None else np.asarray(distortion, dtype=np.float64)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        xyz[found.index], found.uv, np.asarray(K, dtype=np.float64), dist, rvec, tvec, useExtrinsicGuess=True,
        iterationsCount=100, reprojectionError=reprojection_px, flags=cv2.SOLVEPNP_ITERATIVE,
    )
    if not ok or inliers is None or len(inliers) < min_inliers or not np.all(np.isfinite(tvec)):
        return None
    return pose_from_rt(rvec, tvec)
