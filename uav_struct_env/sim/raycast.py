"""Landmark visibility from geometry: the depth test without rendering a pixel.

When nothing reads the image (a state-only policy on simulated detections), rendering a frame
only to depth-test the landmarks is most of an env step. :class:`RayScene` holds the triangles
that a :class:`~uav_struct_env.sim.world.SiteWorld` renders (site elements, ground, markers) and
the oriented boxes it adds (UAV airframes), and casts rays through pixel centres against them:
one compiled loop per ray (numba), each mesh culled by its bounding box first, Möller–Trumbore on
the triangles left.

:func:`raycast_visibility` makes the same decision as
:func:`~uav_struct_env.sim.visibility.landmark_visibility` on a rendered depth image: a ray
through each pixel centre of the ``(2r+1) x (2r+1)`` window around the rounded projection gives
that pixel's depth (the hit's distance along the optical axis: the ray direction is
``K^-1 (u, v, 1)`` in the camera frame, whose z is 1), and the landmark is visible if any of them
is at least ``z - tolerance(z)``. The depth is exact here instead of a rasterized, quantized
buffer, so the two disagree only where a triangle edge crosses a window pixel's centre within
rasterization precision: at grazing angles and silhouette edges (measured in
``tests/sim/test_raycast.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.transforms import as_points, check_transform, inverse_intrinsics
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.visibility import _window_limits

__all__ = ["RayScene", "raycast_visibility"]


class RayScene:
    """Static triangle meshes plus movable oriented boxes, for first-hit ray queries.

    A horizontal flat mesh that fills its bounding rectangle (the ground; holes of at most 1 %
    of its area, which the markers lying in them cover) is intersected as that rectangle.

    Args:
        meshes: ``(vertices (V, 3), faces (F, 3))`` per mesh, project frame, metres.
    """

    def __init__(self, meshes: Sequence[tuple[ArrayLike, ArrayLike]]) -> None:
        tris, lo, hi, rects = [], [], [], []
        for vertices, faces in meshes:
            v = np.asarray(vertices, dtype=np.float64)
            tri = v[np.asarray(faces, dtype=np.int64)]
            vlo, vhi = v.min(axis=0), v.max(axis=0)
            if vhi[2] - vlo[2] < 1e-9 and _area(tri) >= 0.99 * (vhi[0] - vlo[0]) * (vhi[1] - vlo[1]):
                rects.append((vlo[0], vhi[0], vlo[1], vhi[1], vlo[2]))
                continue
            tris.append(tri)
            lo.append(vlo)
            hi.append(vhi)
        counts = np.array([len(t) for t in tris], dtype=np.int64)
        allt = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
        self._v0 = np.ascontiguousarray(allt[:, 0])
        self._e1, self._e2 = allt[:, 1] - allt[:, 0], allt[:, 2] - allt[:, 0]
        self._start, self._count = np.cumsum(counts) - counts, counts
        pad = 1e-6  # boxes of flat meshes get a non-zero thickness
        self._lo = np.array(lo).reshape(-1, 3) - pad
        self._hi = np.array(hi).reshape(-1, 3) + pad
        self._rects = np.array(rects, dtype=np.float64).reshape(-1, 5)
        self.set_boxes(np.zeros((0, 4, 4)), np.zeros((0, 3)))

    @property
    def boxes(self) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Oriented boxes ``(world_from_box (4, 4), half_extents (3,))``; set before each query."""
        return list(zip(self._box_poses, self._box_halves, strict=True))

    @boxes.setter
    def boxes(self, boxes: Sequence[tuple[ArrayLike, ArrayLike]]) -> None:
        self.set_boxes([T for T, _ in boxes], [h for _, h in boxes])

    def set_boxes(self, poses: ArrayLike, half_extents: ArrayLike) -> None:
        """Set the oriented boxes at once: ``poses`` (B, 4, 4), ``half_extents`` (B, 3)."""
        self._box_poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        self._box_halves = np.ascontiguousarray(half_extents, dtype=np.float64).reshape(-1, 3)
        # the compiled loop's rotations and centres, once per pose change, not per query
        self._box_R = np.ascontiguousarray(self._box_poses[:, :3, :3])
        self._box_c = np.ascontiguousarray(self._box_poses[:, :3, 3])

    def _arrays(self) -> tuple[NDArray, ...]:
        """The scene as :func:`_first_hit` reads it, after the ray arguments."""
        return (self._rects, self._lo, self._hi, self._start, self._count, self._v0, self._e1, self._e2,
                self._box_R, self._box_c, self._box_halves)

    @property
    def n_triangles(self) -> int:
        """Triangles tested one by one (flat rectangles excluded)."""
        return len(self._v0)

    def first_hit(
        self,
        origin: ArrayLike,
        directions: ArrayLike,
        t_min: float = 0.0,
        skip_box: ArrayLike | None = None,
    ) -> NDArray[np.float64]:
        """Ray parameter ``t`` of the first surface hit at ``t >= t_min`` (``inf`` for none).

        The rays are ``origin + t * directions[i]``; ``t`` is in units of each direction's length.
        ``skip_box`` (R,) ints: for each ray, the index in :attr:`boxes` of a box that ray passes
        through unseen (-1: none), e.g. the body whose own visibility is asked.
        """
        o = np.ascontiguousarray(origin, dtype=np.float64).reshape(3)
        d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
        skip = np.full(len(d), -1, dtype=np.int64) if skip_box is None else (
            np.ascontiguousarray(skip_box, dtype=np.int64).reshape(-1)
        )
        if skip.shape != (len(d),):  # the compiled loop reads skip[r] for every ray, unchecked
            raise ValueError(f"skip_box must hold one box index per ray ({len(d)}), got shape {skip.shape}")
        return _first_hit(o, d, float(t_min), skip, *self._arrays())


def _area(tri: NDArray[np.float64]) -> float:
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


@njit(cache=True, nogil=True, error_model="numpy")
def _first_hit(
    o: NDArray, d: NDArray, t_min: float, skip: NDArray, rects: NDArray, lo: NDArray, hi: NDArray,
    start: NDArray, count: NDArray, v0: NDArray, e1: NDArray, e2: NDArray, box_R: NDArray,
    box_c: NDArray, box_half: NDArray,
) -> NDArray:
    """:meth:`RayScene.first_hit`, one compiled loop per ray.

    Flat rectangles first; then each mesh whose bounding box the ray enters before its best hit
    so far (slab test; a ray parallel to a slab is limited only outside it), Moller-Trumbore on
    its triangles; then the oriented boxes within the bounding cone seen from ``o``, slab-tested
    in their own frame. Division by zero gives +-inf (``error_model="numpy"``), as in numpy.
    """
    n = d.shape[0]
    best = np.full(n, np.inf)
    radius = np.empty(box_half.shape[0])
    dist = np.empty(box_half.shape[0])
    toward = np.empty((box_half.shape[0], 3))
    for b in range(box_half.shape[0]):
        oc0, oc1, oc2 = box_c[b, 0] - o[0], box_c[b, 1] - o[1], box_c[b, 2] - o[2]
        dist[b] = np.sqrt(oc0 * oc0 + oc1 * oc1 + oc2 * oc2)
        radius[b] = np.sqrt(box_half[b, 0] ** 2 + box_half[b, 1] ** 2 + box_half[b, 2] ** 2)
        m = max(dist[b], 1e-12)
        toward[b, 0], toward[b, 1], toward[b, 2] = oc0 / m, oc1 / m, oc2 / m
    for r in range(n):
        dx, dy, dz = d[r, 0], d[r, 1], d[r, 2]
        bt = np.inf
        for k in range(rects.shape[0]):
            t = (rects[k, 4] - o[2]) / dz
            x, y = o[0] + t * dx, o[1] + t * dy
            if t >= t_min and rects[k, 0] <= x <= rects[k, 1] and rects[k, 2] <= y <= rects[k, 3] and t < bt:
                bt = t
        for g in range(lo.shape[0]):
            near, far = -np.inf, np.inf
            for a in range(3):
                da = d[r, a]
                if da == 0.0:
                    if o[a] < lo[g, a] or o[a] > hi[g, a]:
                        near, far = np.inf, -np.inf
                    continue
                t1, t2 = (lo[g, a] - o[a]) / da, (hi[g, a] - o[a]) / da
                near = max(near, min(t1, t2))
                far = min(far, max(t1, t2))
            if not (far >= max(near, t_min) and near < bt):
                continue
            for i in range(start[g], start[g] + count[g]):
                # Moller-Trumbore
                p0 = dy * e2[i, 2] - dz * e2[i, 1]
                p1 = dz * e2[i, 0] - dx * e2[i, 2]
                p2 = dx * e2[i, 1] - dy * e2[i, 0]
                det = p0 * e1[i, 0] + p1 * e1[i, 1] + p2 * e1[i, 2]
                if not abs(det) > 1e-12:
                    continue
                s0, s1, s2 = o[0] - v0[i, 0], o[1] - v0[i, 1], o[2] - v0[i, 2]
                q0 = s1 * e1[i, 2] - s2 * e1[i, 1]
                q1 = s2 * e1[i, 0] - s0 * e1[i, 2]
                q2 = s0 * e1[i, 1] - s1 * e1[i, 0]
                inv = 1.0 / det
                u = (p0 * s0 + p1 * s1 + p2 * s2) * inv
                v = (dx * q0 + dy * q1 + dz * q2) * inv
                t = (e2[i, 0] * q0 + e2[i, 1] * q1 + e2[i, 2] * q2) * inv
                if u >= 0.0 and v >= 0.0 and u + v <= 1.0 and t >= t_min and t < bt:
                    bt = t
        if box_half.shape[0]:
            norm = np.sqrt(dx * dx + dy * dy + dz * dz)
            for b in range(box_half.shape[0]):
                if b == skip[r]:
                    continue
                # cull by the box's bounding sphere seen from the origin
                cone = np.sqrt(max(1.0 - (radius[b] / dist[b]) ** 2, 0.0))
                cos_limit = cone if dist[b] > radius[b] else -2.0
                if (dx * toward[b, 0] + dy * toward[b, 1] + dz * toward[b, 2]) / norm < cos_limit - 1e-9:
                    continue
                t_lo, t_hi = -np.inf, np.inf
                for a in range(3):  # origin and direction in the box frame
                    ob = (box_R[b, 0, a] * (o[0] - box_c[b, 0]) + box_R[b, 1, a] * (o[1] - box_c[b, 1])
                          + box_R[b, 2, a] * (o[2] - box_c[b, 2]))
                    db = box_R[b, 0, a] * dx + box_R[b, 1, a] * dy + box_R[b, 2, a] * dz
                    h = box_half[b, a]
                    if db == 0.0:
                        if abs(ob) > h:
                            t_lo, t_hi = np.inf, -np.inf
                        continue
                    t1, t2 = (-h - ob) / db, (h - ob) / db
                    t_lo = max(t_lo, min(t1, t2))
                    t_hi = min(t_hi, max(t1, t2))
                if t_hi >= t_lo and t_lo >= t_min and t_lo < bt:
                    bt = t_lo
        best[r] = bt
    return best


def raycast_visibility(
    scene: RayScene,
    landmarks_xyz: ArrayLike,
    ids: ArrayLike,
    cam_from_world: ArrayLike,
    camera: Camera,
    *,
    radius: int = 1,
    abs_tol: float = 0.03,
    rel_tol: float = 0.004,
    skip_box: int = -1,
) -> dict[str, NDArray]:
    """:func:`~uav_struct_env.sim.visibility.landmark_visibility` by ray casting (no depth image).

    ``skip_box``: the index in the scene's boxes of one the rays pass through unseen (-1: none),
    e.g. the camera's own airframe. Returns the same dict: ``ids``, ``xyz``, ``uv``,
    ``in_frame``, ``visible``.
    """
    xyz = as_points("landmarks_xyz", landmarks_xyz, 3)
    ids_arr = np.asarray(ids, dtype=np.int64).reshape(-1)
    if ids_arr.shape != (len(xyz),):
        raise ValueError(f"ids must be ({len(xyz)},) integers, got shape {ids_arr.shape}")
    T = check_transform("cam_from_world", cam_from_world)
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a uav_struct_env.sim.camera.Camera, got {type(camera).__name__}")
    check_number("radius (pixels)", radius, 0, integer=True, type_error=ValueError)
    if not -1 <= skip_box < len(scene._box_halves):
        raise ValueError(f"skip_box must be -1 or one of the scene's {len(scene._box_halves)} boxes, "
                         f"got {skip_box}")
    R, t = np.ascontiguousarray(T[:3, :3]), T[:3, 3]
    K = camera.K
    # The depth is exact (no buffer quantization): the tolerance of a 24-bit buffer.
    xyz = np.array(xyz, dtype=np.float64, order="C")  # writable, returned: one kernel type (visibility.py)
    uv, in_frame, visible = _raycast_windows(
        xyz, R, np.ascontiguousarray(t), K, inverse_intrinsics(K), -R.T @ t,
        int(camera.width), int(camera.height), float(camera.near), float(camera.far), int(radius),
        float(abs_tol), float(rel_tol), 24, int(skip_box), *scene._arrays(),
    )
    return {"ids": ids_arr.copy(), "xyz": xyz, "uv": uv, "in_frame": in_frame, "visible": visible}


@njit(cache=True, nogil=True)
def _raycast_windows(
    xyz: NDArray, R: NDArray, t: NDArray, K: NDArray, K_inv: NDArray, origin: NDArray, width: int,
    height: int, near: float, far: float, radius: int, abs_tol: float, rel_tol: float, depth_bits: int,
    skip_box: int, rects: NDArray, lo: NDArray, hi: NDArray, start: NDArray, count: NDArray,
    v0: NDArray, e1: NDArray, e2: NDArray, box_R: NDArray, box_c: NDArray, box_half: NDArray,
) -> tuple[NDArray, NDArray, NDArray]:
    """The depth test of :mod:`uav_struct_env.sim.visibility` on ray-cast depths, compiled.

    The windows and depth limits of the depth test
    (:func:`~uav_struct_env.sim.visibility._window_limits`); a ray through each in-frame
    landmark's window centre first (a landmark it shows is visible whatever the other pixels
    show), then rays through the other pixels of the windows whose centre is hidden; a pixel's
    depth is its first hit (:func:`_first_hit`, from ``origin``, the camera centre) capped at
    ``far``. Returns ``(uv, in_frame, visible)``.
    """
    uv, in_frame, rows, cols, idx, limit = _window_limits(
        xyz, R, t, K, width, height, near, far, radius, abs_tol, rel_tol, depth_bits
    )
    visible = np.zeros(xyz.shape[0], dtype=np.bool_)
    f = rows.shape[0]
    if f == 0:
        return uv, in_frame, visible
    depth = _first_hit(origin, _pixel_rays(rows[:, radius, radius].copy(), cols[:, radius, radius].copy(),
                                           K_inv, R),
                       near, np.full(f, skip_box, dtype=np.int64), rects, lo, hi, start, count, v0, e1,
                       e2, box_R, box_c, box_half)
    rest = []
    for j in range(f):
        d = depth[j]
        visible[idx[j]] = (far if far < d else d) >= limit[j]  # np.minimum(depth, far), NaN kept
        if not visible[idx[j]]:
            rest.append(j)
    if len(rest) == 0:
        return uv, in_frame, visible
    k = 2 * radius + 1
    n = len(rest) * k * k
    rr = np.empty(n, dtype=rows.dtype)
    cc = np.empty(n, dtype=cols.dtype)
    for q in range(len(rest)):
        for a in range(k):
            for b in range(k):
                rr[(q * k + a) * k + b] = rows[rest[q], a, b]
                cc[(q * k + a) * k + b] = cols[rest[q], a, b]
    depth = _first_hit(origin, _pixel_rays(rr, cc, K_inv, R), near, np.full(n, skip_box, dtype=np.int64),
                       rects, lo, hi, start, count, v0, e1, e2, box_R, box_c, box_half)
    for q in range(len(rest)):
        j = rest[q]
        for p in range(k * k):
            d = depth[q * k * k + p]
            if (far if far < d else d) >= limit[j]:
                visible[idx[j]] = True
                break
    return uv, in_frame, visible


@njit(cache=True, nogil=True)
def _pixel_rays(rows: NDArray, cols: NDArray, K_inv: NDArray, R: NDArray) -> NDArray:
    """(n, 3) world-frame directions of the rays through pixel centres ``(cols, rows)``.

    ``R^T K^-1 (u, v, 1)``: the camera-frame direction has z = 1, so a hit's ray parameter is its
    depth along the optical axis.
    """
    out = np.empty((rows.shape[0], 3))
    for i in range(rows.shape[0]):
        u, v = float(cols[i]), float(rows[i])
        c0 = u * K_inv[0, 0] + v * K_inv[0, 1] + K_inv[0, 2]
        c1 = u * K_inv[1, 0] + v * K_inv[1, 1] + K_inv[1, 2]
        c2 = u * K_inv[2, 0] + v * K_inv[2, 1] + K_inv[2, 2]
        for a in range(3):
            out[i, a] = c0 * R[0, a] + c1 * R[1, a] + c2 * R[2, a]
    return out
