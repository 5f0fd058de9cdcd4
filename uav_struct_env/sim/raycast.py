"""Landmark visibility from geometry: the depth test without rendering a pixel.

When nothing reads the image (a state-only policy on simulated detections), rendering a frame
only to depth-test the landmarks is most of an env step. :class:`RayScene` holds the triangles
that a :class:`~uav_struct_env.sim.world.SiteWorld` renders (site elements, ground, markers) and
the oriented boxes it adds (UAV airframes), and casts rays through pixel centres against them:
pure numpy, each mesh culled by its bounding box first, Möller–Trumbore on the triangles left.

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
from numpy.typing import ArrayLike, NDArray

from localization.geometry import as_points, check_transform
from uav_struct_env.sim.camera import Camera
from uav_struct_env.sim.visibility import window_visibility

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
        self._v0, self._e1, self._e2 = allt[:, 0], allt[:, 1] - allt[:, 0], allt[:, 2] - allt[:, 0]
        self._start, self._count = np.cumsum(counts) - counts, counts
        pad = 1e-6  # boxes of flat meshes get a non-zero thickness
        self._lo = np.array(lo).reshape(-1, 3) - pad
        self._hi = np.array(hi).reshape(-1, 3) + pad
        self._rects = np.array(rects, dtype=np.float64).reshape(-1, 5)
        self._box_poses, self._box_halves = np.zeros((0, 4, 4)), np.zeros((0, 3))

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
        self._box_halves = np.asarray(half_extents, dtype=np.float64).reshape(-1, 3)

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
        o = np.asarray(origin, dtype=np.float64).reshape(3)
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        best = np.full(len(d), np.inf)
        if len(d) == 0:
            return best
        for x0, x1, y0, y1, z in self._rects:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (z - o[2]) / d[:, 2]
                x, y = o[0] + t * d[:, 0], o[1] + t * d[:, 1]
                hit = (t >= t_min) & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
            best = np.where(hit & (t < best), t, best)
        near, far = _slab(o, d, self._lo, self._hi)  # (R, G)
        rays, groups = np.nonzero((far >= np.maximum(near, t_min)) & (near < best[:, None]))
        if len(rays):
            n = self._count[groups]
            ray = np.repeat(rays, n)
            first = np.repeat(self._start[groups] - (np.cumsum(n) - n), n)
            tri = first + np.arange(len(ray))
            t = _moller_trumbore(o, d[ray], self._v0[tri], self._e1[tri], self._e2[tri], t_min)
            np.minimum.at(best, ray, t)
        if len(self._box_poses):
            R, c, half = self._box_poses[:, :3, :3], self._box_poses[:, :3, 3], self._box_halves
            # Cull ray-box pairs by the box's bounding sphere seen from the origin (one matrix
            # product), then slab-test the pairs left.
            oc = c - o
            dist = np.linalg.norm(oc, axis=1)
            radius = np.linalg.norm(half, axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                cone = np.sqrt(np.maximum(1.0 - (radius / dist) ** 2, 0.0))  # cos of the half angle
                cos_limit = np.where(dist > radius, cone, -2.0)
                unit = d / np.linalg.norm(d, axis=1, keepdims=True)
                toward = oc / np.maximum(dist, 1e-12)[:, None]
            ray, box = np.nonzero(unit @ toward.T >= cos_limit[None] - 1e-9)
            if skip_box is not None and len(ray):
                keep = np.asarray(skip_box, dtype=np.int64).reshape(-1)[ray] != box
                ray, box = ray[keep], box[keep]
            if len(ray):
                ob = np.einsum("pij,pi->pj", R[box], o - c[box])  # origin in the box frame
                db = np.einsum("pi,pij->pj", d[ray], R[box])  # direction in the box frame
                hb = half[box]
                with np.errstate(divide="ignore", invalid="ignore"):
                    inv = 1.0 / db
                    t1, t2 = (-hb - ob) * inv, (hb - ob) * inv
                inside = np.abs(ob) <= hb  # a ray parallel to a slab is limited only outside it
                parallel = db == 0
                t_lo = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
                t_hi = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
                entry = np.where((t_hi >= t_lo) & (t_lo >= t_min), t_lo, np.inf)
                np.minimum.at(best, ray, entry)
        return best


def _area(tri: NDArray[np.float64]) -> float:
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


def _slab(o: NDArray, d: NDArray, lo: NDArray, hi: NDArray) -> tuple[NDArray, NDArray]:
    """Entry and exit ray parameters of rays ``(R,)`` through axis-aligned boxes ``(G,)``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d  # (R, 3); +-inf along an axis the ray does not move on
        t1 = (lo[None] - o) * inv[:, None]
        t2 = (hi[None] - o) * inv[:, None]
    zero = d == 0
    if not zero.any():
        return np.minimum(t1, t2).max(axis=2), np.maximum(t1, t2).min(axis=2)
    # A ray parallel to a slab: inside it (0 * inf = nan) never limits, outside it misses.
    parallel = zero[:, None, :]
    inside = (o >= lo) & (o <= hi)  # (G, 3)
    t_lo = np.where(parallel, np.where(inside[None], -np.inf, np.inf), np.minimum(t1, t2))
    t_hi = np.where(parallel, np.where(inside[None], np.inf, -np.inf), np.maximum(t1, t2))
    return t_lo.max(axis=2), t_hi.min(axis=2)


def _cross(a: NDArray, b: NDArray) -> NDArray:
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _moller_trumbore(o, d, v0, e1, e2, t_min) -> NDArray[np.float64]:
    """Hit ``t`` of ray ``d[i]`` with triangle ``i`` (pairs, all ``(P, 3)``); inf: no hit >= t_min."""
    p = _cross(d, e2)
    det = (p * e1).sum(axis=1)
    s = o - v0
    q = _cross(s, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        u = (p * s).sum(axis=1) * inv
        v = (d * q).sum(axis=1) * inv
        t = (e2 * q).sum(axis=1) * inv
        ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= t_min)
    return np.where(ok, t, np.inf)


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
) -> dict[str, NDArray]:
    """:func:`~uav_struct_env.sim.visibility.landmark_visibility` by ray casting (no depth image).

    Returns the same dict: ``ids``, ``xyz``, ``uv``, ``in_frame``, ``visible``.
    """
    xyz = as_points("landmarks_xyz", landmarks_xyz, 3)
    ids_arr = np.asarray(ids, dtype=np.int64).reshape(-1)
    if ids_arr.shape != (len(xyz),):
        raise ValueError(f"ids must be ({len(xyz)},) integers, got shape {ids_arr.shape}")
    T = check_transform("cam_from_world", cam_from_world)
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a uav_struct_env.sim.camera.Camera, got {type(camera).__name__}")
    R, t = T[:3, :3], T[:3, 3]
    K_inv = np.linalg.inv(camera.K)

    def ray_depths(rows: NDArray[np.intp], cols: NDArray[np.intp]) -> NDArray[np.float64]:
        pixels = np.stack([cols.ravel(), rows.ravel(), np.ones(cols.size)], axis=1).astype(np.float64)
        rays_cam = pixels @ K_inv.T  # z = 1: a hit's t is its depth
        depth = scene.first_hit(-R.T @ t, rays_cam @ R, t_min=camera.near)
        return np.minimum(depth, camera.far).reshape(rows.shape)

    # The depth is exact (no buffer quantization): the tolerance of a 24-bit buffer.
    return window_visibility(xyz, ids_arr, T, camera, ray_depths, radius=radius, abs_tol=abs_tol,
                             rel_tol=rel_tol, depth_bits=24)
