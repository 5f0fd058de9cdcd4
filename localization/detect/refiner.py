"""Stage 1b of the learned detector: full-resolution patch refinement of keypoint candidates.

The keypoint network of :mod:`localization.detect.learned` sees the image at half resolution and
places a landmark with a stride-4 heatmap: most candidates land within a few pixels of the
landmark, but the tail (3-8 px off at full resolution, mostly stair-opening corners whose top
surface meets the opening's inner face with little contrast) is too coarse for a 3-pixel
tolerance. :class:`PatchRefiner` looks again, at full resolution, at a small patch around
every candidate: a small CNN (trained by :mod:`uav_struct_env.training.train_refiner`; each named
weight set of :mod:`localization.detect.weights` has one) returns, per landmark type, the
probability that a landmark of that type lies within :data:`POSITIVE_RADIUS` px of the patch
centre and its offset from the centre.
Refinement is iterated (the patch is re-centred on the previous estimate), and the score of the
last pass lets the detector drop candidates that are not landmarks.

Patch convention: a patch is the ``PATCH x PATCH`` (odd) block of pixels centred on the
candidate's nearest pixel ``a = round(uv)`` (pixel centres at integer coordinates, as everywhere
in this package; borders replicated), so patch cell ``(HALF, HALF)`` is pixel ``a`` and the
refined position is ``a + (du, dv)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.detect.onnx_net import OnnxNet
from localization.detect.weights import weight_set
from localization.geometry.transforms import as_points

__all__ = ["DEFAULT_REFINER", "HALF", "PATCH", "POSITIVE_RADIUS", "PatchRefiner", "extract_patches"]


#: Side of a refinement patch (odd, so that the candidate pixel is its centre), px.
PATCH = 33


HALF = PATCH // 2


#: A patch is a positive for a type when a landmark of that type lies this close to its centre.
POSITIVE_RADIUS = 10.0


#: The default weights' refiner (:data:`localization.detect.weights.DEFAULT_WEIGHTS`).
DEFAULT_REFINER = weight_set().refiner


def extract_patches(
    image: NDArray[np.uint8], centers: ArrayLike, size: int = PATCH
) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Patches ``(N, size, size, C)`` centred on the nearest pixels of ``centers`` ``(N, 2)``.

    Returns the patches and their integer anchors ``(N, 2)`` (u, v). Pixels outside the image
    replicate the border.
    """
    if size % 2 != 1 or size < 3:
        raise ValueError(f"patch size must be an odd number >= 3, got {size!r}")
    img = np.asarray(image)
    if img.ndim != 3:
        raise ValueError(f"image must be an (H, W, C) array, got shape {img.shape}")
    pts = as_points("centers", centers, 2)
    anchors = np.round(pts).astype(np.int64)
    half = size // 2
    h, w = img.shape[:2]
    out = np.empty((len(anchors), size, size, img.shape[2]), img.dtype)
    offs = np.arange(-half, half + 1)
    for k, (u, v) in enumerate(anchors):
        if half <= u < w - half and half <= v < h - half:
            out[k] = img[v - half:v + half + 1, u - half:u + half + 1]
        else:  # clamp indices: border replication
            rows = np.clip(v + offs, 0, h - 1)
            cols = np.clip(u + offs, 0, w - 1)
            out[k] = img[rows[:, None], cols[None, :]]
    return out, anchors


class PatchRefiner:
    """Refine and re-score keypoint candidates on full-resolution patches (module docstring).

    Args:
        model: path of the refiner's ONNX model (default :data:`DEFAULT_REFINER`). Input
            ``(N, 3, PATCH, PATCH)`` float RGB 0-255; output ``(N, 3 * 3)``: per landmark type
            (channel order of :data:`localization.detect.learned.LANDMARK_TYPES`) the probability of a
            landmark within :data:`POSITIVE_RADIUS` px, then its offset ``(du, dv)`` in px.
        iterations: most refinement passes; each re-centres the patch on the previous estimate.
        recentre_px: a candidate whose estimate lies within this distance of its patch centre
            is final (a further pass would see nearly the same patch).
        threads: ONNX Runtime threads (:class:`localization.detect.onnx_net.OnnxNet`).

    Raises:
        FileNotFoundError: the model file does not exist. ValueError: ``iterations < 1``.
    """

    def __init__(self, model: str | Path | None = None, iterations: int = 2,
                 recentre_px: float = 0.5, threads: int = 1) -> None:
        path = Path(DEFAULT_REFINER if model is None else model)
        if not path.is_file():
            raise FileNotFoundError(f"refiner model not found: {path}")
        self.model_path = path
        self.iterations = check_number("iterations", iterations, 1, integer=True, type_error=ValueError)
        self.recentre_px = check_number("recentre_px", recentre_px, 0.0, type_error=ValueError)
        self._net = OnnxNet(path, threads)

    def predict(self, image: NDArray[np.uint8], uv: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """One pass: ``(anchors (N, 2), probabilities (N, 3), offsets (N, 3, 2))``."""
        patches, anchors = extract_patches(image, uv)
        if len(anchors) == 0:
            return anchors, np.zeros((0, 3)), np.zeros((0, 3, 2))
        out = self._net(patches.transpose(0, 3, 1, 2)).astype(np.float64).reshape(len(anchors), 9)
        return anchors, out[:, :3], out[:, 3:].reshape(-1, 3, 2)

    def refine(
        self, image: NDArray[np.uint8], uv: ArrayLike, types: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Refined positions ``(N, 2)`` and scores ``(N,)`` of candidates of the given types.

        ``types (N,)`` are indices of :data:`localization.detect.learned.LANDMARK_TYPES`. The score is
        the last pass's probability that a landmark of the candidate's type lies near it.
        """
        pts = as_points("uv", uv, 2).copy()
        kinds = np.asarray(types, dtype=np.int64).reshape(-1)
        if len(kinds) != len(pts):
            raise ValueError(f"types has {len(kinds)} entries for {len(pts)} candidates")
        scores = np.zeros(len(pts))
        active = np.arange(len(pts))
        for _ in range(self.iterations):
            if len(active) == 0:
                break
            anchors, prob, off = self.predict(image, pts[active])
            rows = np.arange(len(active))
            shift = off[rows, kinds[active]]
            pts[active] = anchors + shift
            scores[active] = prob[rows, kinds[active]]
            active = active[np.hypot(shift[:, 0], shift[:, 1]) > self.recentre_px]
        return pts, scores

    def __repr__(self) -> str:
        return (f"PatchRefiner(model={self.model_path.name!r}, iterations={self.iterations}, "
                f"recentre_px={self.recentre_px})")
