"""Stage 1, detection: image (and context) in, anonymous 2D landmark detections out.

Every detector follows the small :class:`Detector` protocol::

    detections = detector.detect(image, context)   # -> Detections

``context`` is a plain mapping. The environment provides, per agent,
``context["landmarks"][set_name]`` -- a dict of arrays ``ids (M,)``, ``xyz (M, 3)``, ``uv (M, 2)``,
``in_frame (M,)`` and ``visible (M,)`` (in frame and not occluded) -- and
``context["image_size"] = (W, H)``. Detectors that read pixels may ignore the context; simulated
detectors such as :class:`ProjectionDetector` may ignore the image.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_number
from localization.geometry import as_points

__all__ = ["Detections", "Detector", "ProjectionDetector", "check_image_size"]


@dataclass(frozen=True, eq=False)
class Detections:
    """Anonymous 2D landmark detections in one image.

    Attributes:
        uv: (N, 2) float64 pixel coordinates (integer pixel centres, v down).
        scores: (N,) float64 confidences, or None when the detector has none.
        true_ids: (N,) int64 ground-truth landmark id of each detection, -1 for a false positive;
            None when unknown (only simulated detectors know it). Never used by the localizer.
    """

    uv: NDArray[np.float64]
    scores: NDArray[np.float64] | None = None
    true_ids: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        uv = as_points("Detections.uv", self.uv, 2)
        object.__setattr__(self, "uv", uv)
        n = uv.shape[0]
        if self.scores is not None:
            scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
            if scores.shape != (n,):
                raise ValueError(f"Detections.scores must have shape ({n},), got {scores.shape}")
            object.__setattr__(self, "scores", scores)
        if self.true_ids is not None:
            ids = np.asarray(self.true_ids)
            if not np.issubdtype(ids.dtype, np.integer):
                raise TypeError(f"Detections.true_ids must be integers, got dtype {ids.dtype}")
            ids = ids.astype(np.int64).reshape(-1)
            if ids.shape != (n,):
                raise ValueError(f"Detections.true_ids must have shape ({n},), got {ids.shape}")
            object.__setattr__(self, "true_ids", ids)

    def __len__(self) -> int:
        return int(self.uv.shape[0])

    @classmethod
    def _of_checked(
        cls, uv: NDArray[np.float64], scores: NDArray[np.float64] | None, true_ids: NDArray[np.int64] | None
    ) -> Detections:
        """Detections of arrays a detector built with the checked dtypes and shapes (no checks).

        ``uv`` float64 (N, 2), ``scores`` float64 (N,) or None, ``true_ids`` int64 (N,) or None.
        """
        out = object.__new__(cls)
        object.__setattr__(out, "uv", uv)
        object.__setattr__(out, "scores", scores)
        object.__setattr__(out, "true_ids", true_ids)
        return out


@runtime_checkable
class Detector(Protocol):
    """Anything with ``detect(image, context) -> Detections``."""

    def detect(self, image: Any, context: Mapping[str, Any]) -> Detections:
        """Detect anonymous landmarks in ``image`` (context: see the module docstring)."""
        ...


def check_image_size(name: str, image_size: Any) -> tuple[int, int]:
    """Return ``image_size`` as ``(W, H)`` positive ints, or raise naming ``name``."""
    if type(image_size) is tuple and len(image_size) == 2:  # the common case, checked quickly
        w, h = image_size
        if type(w) is int and type(h) is int and w > 0 and h > 0:
            return w, h
    try:
        w, h = image_size
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (W, H), got {image_size!r}") from None
    for v in (w, h):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer, float, np.floating)):
            raise TypeError(f"{name} must hold numbers (W, H), got {image_size!r}")
    if not (w > 0 and h > 0) or int(w) != w or int(h) != h:
        raise ValueError(f"{name} must be positive integers (W, H), got {image_size!r}")
    return int(w), int(h)


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
