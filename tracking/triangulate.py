"""Triangulation of one 3D point from several calibrated views: DLT, then nonlinear refinement.

Every function works on undistorted pixels (:meth:`~tracking.views.CameraView.undistort`) and
weighs each observation by its 2x2 pixel covariance: the detector's ``sigma_px^2 I`` plus the
pose uncertainty of its view propagated to that point (``J Sigma J^T``, :mod:`tracking.views`).

* :func:`dlt` -- the linear solution (homogeneous least squares on normalized image coordinates,
  Hartley & Zisserman ch. 12.2), batched over many candidate points at once.
* :func:`refine` -- batched Gauss-Newton on the whitened reprojection error; what the cross-view
  association evaluates for thousands of candidate pairs per frame.
* :func:`triangulate_point` -- one point from all the views that see it: DLT, then
  ``scipy.optimize.least_squares`` on the whitened residuals, covariance ``(J^T W J)^-1`` and the
  chi-square of the fit; degenerate cases (one view, rays within ``min_ray_angle_deg`` of parallel,
  a point behind a camera) come back as a failed :class:`PointEstimate` with the reason.
* :func:`triangulate_upright` -- a standing worker's feet and head top at one horizontal
  position (four unknowns instead of six), an option of the tracker.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from localization.pose.covariance import pose_jacobian
from tracking.views import CameraView

__all__ = [
    "DEFAULT_MIN_RAY_ANGLE_DEG",
    "PointEstimate",
    "dlt",
    "max_ray_angle_deg",
    "pixel_covariances",
    "refine",
    "triangulate_point",
    "triangulate_upright",
]

#: Below this largest angle between two viewing rays (deg) a point's depth is not observable.
DEFAULT_MIN_RAY_ANGLE_DEG = 1.0


@dataclass(frozen=True, eq=False)
class PointEstimate:
    """A triangulated point with its quality.

    Attributes:
        success: False for a degenerate case (see ``failure_reason``).
        xyz: (3,) the point in the world frame, m (NaN when failed).
        covariance: (3, 3) its covariance, m^2 (inf when failed).
        chi2: sum of squared whitened reprojection residuals (NaN when failed).
        dof: degrees of freedom of ``chi2``: ``2 n_views - 3``.
        rmse_px: RMS reprojection residual in pixels (NaN when failed).
        ray_angle_deg: largest angle between two of its viewing rays, deg.
        failure_reason: why it failed, with the numbers of the case; None on success.
    """

    success: bool
    xyz: NDArray[np.float64]
    covariance: NDArray[np.float64]
    chi2: float
    dof: int
    rmse_px: float
    ray_angle_deg: float
    failure_reason: str | None = None


def _stack(views: Sequence[CameraView]) -> tuple[NDArray, NDArray]:
    return np.stack([v.cam_from_world for v in views]), np.stack([v.K for v in views])


def dlt(cam_from_world: NDArray, K: NDArray, uv: NDArray) -> tuple[NDArray, NDArray]:
    """Linear triangulation of a batch of points.

    Args:
        cam_from_world: (n, 4, 4) the n views.
        K: (n, 3, 3) their intrinsics.
        uv: (B, n, 2) undistorted pixels of B points, each seen in all n views.

    Returns:
        ``(xyz (B, 3), w (B,))``: the points and the homogeneous scale of the unit null vector; a
        ``|w|`` near 0 means a point at infinity (parallel rays), whose ``xyz`` is meaningless.
    """
    B, n = uv.shape[:2]
    hom = np.concatenate([uv, np.ones((B, n, 1))], axis=2)
    xn = np.einsum("nij,bnj->bni", np.linalg.inv(K), hom)  # normalized image coordinates
    P = cam_from_world[:, :3, :]  # (n, 3, 4)
    rows = np.empty((B, n, 2, 4))
    rows[:, :, 0] = xn[:, :, 0, None] * P[None, :, 2] - P[None, :, 0]
    rows[:, :, 1] = xn[:, :, 1, None] * P[None, :, 2] - P[None, :, 1]
    A = rows.reshape(B, 2 * n, 4)
    A = A / np.linalg.norm(A, axis=2, keepdims=True)
    _, _, vt = np.linalg.svd(A)
    h = vt[:, -1]
    w = h[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        xyz = h[:, :3] / w[:, None]
    return xyz, w


def pixel_covariances(views: Sequence[CameraView], xyz: NDArray, sigma_px: NDArray) -> NDArray:
    """(B, n, 2, 2) pixel covariance of each point in each view: detector noise plus pose noise.

    Args:
        views: the n views.
        xyz: (B, 3) points where the pose uncertainty is propagated.
        sigma_px: (B, n) detector sigma of each observation, px.
    """
    B, n = sigma_px.shape
    cov = np.zeros((B, n, 2, 2))
    cov[:, :, 0, 0] = cov[:, :, 1, 1] = sigma_px**2
    for j, view in enumerate(views):
        if view.pose_covariance is None:
            continue
        pts = np.where(np.isfinite(xyz), xyz, 0.0)
        J, _ = pose_jacobian(view.K, view.cam_from_world, pts)
        J = J.reshape(B, 2, 6)
        cov[:, j] += J @ view.pose_covariance @ J.transpose(0, 2, 1)
    return cov


def _project(cam_from_world: NDArray, K: NDArray, xyz: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """Projections (B, n, 2), camera-frame points (B, n, 3) and d uv / d xyz (B, n, 2, 3)."""
    R = cam_from_world[:, :3, :3]
    p = xyz @ R.transpose(0, 2, 1)  # (n, B, 3)
    p = p.transpose(1, 0, 2) + cam_from_world[None, :, :3, 3]
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = p[..., 0] / z, p[..., 1] / z
        fx, fy, s = K[None, :, 0, 0], K[None, :, 1, 1], K[None, :, 0, 1]
        uv = np.stack([fx * x + s * y + K[None, :, 0, 2], fy * y + K[None, :, 1, 2]], axis=-1)
        dp = np.zeros(p.shape[:2] + (2, 3))
        dp[..., 0, 0] = fx / z
        dp[..., 0, 1] = s / z
        dp[..., 0, 2] = -(fx * x + s * y) / z
        dp[..., 1, 1] = fy / z
        dp[..., 1, 2] = -fy * y / z
    J = dp @ R[None]
    return uv, p, J


def refine(
    cam_from_world: NDArray, K: NDArray, uv: NDArray, cov: NDArray, xyz: NDArray, iterations: int = 6
) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Batched Gauss-Newton on the whitened reprojection error from starting points ``xyz``.

    Args:
        cam_from_world: (n, 4, 4) the views.
        K: (n, 3, 3) their intrinsics.
        uv: (B, n, 2) undistorted observations.
        cov: (B, n, 2, 2) their covariances, px^2.
        xyz: (B, 3) starting points (the DLT's).
        iterations: Gauss-Newton steps (the DLT start is within the basin; 3-4 converge to 1e-9 m).

    Returns:
        ``(xyz (B, 3), chi2 (B,), information (B, 3, 3), depth (B, n))`` at the last iterate.
    """
    W = np.linalg.inv(cov)
    xyz = np.where(np.isfinite(xyz), xyz, 0.0)
    for _ in range(iterations):
        proj, _, J = _project(cam_from_world, K, xyz)
        r = proj - uv
        JtW = J.transpose(0, 1, 3, 2) @ W  # (B, n, 3, 2)
        H = (JtW @ J).sum(axis=1)
        g = (JtW @ r[..., None]).sum(axis=1)[..., 0]
        ok = np.all(np.isfinite(H), axis=(1, 2)) & np.all(np.isfinite(g), axis=1)
        ok &= np.abs(np.linalg.det(np.where(ok[:, None, None], H, np.eye(3)))) > 1e-300
        step = np.zeros_like(xyz)
        if np.any(ok):
            step[ok] = np.linalg.solve(H[ok], g[ok][..., None])[..., 0]
        xyz = xyz - step
    proj, p, J = _project(cam_from_world, K, xyz)
    r = proj - uv
    chi2 = (r[..., None, :] @ W @ r[..., None])[..., 0, 0].sum(axis=1)
    H = (J.transpose(0, 1, 3, 2) @ W @ J).sum(axis=1)
    return xyz, chi2, H, p[..., 2]


def max_ray_angle_deg(views: Sequence[CameraView], uv: NDArray) -> NDArray:
    """(B,) the largest angle between two viewing rays of each point, deg.

    Args:
        views: the n views.
        uv: (B, n, 2) undistorted pixels.
    """
    B, n = uv.shape[:2]
    hom = np.concatenate([uv, np.ones((B, n, 1))], axis=2)
    rays = np.stack(
        [hom[:, j] @ np.linalg.inv(v.K).T @ v.cam_from_world[:3, :3] for j, v in enumerate(views)], axis=1
    )  # world-frame directions R^T K^-1 [u v 1]
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    cos = np.clip(np.einsum("bic,bjc->bij", rays, rays), -1.0, 1.0)
    return np.degrees(np.arccos(np.min(cos.reshape(B, -1), axis=1)))


def _failed(reason: str, dof: int, angle: float) -> PointEstimate:
    nan3 = np.full(3, np.nan)
    return PointEstimate(False, nan3, np.full((3, 3), np.inf), float("nan"), dof, float("nan"), angle, reason)


def triangulate_point(
    views: Sequence[CameraView],
    uv: ArrayLike,
    sigma_px: ArrayLike,
    *,
    min_ray_angle_deg: float = DEFAULT_MIN_RAY_ANGLE_DEG,
) -> PointEstimate:
    """Triangulate one point seen in every one of ``views``.

    Args:
        views: n >= 1 camera views.
        uv: (n, 2) undistorted pixel positions of the point in each view.
        sigma_px: (n,) detector noise of each observation, px (a scalar is broadcast).
        min_ray_angle_deg: fail as degenerate below this largest angle between two rays.

    Returns:
        A :class:`PointEstimate`; a failed one (never an exception) for one view, nearly parallel
        rays, or a solution behind one of the cameras.
    """
    n = len(views)
    obs = np.asarray(uv, dtype=np.float64).reshape(n, 2)
    sig = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), (n,)).copy()
    dof = 2 * n - 3
    if n < 2:
        return _failed(f"seen by {n} camera{'s' if n != 1 else ''} only: a 3D point needs two", dof, 0.0)
    angle = float(max_ray_angle_deg(views, obs[None])[0])
    if angle < min_ray_angle_deg:
        return _failed(
            f"viewing rays nearly parallel: largest angle {angle:.3f} deg < {min_ray_angle_deg} deg "
            f"(cameras {[v.name for v in views]})",
            dof,
            angle,
        )
    T, Ks = _stack(views)
    x0, w = dlt(T, Ks, obs[None])
    if not np.all(np.isfinite(x0)) or abs(w[0]) < 1e-12:
        return _failed("the linear solution is at infinity (parallel rays)", dof, angle)
    cov = pixel_covariances(views, x0, sig[None])[0]  # (n, 2, 2), fixed during the refinement
    L = np.linalg.cholesky(np.linalg.inv(cov))  # W = L L^T, whitened residual L^T r

    def residuals(x: NDArray) -> NDArray:
        proj, _, _ = _project(T, Ks, x[None])
        return np.einsum("nji,nj->ni", L, proj[0] - obs).reshape(-1)

    def jacobian(x: NDArray) -> NDArray:
        _, _, J = _project(T, Ks, x[None])
        return np.einsum("nji,njk->nik", L, J[0]).reshape(-1, 3)

    sol = least_squares(residuals, x0[0], jac=jacobian, method="lm" if 2 * n >= 3 else "trf", xtol=1e-12)
    xyz = sol.x
    proj, p, J = _project(T, Ks, xyz[None])
    depth = p[0, :, 2]
    if np.any(depth <= 0):
        bad = [v.name for v, d in zip(views, depth, strict=True) if d <= 0]
        return _failed(
            f"the triangulated point is behind camera(s) {bad} (depth {depth.round(3).tolist()} m)",
            dof,
            angle,
        )
    H = np.einsum("nji,njk,nkl->il", J[0], np.linalg.inv(cov), J[0])
    r = proj[0] - obs
    chi2 = float(np.sum(sol.fun**2))
    return PointEstimate(
        True, xyz, np.linalg.inv(H), chi2, dof, float(np.sqrt(np.mean(np.sum(r**2, axis=1)))), angle
    )


def triangulate_upright(
    views: Sequence[CameraView],
    uv: ArrayLike,
    sigma_px: ArrayLike,
    *,
    min_ray_angle_deg: float = DEFAULT_MIN_RAY_ANGLE_DEG,
) -> tuple[PointEstimate, PointEstimate]:
    """Triangulate a standing worker: the head top straight above the feet (world z up).

    The feet ``(x, y, z_feet)`` and head top ``(x, y, z_head)`` share their horizontal position:
    four unknowns instead of six, fitted jointly by ``scipy.optimize.least_squares`` on the
    whitened residuals of both points, from the information-weighted mean of the two independent
    solutions (:func:`triangulate_point`, which also reports the degenerate cases). A worker who
    leans or crouches violates the model; its chi-square shows it.

    Args:
        views: n >= 1 camera views.
        uv: (n, 2, 2) undistorted feet (index 0) and head-top (index 1) pixels in each view.
        sigma_px: (n,) detector noise of each view's detection, px (a scalar is broadcast).
        min_ray_angle_deg: as :func:`triangulate_point`.

    Returns:
        ``(feet, head)``: :class:`PointEstimate` objects whose covariances are the blocks of the
        joint 4x4 covariance; ``chi2`` and ``dof`` (``2 n - 2`` each) split the joint fit's.
    """
    n = len(views)
    obs = np.asarray(uv, dtype=np.float64).reshape(n, 2, 2)
    sig = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), (n,)).copy()
    feet, head = (
        triangulate_point(views, obs[:, k], sig, min_ray_angle_deg=min_ray_angle_deg) for k in (0, 1)
    )
    if not (feet.success and head.success):
        return feet, head
    info_f, info_h = np.linalg.inv(feet.covariance[:2, :2]), np.linalg.inv(head.covariance[:2, :2])
    xy = np.linalg.solve(info_f + info_h, info_f @ feet.xyz[:2] + info_h @ head.xyz[:2])
    q0 = np.array([xy[0], xy[1], feet.xyz[2], head.xyz[2]])
    T, Ks = _stack(views)
    points0 = np.stack([feet.xyz, head.xyz])
    cov = pixel_covariances(views, points0, np.stack([sig, sig]))  # (2, n, 2, 2)
    L = np.linalg.cholesky(np.linalg.inv(cov))
    select = np.zeros((2, 3, 4))  # d point / d q
    select[:, 0, 0] = select[:, 1, 1] = 1.0
    select[0, 2, 2] = select[1, 2, 3] = 1.0

    def points(q: NDArray) -> NDArray:
        return np.array([[q[0], q[1], q[2]], [q[0], q[1], q[3]]])

    def residuals(q: NDArray) -> NDArray:
        proj, _, _ = _project(T, Ks, points(q))
        return np.einsum("bnji,bnj->bni", L, proj - obs.transpose(1, 0, 2)).reshape(-1)

    def jacobian(q: NDArray) -> NDArray:
        _, _, J = _project(T, Ks, points(q))  # (2, n, 2, 3)
        return np.einsum("bnji,bnjk,bkl->bnil", L, J, select).reshape(-1, 4)

    sol = least_squares(residuals, q0, jac=jacobian, method="lm", xtol=1e-12)
    cov_q = np.linalg.inv(jacobian(sol.x).T @ jacobian(sol.x))
    r = sol.fun.reshape(2, n, 2)
    proj, p, _ = _project(T, Ks, points(sol.x))
    if np.any(p[..., 2] <= 0):
        reason = "the upright worker is behind a camera"
        return _failed(reason, 2 * n - 2, feet.ray_angle_deg), _failed(reason, 2 * n - 2, head.ray_angle_deg)
    out = []
    for k, (index, point) in enumerate((((0, 1, 2), feet), ((0, 1, 3), head))):
        res_px = proj[k] - obs[:, k]
        out.append(PointEstimate(
            True, points(sol.x)[k], cov_q[np.ix_(index, index)], float(np.sum(r[k] ** 2)), 2 * n - 2,
            float(np.sqrt(np.mean(np.sum(res_px**2, axis=1)))), point.ray_angle_deg,
        ))
    return out[0], out[1]
