"""Plan polygons (outlines of elements and openings) as ``(K, 2)`` arrays, metres, project frame.

One convention for every outline in the site model: counter-clockwise seen from above, no
repeated closing vertex, no collinear vertices, starting at the vertex with the smallest ``y``
(then the smallest ``x``). For a rectangle that is ``(xmin, ymin), (xmax, ymin), (xmax, ymax),
(xmin, ymax)``: the corner order that the landmark sets use.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uav_struct_env.errors import SiteGeometryError

__all__ = [
    "canonical_outline",
    "is_axis_aligned_rectangle",
    "points_in_polygon",
    "polygon_bounds",
    "rectangle",
    "signed_area",
]


def signed_area(outline: ArrayLike) -> float:
    """Shoelace area (m^2), positive for a counter-clockwise outline."""
    p = np.asarray(outline, dtype=np.float64).reshape(-1, 2)
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))


def rectangle(xmin: float, ymin: float, xmax: float, ymax: float) -> NDArray[np.float64]:
    """The canonical outline of an axis-aligned rectangle."""
    return np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]], dtype=np.float64)


def polygon_bounds(outline: ArrayLike) -> tuple[float, float, float, float]:
    """``(xmin, ymin, xmax, ymax)`` of an outline."""
    p = np.asarray(outline, dtype=np.float64).reshape(-1, 2)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])


def canonical_outline(outline: ArrayLike, where: str, *, tol: float = 1e-6) -> NDArray[np.float64]:
    """``outline`` in the module's convention (see the module docstring).

    Drops a repeated closing vertex, repeated vertices and vertices within ``tol`` metres of the
    line through their neighbours; turns a clockwise outline round.

    Raises:
        SiteGeometryError: naming ``where`` if the outline is not a finite (K, 2) array or has
            fewer than three corners or no area.
    """
    try:
        p = np.array(outline, dtype=np.float64)
    except (TypeError, ValueError):
        raise SiteGeometryError(
            f"{where} must be a (K, 2) array of plan points in metres, got {outline!r}"
        ) from None
    if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
        raise SiteGeometryError(
            f"{where} must be a finite (K, 2) array of plan points, got shape {p.shape}"
        )
    if len(p) > 1 and np.allclose(p[0], p[-1], atol=tol):
        p = p[:-1]
    changed = True
    while changed and len(p) >= 3:
        changed = False
        prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
        d = nxt - prev
        length = np.hypot(d[:, 0], d[:, 1])
        cross = (p[:, 0] - prev[:, 0]) * d[:, 1] - (p[:, 1] - prev[:, 1]) * d[:, 0]
        dist = np.abs(cross) / np.maximum(length, 1e-300)
        same = np.hypot(*(p - prev).T) <= tol
        drop = same | (dist <= tol)
        if drop.any():
            k = int(np.argmax(drop))  # one at a time: neighbours change
            p = np.delete(p, k, axis=0)
            changed = True
    if len(p) < 3 or abs(signed_area(p)) <= tol:
        raise SiteGeometryError(
            f"{where} needs at least three corners enclosing an area, got {len(p)} corners"
        )
    if signed_area(p) < 0:
        p = p[::-1]
    start = int(np.lexsort((p[:, 0], p[:, 1]))[0])
    return np.ascontiguousarray(np.roll(p, -start, axis=0))


def points_in_polygon(points: ArrayLike, outline: ArrayLike) -> NDArray[np.bool_]:
    """Whether each plan point (N, 2) lies strictly inside ``outline`` (even-odd rule)."""
    q = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    p = np.asarray(outline, dtype=np.float64).reshape(-1, 2)
    a, b = p, np.roll(p, -1, axis=0)
    x, y = q[:, :1], q[:, 1:]
    straddle = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[None, :, 0] + (y - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (
            b[None, :, 1] - a[None, :, 1]
        )
    return (np.count_nonzero(straddle & (x < x_cross), axis=1) % 2) == 1


def is_axis_aligned_rectangle(outline: ArrayLike) -> bool:
    """Whether a canonical outline is an axis-aligned rectangle (four corners, edges along x, y)."""
    p = np.asarray(outline, dtype=np.float64).reshape(-1, 2)
    d = np.roll(p, -1, axis=0) - p
    return len(p) == 4 and bool(np.all(np.minimum(np.abs(d[:, 0]), np.abs(d[:, 1])) == 0.0))
