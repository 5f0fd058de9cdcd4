"""Identity hypotheses the geometry cannot tell apart: find the rivals of a winner, judge the tie.

Robust association picks the association hypothesis with the lowest negative log-likelihood
(:mod:`localization.associate`). Two things can make that pick a confident wrong pose:

* *The right hypothesis was never tried.* A layout that repeats itself -- a regular column grid,
  the same grid on two levels -- maps onto itself under a translation ``t = X_j - X_i``. A camera
  moved by ``t`` sees landmark ``X_j`` exactly where the winner's camera saw ``X_i``, so the
  winner's pose moved by ``t`` is as good a start as any layout vote, and at long focal lengths
  (where the prior's error is hundreds of pixels) it is often better. :func:`translation_hypotheses`
  proposes those rivals: every translation between an assigned landmark and any landmark that
  keeps the camera consistent with the prior, ranked by how many detections it explains.
* *Two hypotheses explain the detections about equally well* (a window onto a grid larger than
  the image, shifted by one bay). Then nothing but the prior separates them, and the prior is
  metres off. :func:`ambiguity` reports a rival whose score is within ``margin`` of the
  winner's (a likelihood ratio below ``exp(margin / 2)``), whose identities conflict with the
  winner's (some detection names another landmark) and whose camera centre lies outside the
  winner's own 99.9 % position ellipsoid: picking either would be a guess, so the estimate fails
  with :attr:`~localization.failure.FailureCode.AMBIGUOUS` instead.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from localization.associate.hypothesis_kernels import rival_translations
from localization.geometry.kernels import kernel_array
from localization.geometry.transforms import camera_center
from localization.pose.covariance import pose_covariance

__all__ = ["AMBIGUITY_MARGIN", "ambiguity", "translation_hypotheses"]


#: Score margin (negative log-likelihood, chi-square units) within which a conflicting rival
#: makes the winner ambiguous: ``2 ln 100``, i.e. the winner is less than 100 times as likely.
AMBIGUITY_MARGIN = 2.0 * float(np.log(100.0))


#: chi-square 99.9 % quantile, 3 dof: a rival camera centre beyond this (squared Mahalanobis
#: distance under the winner's covariance) is a different pose, not the same one re-weighted.
_DISTINCT_POSITION_SQ = 16.27


def translation_hypotheses(
    det: NDArray[np.float64],
    landmarks_xyz: NDArray[np.float64],
    K: NDArray[np.float64],
    cam_from_world: NDArray[np.float64],
    assignment: NDArray[np.int64],
    prior_cam_from_world: NDArray[np.float64],
    prior_position_sigma_m: NDArray[np.float64],
    max_prior_position_sq: float | None,
    gate_px: float,
    min_pairs: int,
    limit: int,
) -> list[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]]:
    """Coarse assignments of the winner's pose moved by the layout's self-translations.

    Args:
        det: (N, 2) detections (NaN rows never match).
        landmarks_xyz: (M, 3) model landmarks.
        K: (3, 3) intrinsics.
        cam_from_world: (4, 4) the winner's pose.
        assignment: (N,) the winner's landmark per detection, -1 when unassigned.
        prior_cam_from_world: (4, 4) the prior.
        prior_position_sigma_m: (3,) the prior's position sigmas.
        max_prior_position_sq: a moved camera centre farther from the prior's than this (squared
            Mahalanobis distance) is not tried; None tries all.
        gate_px: a detection is explained by a moved projection within this distance.
        min_pairs: a translation must explain at least this many detections (and at least one
            fewer than the winner has pairs) to be proposed.
        limit: most translations returned, best first: the smallest sum over the detections
            of the squared distance to the nearest moved projection, capped at ``gate_px^2``
            (ties: the camera centre nearer the prior's).

    Returns:
        ``[(landmark indices (K,), their moved projections (K, 2), moved cam_from_world (4, 4)),
        ...]``, one per proposed translation: the landmarks in front of the moved camera and
        its pose (a start that needs no PnP, which fails on some four-point sets).
    """
    pairs = assignment >= 0
    good = np.isfinite(det).all(axis=1)
    need = max(min_pairs, int(pairs.sum()) - 1)
    # A translation that explains `need` of the finite detections explains one of any
    # (finite - need + 1) of them: anchoring on that many of the winner's pairs finds it.
    anchors = assignment[np.flatnonzero(pairs)[: max(int(good.sum()) - need + 1, 1)]]
    if anchors.size == 0:
        return []
    f64 = np.float64
    t, uv, depth, centre = rival_translations(  # compiled: the translations, gated, scored, ranked
        kernel_array(det[good], dtype=f64), kernel_array(landmarks_xyz, dtype=f64),
        kernel_array(K, dtype=f64), kernel_array(cam_from_world, dtype=f64),
        kernel_array(anchors, dtype=np.int64), camera_center(prior_cam_from_world),
        kernel_array(prior_position_sigma_m, dtype=f64),
        np.inf if max_prior_position_sq is None else float(max_prior_position_sq), float(gate_px) ** 2,
        int(need), int(limit),
    )
    R = cam_from_world[:3, :3]
    out = []
    for k in range(t.shape[0]):
        front = np.flatnonzero(depth[k] > 1e-6)
        moved_pose = cam_from_world.copy()
        moved_pose[:3, 3] = -R @ (centre + t[k])
        out.append((front, uv[k, front], moved_pose))
    return out


def ambiguity(
    scored: list[tuple[float, NDArray[np.int64], NDArray[np.float64]]],
    landmarks_xyz: NDArray[np.float64],
    K: NDArray[np.float64],
    pixel_sigma: float,
    margin: float = AMBIGUITY_MARGIN,
) -> str | None:
    """Why the best of ``scored`` cannot be told from a rival, or None when it can.

    Args:
        scored: ``[(score, assignment (N,), cam_from_world (4, 4)), ...]``, best (lowest) first.
        landmarks_xyz: (M, 3) model landmarks.
        K: (3, 3) intrinsics.
        pixel_sigma: detector noise, px (the winner's covariance).
        margin: score margin of an ambiguity (module docstring).
    """
    best_score, best_a, best_T = scored[0]
    pairs = best_a >= 0
    cov = None  # the winner's covariance, computed only when a rival is close enough to need it
    centre = camera_center(best_T)
    for score, a, T in scored[1:]:
        if score - best_score >= margin:
            break
        conflict = (a >= 0) & pairs & (a != best_a)
        if not conflict.any():
            continue
        if cov is None:
            cov = pose_covariance(K, best_T, landmarks_xyz[best_a[pairs]], pixel_sigma)[:3, :3]
        d = camera_center(T) - centre
        if np.all(np.isfinite(cov)):
            distinct = float(d @ np.linalg.solve(cov, d)) > _DISTINCT_POSITION_SQ
        else:
            distinct = True
        if distinct:
            return (
                f"ambiguous association: two identity hypotheses fit about equally well (scores "
                f"{best_score:.1f} and {score:.1f}, margin {margin:.1f}) with camera centres "
                f"{float(np.linalg.norm(d)):.2f} m apart"
            )
    return None
