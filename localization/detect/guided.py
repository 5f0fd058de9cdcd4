"""Stage 1, detection guided by the building model: render the structure at a pose, match the image.

The building model is known before the image is seen. :class:`TemplateMatcher` renders the
model's structure at a camera pose (through a :class:`TemplateSource`, which the simulator
package implements with its rasterizer: ``uav_struct_env.sim.templates``) and finds each landmark
the render shows in the image by matching the structure's edges against the image's gradients
around the landmark's projection ("render and match", the way model-based trackers align
wireframes):

* each landmark in the frame that the model itself does not hide (the render's depth around its
  pixel is not in front of it) gets a ``patch_px`` square render centred on its projection (a
  view whose principal point is moved there);
* the patch's structure (:func:`structure_shading`: every label of the render its own grey
  level, so that its gradients lie on the model's edges) and the image are compared as doubled-angle
  orientation fields of their gradients (:func:`orientation_field`: an edge counts whichever side
  is brighter, and texture, whose orientations scatter, averages out) by normalised correlation
  over ``search_px`` around the projection;
* a peak is kept when it scores at least ``min_score`` and no other local maximum farther than
  ``exclusion_px`` reaches ``max_second_ratio`` of it (an ambiguous peak is dropped, not
  guessed); it is placed to sub-pixel by a parabola through the scores.

Matching from the onboard prior directly does not work: its error (3 m, 5 deg) moves the
landmarks by up to ~150 px and by different amounts (parallax), so a template drawn at the prior
neither sits where the image shows its landmark nor looks quite like it. At a pose within a few
decimetres of the truth (one the localizer estimated from a first set of detections) the
templates and the image agree to a pixel or two, and a search of a few pixels finds the
landmarks a first detector missed: ``uav_struct_env.stack.guided`` composes the two passes.

The templates are pinhole renders; a lens's distortion moves the projections
(:func:`~localization.geometry.distortion.distort_points`) but does not bend the templates.
Visibility comes from the render, never from the ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.detect.interface import check_rgb_image
from localization.geometry.distortion import distort_points, is_pinhole
from localization.geometry.transforms import as_points, check_intrinsics, check_transform, project

__all__ = ["GUIDED_FIT_SIGMA_PX", "Matches", "ModelViews", "TemplateMatcher", "TemplateSource",
           "orientation_field", "structure_shading"]

#: The pixel noise the pose verification assumes for the guided detector's output. Chosen on the
#: train buildings when its template matches landed 1.1-1.2 px RMS from their landmarks (the
#: learned candidates it keeps ~0.56 px): 0.7 px kept one confidently wrong pose there, 1 px let
#: three more through (revit_large_building slab corners), the learned detector's calibrated
#: 0.54 px refused a third of revit_large_building's right poses (26 -> 18 of 40). Kept since the
#: templates were redrawn (label shading, orientation labels): their matches at the true pose now
#: land 0.37-0.46 px RMS from their landmarks on the same buildings.
GUIDED_FIT_SIGMA_PX = 0.7


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
    """Renders the building model.

    ``render(cam_from_world (4, 4), Ks (V, 3, 3), size (W, H)) -> ModelViews``.
    """

    def render(self, cam_from_world: ArrayLike, Ks: ArrayLike, size: tuple[int, int]) -> ModelViews:
        """The model seen from one pose through each of ``Ks``, at ``size`` (W, H)."""
        ...


def structure_shading(views: ModelViews) -> NDArray[np.float32]:
    """(V, H, W) float32 the structure as a grey image whose edges are the model's: one level per label.

    Every label (``uav_struct_env.sim.templates`` labels faces by their orientation) gets its own
    grey level in 0.2-1 (a hash of the label), the background 0.5, so that the image's gradient
    lies where the label changes and points across the boundary, as a photograph's does at a
    structural edge; its :func:`orientation_field` is the template the image is matched against.
    (Gradients of a blurred binary edge map would lie beside each edge, on both sides of it: a
    template drawn that way ties its peak less tightly to the edge.) A depth step within one
    label (a face in front of a parallel one) is not drawn: the image shows it no more than its
    lighting, which is the same on both.
    """
    label = views.label.astype(np.int64)
    level = ((label * 2654435761) % 1000003).astype(np.float32) * np.float32(0.8 / 1000003) + np.float32(0.2)
    level[label < 0] = 0.5
    return level


def orientation_field(gray: NDArray[np.float32], blur_px: float = 1.0,
                      power: float = 0.5) -> NDArray[np.float32]:
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
class Matches:
    """Landmarks found in one image.

    Attributes:
        uv: (N, 2) float64 pixel positions (as delivered: distorted by the lens, if any).
        score: (N,) float64 normalised correlation of each match, in [-1, 1].
        index: (N,) int64 index of the matched landmark in the matcher's model points.
    """

    uv: NDArray[np.float64]
    score: NDArray[np.float64]
    index: NDArray[np.int64]


#: Blur of the templates' structure shading, px (less than the image's 1 px: the model's edges
#: are sharp, the image's are blurred by its optics already). At the true poses of two train
#: buildings (labels per element then) it placed the most corners within 2 px: 501 of 640,
#: against 498 at 0.5 px and 473 at 1 px.
_TEMPLATE_BLUR_PX = 0.7
#: Pixels around a search window that its orientation field's filters read (blur 1 px and Sobel).
_FILTER_BORDER = 6
_NO_MATCHES = Matches(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))


class TemplateMatcher:
    """Finds the model's landmarks near their projections at a pose (see the module docstring).

    Args:
        landmarks_xyz: (M, 3) the landmark set's model points, project frame, m.
        templates: the building model's renderer (:class:`TemplateSource`).
        patch_px: side of each landmark's template render, px.
        search_px: half-size of the search around each projection, px.
        min_score: least normalised correlation of a kept peak.
        max_second_ratio: a peak is ambiguous when another local maximum, farther than
            ``exclusion_px``, reaches this fraction of it.
        exclusion_px: radius around the best peak where a second peak is not a rival, px.

    Raises:
        TypeError: if ``templates`` does not follow :class:`TemplateSource`.
        ValueError: for malformed points or numbers out of range.
    """

    def __init__(
        self,
        landmarks_xyz: ArrayLike,
        templates: TemplateSource,
        *,
        patch_px: int = 48,
        search_px: int = 6,
        min_score: float = 0.3,
        max_second_ratio: float = 0.9,
        exclusion_px: float = 3.0,
    ) -> None:
        if not isinstance(templates, TemplateSource):
            raise TypeError(
                f"templates must have render(cam_from_world, Ks, size), got {type(templates).__name__}"
            )
        self.xyz = as_points("landmarks_xyz", landmarks_xyz, 3)
        self.templates = templates
        self.patch_px = check_number("patch_px", patch_px, 8, integer=True, type_error=ValueError)
        self.search_px = check_number("search_px", search_px, 1, integer=True, type_error=ValueError)
        self.min_score = float(check_number("min_score", min_score, -1.0, 1.0, type_error=ValueError))
        self.max_second_ratio = float(check_number("max_second_ratio", max_second_ratio, 0.0, 1.0,
                                                   type_error=ValueError))
        self.exclusion_px = float(check_number("exclusion_px", exclusion_px, 0.0, type_error=ValueError))

    def find(self, image: ArrayLike, cam_from_world: ArrayLike, K: ArrayLike,
             distortion: ArrayLike | None = None, search_px: int | None = None) -> Matches:
        """The landmarks the model shows at ``cam_from_world``, matched in ``image`` ((H, W, 3) uint8 RGB).

        Args:
            image: the frame.
            cam_from_world: (4, 4) the pose to render the templates at.
            K: (3, 3) intrinsics.
            distortion: the frame's OpenCV distortion coefficients, or None for a pinhole.
            search_px: half-size of the search around each projection, px (None: the
                matcher's ``search_px``; wider for a pose known less well).

        Raises:
            ValueError: for a malformed image, pose or intrinsics, or a ``search_px`` below 1.
        """
        img = check_rgb_image(image)
        T = check_transform("cam_from_world", cam_from_world)
        K = check_intrinsics("K", K)
        r = self.search_px if search_px is None else check_number("search_px", search_px, 1, integer=True,
                                                                   type_error=ValueError)
        h, w = img.shape[:2]
        uv, z = project(K, T, self.xyz)
        inside = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
        idx = np.flatnonzero(inside)
        if len(idx) == 0:
            return _NO_MATCHES
        P = self.patch_px
        # patch pixel (i, j) is image pixel corner + (i, j)
        corner = np.floor(uv[idx]).astype(np.int64) - P // 2
        Ks = np.repeat(K[None], len(idx), axis=0)
        Ks[:, 0, 2] -= corner[:, 0]
        Ks[:, 1, 2] -= corner[:, 1]
        views = self.templates.render(T, Ks, (P, P))
        at = uv[idx] - corner  # each landmark in its patch
        seen = _unhidden(views.depth, at, z[idx])
        if not np.any(seen):
            return _NO_MATCHES
        pred = uv[idx] if is_pinhole(distortion) else distort_points(uv[idx], K, distortion)
        return self._search(img, structure_shading(views), idx, at, pred, seen, r)

    def _search(self, image: NDArray[np.uint8], shading: NDArray[np.float32], idx: NDArray, at: NDArray,
                pred: NDArray, seen: NDArray, r: int) -> Matches:
        """Correlate each seen landmark's template with the image around its projection ``pred``.

        The image's grey levels and orientation field are computed in each search window only
        (with a border for its filters): the windows cover a tenth of a frame or less.
        """
        P = self.patch_px
        b, side = _FILTER_BORDER, P + 2 * r
        out_uv, out_s, out_i = [], [], []
        for k in np.flatnonzero(seen):
            template = orientation_field(shading[k], _TEMPLATE_BLUR_PX)
            if float(np.abs(template).max()) < 1e-3:  # nothing of the structure drawn around it
                continue
            x0, y0 = (int(v) for v in np.round(pred[k] - at[k]).astype(np.int64) - r)
            crop = _grey_crop(image, x0 - b, y0 - b, side + 2 * b)
            if crop is None:  # the search window lies outside the frame
                continue
            window = orientation_field(crop)[b:-b, b:-b]
            scores = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
            x, y, best, second = _peak(scores, self.exclusion_px)
            if best < self.min_score or second > self.max_second_ratio * best:
                continue
            out_uv.append((x0 + x + at[k, 0], y0 + y + at[k, 1]))
            out_s.append(best)
            out_i.append(idx[k])
        if not out_i:
            return _NO_MATCHES
        return Matches(np.array(out_uv, dtype=np.float64), np.array(out_s, dtype=np.float64),
                       np.array(out_i, dtype=np.int64))

    def __repr__(self) -> str:
        return (f"TemplateMatcher(M={len(self.xyz)}, patch_px={self.patch_px}, search_px={self.search_px}, "
                f"min_score={self.min_score}, max_second_ratio={self.max_second_ratio})")


def _grey_crop(image: NDArray[np.uint8], x: int, y: int, size: int) -> NDArray[np.float32] | None:
    """The ``size`` square of ``image`` from ``(x, y)``, grey float32, border-replicated; None outside."""
    h, w = image.shape[:2]
    x1, y1, x2, y2 = max(x, 0), max(y, 0), min(x + size, w), min(y + size, h)
    if x2 <= x1 or y2 <= y1:
        return None
    crop = cv2.cvtColor(np.ascontiguousarray(image[y1:y2, x1:x2]), cv2.COLOR_RGB2GRAY).astype(np.float32)
    pads = (y1 - y, y + size - y2, x1 - x, x + size - x2)
    return cv2.copyMakeBorder(crop, *pads, cv2.BORDER_REPLICATE) if any(pads) else crop


def _unhidden(depth: NDArray[np.float32], at: NDArray, z: NDArray) -> NDArray[np.bool_]:
    """(V,) True where no model surface lies in front of the landmark around its pixel (3 x 3).

    A landmark lies on the surface it belongs to, so the render's depth there is its own (within
    2 % and 5 cm); a nearer surface hides it.
    """
    out = np.zeros(len(at), bool)
    h, w = depth.shape[1:]
    for k, (u, v) in enumerate(np.round(at).astype(np.int64)):
        if 1 <= u < w - 1 and 1 <= v < h - 1:
            out[k] = float(depth[k, v - 1: v + 2, u - 1: u + 2].min()) >= 0.98 * z[k] - 0.05
    return out
