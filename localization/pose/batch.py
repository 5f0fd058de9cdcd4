"""Many poses at once: projection, Levenberg-Marquardt and pose differences over a stack.

Robust association (:mod:`localization.associate.robust`) weighs tens of identity hypotheses per
image; every step here takes a stack of ``H`` hypotheses so that one set of numpy calls (or one
compiled kernel, :mod:`localization.pose.lm`) serves them all instead of one per hypothesis.

Poses are held as ``R`` (H, 3, 3) and ``t`` (H, 3) of ``cam_from_world`` (``p_cam = R X + t``).
Correspondences of different hypotheses are padded to one length ``P`` and carry a (H, P) bool
mask. The LM update perturbs the camera frame, ``R' = exp([w]x) R``, ``t' = exp([w]x) t + d``;
the resulting poses are the same as :func:`localization.pose.pnp.refine_pose`'s (a different
parameterization of the same least-squares problem).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from localization.geometry.kernels import kernel_array
from localization.geometry.transforms import so3_log
from localization.pose.lm import lm_many

__all__ = [
    "pose_difference_many",
    "project_many",
    "refine_many",
    "rotation_between",
    "so3_exp_many",
    "to_transforms",
]


def so3_exp_many(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """(H, 3, 3) rotation matrices of (H, 3) rotation vectors (Rodrigues, series near zero)."""
    theta2 = np.sum(w * w, axis=1)
    theta = np.sqrt(theta2)
    small = theta < 1e-4
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    W = (w[:, _SKEW_FROM] * _SKEW_SIGN).reshape(-1, 3, 3)
    return np.eye(3) + a[:, None, None] * W + b[:, None, None] * (W @ W)


#: The skew matrix [w]x as a gather of w's components (row-major) times signs (0 where zero).
_SKEW_FROM = np.array([0, 2, 1, 2, 0, 0, 1, 0, 0])


_SKEW_SIGN = np.array([0.0, -1.0, 1.0, 1.0, 0.0, -1.0, -1.0, 1.0, 0.0])


def rotation_between(b1: NDArray[np.float64], b2: NDArray[np.float64]) -> NDArray[np.float64]:
    """(H, 3, 3) the smallest rotations taking directions ``b1`` (H, 3) to ``b2`` (H, 3)."""
    b1 = b1 / np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = b2 / np.linalg.norm(b2, axis=1, keepdims=True)
    axis = np.cross(b1, b2)
    s = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(s, np.sum(b1 * b2, axis=1))
    return so3_exp_many(axis * np.where(s > 1e-15, angle / np.maximum(s, 1e-300), 0.0)[:, None])


def project_many(
    K: NDArray[np.float64], R: NDArray[np.float64], t: NDArray[np.float64], X: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixels (H, M, 2) and depths (H, M) of points ``X`` ((M, 3) shared or (H, M, 3)).

    A point at or behind the camera gets NaN pixels (its depth tells which).
    """
    p = X @ R.transpose(0, 2, 1) + t[:, None, :]
    z = p[..., 2]
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    u = (K[0, 0] * p[..., 0] + K[0, 1] * p[..., 1]) / zs + K[0, 2]
    v = K[1, 1] * p[..., 1] / zs + K[1, 2]
    uv = np.stack([u, v], axis=-1)
    uv[~front] = np.nan
    return uv, z


def refine_many(
    K: NDArray[np.float64],
    R: NDArray[np.float64],
    t: NDArray[np.float64],
    X: NDArray[np.float64],
    uv: NDArray[np.float64],
    mask: NDArray[np.bool_],
    iterations: int = 10,
    robust_px: float | None = None,
    tol: float = 1e-6,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Levenberg-Marquardt on the reprojection error of H poses at once.

    Compiled (:func:`localization.pose.lm.lm_many`): one loop per pose, no per-step array calls.

    Args:
        K: (3, 3) intrinsics.
        R: (H, 3, 3) start rotations of ``cam_from_world``.
        t: (H, 3) start translations.
        X: (H, P, 3) model points, padded.
        uv: (H, P, 2) their pixels, padded.
        mask: (H, P) the real correspondences.
        iterations: LM steps (each tries one damped update per pose and keeps it if it lowers
            that pose's cost, else raises its damping).
        robust_px: if given, Cauchy weights ``1 / (1 + (|r| / robust_px)^2)`` recomputed each
            step (iteratively reweighted least squares), so a wrong pair pulls less.
        tol: a pose whose relative cost decrease falls below this stops moving.

    Returns:
        ``(R, t, cost)``: refined poses and their unweighted sum of squared residuals over the
        mask, px^2 (inf for a pose with a masked point at or behind the camera).
    """
    h, p = np.shape(mask)
    shapes = (np.shape(R), np.shape(t), np.shape(X), np.shape(uv))
    if shapes != ((h, 3, 3), (h, 3), (h, p, 3), (h, p, 2)):
        raise ValueError(
            f"refine_many needs R (H, 3, 3), t (H, 3), X (H, P, 3), uv (H, P, 2) for mask (H, P) = "
            f"{(h, p)}; got R {np.shape(R)}, t {np.shape(t)}, X {np.shape(X)}, uv {np.shape(uv)}"
        )
    f64 = np.float64
    return lm_many(
        kernel_array(K, dtype=f64),
        kernel_array(R, dtype=f64),
        kernel_array(t, dtype=f64),
        kernel_array(X, dtype=f64),
        kernel_array(uv, dtype=f64),
        kernel_array(mask, dtype=np.bool_),
        int(iterations),
        0.0 if robust_px is None else float(robust_px),
        float(tol),
    )


def pose_difference_many(
    R: NDArray[np.float64], t: NDArray[np.float64], prior: NDArray[np.float64]
) -> NDArray[np.float64]:
    """(H, 6) poses minus ``prior`` (4, 4) as :func:`localization.pose.covariance.pose_difference` gives them.

    Camera centre difference [m], then the world-frame rotation vector ``log(R_wc R_wc_prior^T)``.
    """
    C = -(R.transpose(0, 2, 1) @ t[..., None])[..., 0]
    Rp = prior[:3, :3]
    Cp = -Rp.T @ prior[:3, 3]
    Q = R.transpose(0, 2, 1) @ Rp  # R_wc @ R_wc_prior.T
    w = np.stack([Q[:, 2, 1] - Q[:, 1, 2], Q[:, 0, 2] - Q[:, 2, 0], Q[:, 1, 0] - Q[:, 0, 1]], axis=1)
    cos = np.clip((Q[:, 0, 0] + Q[:, 1, 1] + Q[:, 2, 2] - 1.0) / 2.0, -1.0, 1.0)
    s = 0.5 * np.linalg.norm(w, axis=1)
    theta = np.arctan2(s, cos)
    rot = w * np.where(s < 1e-12, 0.5, theta / (2.0 * np.maximum(s, 1e-300)))[:, None]
    far = cos <= -0.99  # near pi the skew part loses the axis: the exact scalar logarithm
    for i in np.flatnonzero(far):
        rot[i] = so3_log(Q[i])
    return np.concatenate([C - Cp, rot], axis=1)


def to_transforms(R: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    """(H, 4, 4) rigid transforms of rotations (H, 3, 3) and translations (H, 3)."""
    T = np.zeros((R.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = t
    T[:, 3, 3] = 1.0
    return T
