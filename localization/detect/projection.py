"""The projection detector: ground-truth projections with noise, misses and clutter.

An ablation that isolates association and pose from detection: it reads the landmark truth the
simulator provides (``context``), keeps the visible landmarks, perturbs them with Gaussian pixel
noise, drops a fraction and adds uniform false detections, all from a seeded generator.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from localization.checks import check_number
from localization.detect.interface import Detections, check_image_size
from localization.geometry.transforms import as_points

__all__ = ["ProjectionDetector"]


class ProjectionDetector:
    """Simulated detector: ground-truth projections of visible landmarks, with noise and errors.

    It stands for a trained detector when a study wants to isolate association and pose. Each
    visible landmark is detected with probability ``1 - miss_rate`` at its true projection plus
    isotropic Gaussian noise of ``pixel_sigma`` px; a Poisson number (mean ``false_positives``) of
    clutter detections is placed uniformly inside the image; the result is shuffled, so detections
    are anonymous (``true_ids`` keeps the ground truth for scoring only).

    Args:
        landmarks: name of the landmark set in ``context["landmarks"]``.
        pixel_sigma: standard deviation of the pixel noise per axis, px.
        miss_rate: probability in [0, 1] that a visible landmark is not detected.
        false_positives: mean number of clutter detections per image (Poisson), >= 0.
        rng: the random generator to draw from (required for reproducibility; a fresh
            ``np.random.default_rng()`` is used only if None).
    """

    def __init__(
        self,
        landmarks: str = "column_tops",
        pixel_sigma: float = 1.0,
        miss_rate: float = 0.0,
        false_positives: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        if not isinstance(landmarks, str):
            raise TypeError(f"landmarks must be a landmark-set name (str), got {landmarks!r}")
        pixel_sigma = check_number("pixel_sigma", pixel_sigma, 0.0)
        miss_rate = check_number("miss_rate", miss_rate, 0.0, 1.0)
        false_positives = check_number("false_positives", false_positives, 0.0)
        if rng is not None and not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.landmarks = landmarks
        self.pixel_sigma = float(pixel_sigma)
        self.miss_rate = float(miss_rate)
        self.false_positives = float(false_positives)
        self.rng = rng if rng is not None else np.random.default_rng()

    def detect(self, image: Any, context: Mapping[str, Any]) -> Detections:
        """Detections for the landmark set ``self.landmarks`` (``image`` is ignored).

        Raises:
            KeyError: if the context lacks the landmark set or the image size.
            ValueError: if the landmark arrays have inconsistent shapes.
        """
        if not isinstance(context, (dict, Mapping)):  # a dict is checked without the ABC
            raise TypeError(f"context must be a mapping, got {type(context).__name__}")
        try:
            gt = context["landmarks"][self.landmarks]
        except KeyError:
            have = list(context.get("landmarks", {}).keys()) if "landmarks" in context else []
            raise KeyError(
                f"context['landmarks'] has no set {self.landmarks!r}; available: {have}"
            ) from None
        if "image_size" not in context:
            raise KeyError("context must hold 'image_size' = (W, H)")
        w, h = check_image_size("context['image_size']", context["image_size"])
        uv_all = as_points(f"landmarks[{self.landmarks!r}]['uv']", gt["uv"], 2)
        ids_all = np.asarray(gt["ids"]).astype(np.int64).reshape(-1)
        visible = np.asarray(gt["visible"], dtype=bool).reshape(-1)
        if not (uv_all.shape[0] == ids_all.shape[0] == visible.shape[0]):
            raise ValueError(
                f"landmark arrays disagree in length: uv {uv_all.shape[0]}, "
                f"ids {ids_all.shape[0]}, "
                f"visible {visible.shape[0]}"
            )
        rng = self.rng
        keep = visible & np.isfinite(uv_all[:, 0]) & np.isfinite(uv_all[:, 1])
        if self.miss_rate > 0:
            keep &= rng.random(keep.shape[0]) >= self.miss_rate
        uv = uv_all[keep] + rng.normal(0.0, self.pixel_sigma, size=(int(np.count_nonzero(keep)), 2))
        ids = ids_all[keep]
        n_fp = int(rng.poisson(self.false_positives)) if self.false_positives > 0 else 0
        if n_fp:
            clutter = rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], size=(n_fp, 2))
            uv = np.vstack([uv, clutter])
            ids = np.concatenate([ids, np.full(n_fp, -1, dtype=np.int64)])
        order = rng.permutation(uv.shape[0])
        return Detections._of_checked(uv[order], None, ids[order])  # float64 (N, 2), int64 (N,)
