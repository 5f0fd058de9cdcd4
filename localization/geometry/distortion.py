"""OpenCV's (Brown-Conrady) lens distortion: the five coefficients ``(k1, k2, p1, p2, k3)``.

The model is OpenCV's (``cv2.projectPoints``): a point ``(x, y)`` on the normalized image plane
(``z = 1`` in the camera frame, before ``K``) appears at

    r2 = x^2 + y^2,  radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y

and at pixel ``K @ (x_d, y_d, 1)``. "Pinhole pixels" below are ``K @ (x, y, 1)``: where the point
would appear without distortion. :func:`undistort_points` inverts the model by Newton's method
to 1e-12 of the normalized plane (``cv2.undistortPoints`` stops after a few fixed-point
iterations: 0.02 px off at the corners of the Mavic 2 Pro preset's 1280 x 720 frame, 15 px just
outside it).

The localization pipeline takes distortion once, at its entry: detected points are undistorted
to pinhole pixels and everything downstream is the pinhole model (docs/design.md, Conventions).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.geometry.transforms import as_points, check_intrinsics

__all__ = [
    "NO_DISTORTION",
    "check_distortion",
    "distort_normalized",
    "distort_points",
    "is_pinhole",
    "undistort_normalized",
    "undistort_points",
]


#: The coefficients of a distortion-free (pinhole) camera.
NO_DISTORTION = np.zeros(5)


def check_distortion(name: str, coefficients: ArrayLike | None) -> NDArray[np.float64]:
    """``coefficients`` as a float64 ``(5,)`` array ``(k1, k2, p1, p2, k3)``; None gives zeros.

    Four coefficients (``k3 = 0``) are accepted, as OpenCV does.

    Raises:
        TypeError: if they are not numbers.
        ValueError: if there are not 4 or 5 of them, or one is not finite.
    """
    if coefficients is None:
        return NO_DISTORTION.copy()
    arr = np.asarray(coefficients)
    if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
        raise TypeError(f"{name} must be numbers (k1, k2, p1, p2, k3), got dtype {arr.dtype}")
    arr = arr.astype(np.float64).reshape(-1)
    if arr.size not in (4, 5):
        raise ValueError(
            f"{name} must hold the 5 OpenCV coefficients (k1, k2, p1, p2, k3) (or the first 4), "
            f"got {arr.size}: {arr.tolist()}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return np.concatenate([arr, np.zeros(5 - arr.size)])


def is_pinhole(coefficients: ArrayLike | None) -> bool:
    """True when the coefficients are None or all zero (no distortion)."""
    return coefficients is None or not np.any(np.asarray(coefficients, dtype=np.float64))


def distort_normalized(xy: ArrayLike, coefficients: ArrayLike) -> NDArray[np.float64]:
    """The distorted normalized coordinates (..., 2) of undistorted ones (..., 2) (the model above)."""
    k1, k2, p1, p2, k3 = np.asarray(coefficients, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _jacobian(x: NDArray, y: NDArray, c: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """d(x_d, y_d) / d(x, y) of :func:`distort_normalized`, element-wise."""
    k1, k2, p1, p2, k3 = c
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
    a = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
    d = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
    return a, b, b, d


def undistort_normalized(
    xy_d: ArrayLike, coefficients: ArrayLike, *, iterations: int = 20, tol: float = 1e-12
) -> NDArray[np.float64]:
    """Invert :func:`distort_normalized` by Newton's method (..., 2) -> (..., 2).

    Starts from the distorted point and stops when every update is below ``tol``. Where the model
    folds over (``|d x_d / d x|`` reaches 0, far outside any calibrated field) the result is NaN.
    """
    c = np.asarray(coefficients, dtype=np.float64)
    target = np.asarray(xy_d, dtype=np.float64)
    if is_pinhole(c):
        return target.copy()
    xy = target.copy()
    for _ in range(iterations):
        residual = distort_normalized(xy, c) - target
        a, b, cc, d = _jacobian(xy[..., 0], xy[..., 1], c)
        det = a * d - b * cc
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (d * residual[..., 0] - b * residual[..., 1]) / det
            dy = (a * residual[..., 1] - cc * residual[..., 0]) / det
        xy[..., 0] -= dx
        xy[..., 1] -= dy
        step = np.nanmax(np.abs(np.stack([dx, dy]))) if dx.size else 0.0
        if not np.isfinite(step) or step < tol:
            break
    bad = ~np.all(np.isfinite(xy), axis=-1)
    with np.errstate(invalid="ignore"):
        bad |= np.any(np.abs(distort_normalized(xy, c) - target) > 1e-9, axis=-1)
    xy[bad] = np.nan
    return xy


def _normalized(uv: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return np.stack([x, y], axis=1)


def _pixels(xy: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.stack([K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2],
                     K[1, 1] * xy[:, 1] + K[1, 2]], axis=1)


def distort_points(uv: ArrayLike, K: ArrayLike, coefficients: ArrayLike | None) -> NDArray[np.float64]:
    """Pinhole pixels (N, 2) -> where they appear through the distorting lens (N, 2).

    Equal to ``cv2.projectPoints`` of the same 3D points with ``K`` and the coefficients.

    Raises:
        TypeError, ValueError: for malformed points, ``K`` or coefficients.
    """
    pts = as_points("uv", uv, 2)
    K = check_intrinsics("K", K)
    c = check_distortion("distortion", coefficients)
    if is_pinhole(c):
        return pts.copy()
    return _pixels(distort_normalized(_normalized(pts, K), c), K)


def undistort_points(
    uv: ArrayLike, K: ArrayLike, coefficients: ArrayLike | None
) -> NDArray[np.float64]:
    """Distorted pixels (N, 2) -> pinhole pixels (N, 2) (``cv2.undistortPoints(..., P=K)``, exact).

    NaN rows stay NaN; so do points outside the region where the model can be inverted.

    Raises:
        TypeError, ValueError: for malformed points, ``K`` or coefficients.
    """
    pts = as_points("uv", uv, 2)
    K = check_intrinsics("K", K)
    c = check_distortion("distortion", coefficients)
    if is_pinhole(c):
        return pts.copy()
    return _pixels(undistort_normalized(_normalized(pts, K), c), K)
