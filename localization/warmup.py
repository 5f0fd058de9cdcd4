"""Compile, or load from numba's on-disk cache, every compiled kernel before anything is timed.

The kernels (``*_kernels.py``, ``geometry/kernels.py``, ``pose/lm.py``, ...) compile on their
first call and are cached beside the installed package (``cache=True``; numba falls back to a
user cache folder where the package is read-only), so only the first process after an install
pays the compilation -- a minute or two on a 2-core machine -- and later ones load them in a
fraction of a second. A command that times localizations calls :func:`warm_up` first, so that
neither the compilation nor the loading lands in a latency figure, and says so in one line when
the kernels are not yet cached (:func:`kernels_cached`) rather than sitting silently at 0 %.

:func:`warm_up` runs the localizer on a small synthetic scene the way a study frame does: both
association modes, clean detections and detections with misses and clutter (the layout vote and
the rival search), a warm start, detection scores and lens distortion, and the metrics.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import time
from collections.abc import Callable

import numpy as np

import localization
from localization.associate.upright import upright_two_point
from localization.detect.interface import Detections
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import look_at, project, quat_wxyz_from_matrix
from localization.metrics import association_scores, pose_errors
from localization.pipeline import Localizer
from localization.testing.synthetic import paper_prior

__all__ = ["compiled_kernels", "kernels_cached", "warm_up"]

#: What :func:`warm_up` says before a first compilation.
COMPILING = ("compiling the localization kernels once (1-2 min on 2 cores; cached beside the "
             "package, later runs load them in about a second) ...")


def compiled_kernels() -> list:
    """Every numba dispatcher defined in the ``localization`` package (its modules imported)."""
    out = []
    for info in pkgutil.walk_packages(localization.__path__, "localization."):
        module = importlib.import_module(info.name)
        for value in vars(module).values():
            if hasattr(value, "py_func") and hasattr(value, "signatures") and value.__module__ == info.name:
                out.append(value)
    return out


def kernels_cached() -> bool:
    """Whether numba's on-disk cache holds an index for every compiled kernel of the package.

    False when any index is missing (a fresh install, an edited kernel) or when this numba does not
    expose where its cache lives.
    """
    for dispatcher in compiled_kernels():
        try:
            index = dispatcher._cache._cache_file._index_path
        except AttributeError:
            return False
        if not os.path.exists(index):
            return False
    return True


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A 3 x 4 column grid (tops at 7 m) and a slab's four corners (3.5 m): (M, 3) each."""
    xs, ys = np.meshgrid([0.0, 4.0, 8.0], [0.0, 4.0, 7.0, 11.0])
    tops = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 7.0)])
    slab = np.array([[-0.3, -0.3, 3.5], [8.3, -0.3, 3.5], [8.3, 11.3, 3.5], [-0.3, 11.3, 3.5]])
    return tops + rng.normal(0.0, 1e-3, tops.shape), slab


def _localize_views(landmarks: np.ndarray, K: np.ndarray, rng: np.random.Generator, **kwargs) -> None:
    views = [look_at([4.0 + dx, -20.0, 15.0], [4.0, 5.5, 4.0]) for dx in (-6.0, 0.0, 6.0)]
    for association in ("robust", "paper"):
        loc = Localizer(landmarks, K, association=association, image_size=PAPER_IMAGE_SIZE, **kwargs)
        for k, truth in enumerate(views):
            uv, _ = project(K, truth, landmarks)
            clean = uv + rng.normal(0.0, 1.0, uv.shape)
            cluttered = np.vstack([clean[1:], rng.uniform([0, 0], PAPER_IMAGE_SIZE, (3, 2))])
            for det in (clean, cluttered):
                est = loc.localize(det, paper_prior(truth, k))
                if est.success:
                    pose_errors(est.cam_from_world, truth)
                    quat_wxyz_from_matrix(est.cam_from_world[:3, :3])
                    association_scores(est.assignment, np.arange(len(det)) % len(landmarks),
                                       np.arange(len(landmarks)))
            if association == "robust":
                loc.localize(clean, paper_prior(truth, k), warm_start=truth)
                scored = Detections(uv=cluttered, scores=np.linspace(0.2, 0.95, len(cluttered)))
                loc.localize(scored, paper_prior(truth, k))


def warm_up(announce: Callable[[str], None] | None = print) -> float:
    """Compile or load every kernel the localizer uses; the seconds it took.

    Args:
        announce: called with :data:`COMPILING` when the kernels are not cached yet (None: silent).
    """
    if announce is not None and not kernels_cached():
        announce(COMPILING)
    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    K = PAPER_K
    tops, slab = _scene(rng)
    for landmarks in (tops, slab):
        _localize_views(landmarks, K, rng)
    _localize_views(tops, K, rng, distortion=np.array([-0.1, 0.02, 0.0, 0.0, 0.0]))
    # the public closed form (the search solves it inside compiled code, never through this
    # entry): compiled too, so that every kernel of the package is cached (kernels_cached)
    upright_two_point(np.array([[0.1, 0.0, 1.0]]), np.array([[-0.1, 0.0, 1.0]]), tops[:1], tops[1:2])
    return time.perf_counter() - t0
