"""Stage 1, detection: what every detector returns and the interface it implements.

:class:`Detections` holds anonymous pixel detections (with optional scores, and the true ids a
simulated detector knows for scoring only); :class:`Detector` is the protocol every detector
follows: ``detect(image, context) -> Detections``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.geometry.transforms import as_points

__all__ = ["Detections", "Detector", "check_image_size", "check_rgb_image"]


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


def check_rgb_image(image: ArrayLike) -> NDArray[np.uint8]:
    """``image`` as an (H, W, 3) uint8 RGB array; ValueError naming its shape and dtype otherwise."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(
            f"image must be an (H, W, 3) uint8 RGB array, got shape {img.shape}, dtype {img.dtype}"
        )
    return img
