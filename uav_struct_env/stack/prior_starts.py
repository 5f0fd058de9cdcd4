"""Where the guided detector's wide pass starts when no first pose exists: the model aligned at the prior.

:class:`PriorStarts` aligns the whole building model drawn at the prior with the image
(:class:`~localization.detect.prior_align.PriorAligner`) and corrects each hypothesis by a pose
fitted to the template matches of every structural landmark around it
(:func:`~localization.detect.prior_align.fit_matches`). Neither depends on the landmark set, so
one instance serves every set's guided detector of a site and camera, and remembers the frame's
alignments and fitted poses (:class:`~uav_struct_env.stack.frame_memo.FrameMemo`): the second set
of a frame reuses them.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.detect.guided import TemplateMatcher
from localization.detect.prior_align import PriorAligner, fit_matches
from localization.geometry.transforms import check_intrinsics
from uav_struct_env.stack.frame_memo import FrameMemo

__all__ = ["PriorStarts"]


class PriorStarts:
    """The starts of the wide pass from the prior (module docstring).

    Args:
        aligner: aligns the model drawn at the prior with the image.
        wide: the template matcher of every structural landmark of the stage.
        K: (3, 3) the camera's intrinsics.
        distortion: its OpenCV distortion coefficients, or None for a pinhole.
        search_px: half-size of the template search around an alignment's pose, px.

    Raises:
        TypeError: if ``aligner`` or ``wide`` is not what it should be.
        ValueError: for malformed intrinsics.
    """

    def __init__(self, aligner: PriorAligner, wide: TemplateMatcher, K: ArrayLike,
                 distortion: ArrayLike | None = None, search_px: int = 24) -> None:
        if not isinstance(aligner, PriorAligner) or not isinstance(wide, TemplateMatcher):
            raise TypeError(f"aligner and wide must be a PriorAligner and a TemplateMatcher, got "
                            f"{type(aligner).__name__} and {type(wide).__name__}")
        self.aligner = aligner
        self.wide = wide
        self.K = check_intrinsics("K", K)
        self.distortion = None if distortion is None else np.asarray(distortion, dtype=np.float64)
        self.search_px = search_px
        self._align = FrameMemo(lambda image, prior: self.aligner.align(image, prior, self.K), 1)
        self._refined = FrameMemo(self.refined, 4)

    def __call__(self, image: ArrayLike,
                 prior: NDArray[np.float64]) -> Iterator[tuple[NDArray[np.float64], float]]:
        """``(pose, score)`` of each alignment of the model drawn at ``prior`` with ``image``, best first.

        Each pose is the alignment's corrected by :meth:`refined`, computed when it is reached: the
        alignment moves the structure as one picture, so the building's depth leaves its landmarks
        ten to thirty pixels off.
        """
        for a in self._align(np.asarray(image), np.asarray(prior)):
            yield self._refined(np.asarray(image), a.cam_from_world), a.score

    def refined(self, image: ArrayLike, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """``pose`` corrected by a fit to every structural landmark's matches within ``search_px``."""
        found = self.wide.find(image, pose, self.K, self.distortion, search_px=self.search_px)
        fitted = fit_matches(self.wide.xyz, found, self.K, self.distortion, pose)
        return pose if fitted is None else fitted

    def same_camera(self, K: ArrayLike, distortion: ArrayLike | None) -> bool:
        """Whether these starts are for a camera with ``K`` and ``distortion``."""
        if (distortion is None) != (self.distortion is None):
            return False
        return bool(np.array_equal(np.asarray(K, dtype=np.float64), self.K)) and (
            distortion is None or np.array_equal(np.asarray(distortion, dtype=np.float64), self.distortion))

    def __repr__(self) -> str:
        return f"PriorStarts(aligner={self.aligner!r}, wide={self.wide!r}, search_px={self.search_px})"
