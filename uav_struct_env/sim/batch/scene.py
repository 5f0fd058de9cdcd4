"""A SiteWorld's renderable geometry as flat arrays, and batches of scenes packed together.

:class:`BatchScene` reads a :class:`~uav_struct_env.sim.world.SiteWorld` once: every triangle of
its site elements (project-frame corners, texture coordinates, flat normal, texture, the
element's pybullet body id) and every element's texture. The ground is not kept as triangles:
its mesh (``site.mesh.ground_elements``) is a grid of axis-aligned quads at z = 0, cut only so
its texture coordinates can follow a logarithmic warp, with cells missing under marker sheets,
and :func:`ground_grid` reads it back as that grid -- the x and y breaks, the texture coordinate
at each break and which cells exist -- for the rasterizer to draw per pixel (the ray's
intersection with z = 0) at a cost that does not grow with its ~1,700 triangles. The bodies added with
``SiteWorld.add_body`` (airframes, workers, equipment, materials) are oriented boxes read from
the world at each render (:meth:`BatchScene.boxes`), so they are drawn where pybullet draws them.
:class:`PackedScenes` concatenates the static arrays of several scenes for one compiled call and
is kept while the same scenes are rendered together.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = ["BatchScene", "GroundGrid", "PackedScenes", "ground_grid"]

_UIDS = itertools.count()


class GroundGrid(NamedTuple):
    """A ground mesh as a grid: quad ``(i, j)`` spans ``x[i]..x[i + 1]`` by ``y[j]..y[j + 1]`` at z = 0.

    ``u[i]`` is the texture ``u`` at every vertex at ``x[i]``, ``v[j]`` the texture ``v`` at
    every vertex at ``y[j]``; ``cells[i, j]`` is 1 where the quad exists (0: a hole).
    """

    x: NDArray[np.float64]
    u: NDArray[np.float64]
    y: NDArray[np.float64]
    v: NDArray[np.float64]
    cells: NDArray[np.uint8]


def _breaks(coord: NDArray, tex: NDArray) -> tuple[NDArray, NDArray, NDArray] | None:
    """(sorted breaks, the texture coordinate at each, each vertex's break index) or None.

    None when two vertices at the same break carry different texture coordinates.
    """
    breaks, index = np.unique(coord, return_inverse=True)
    at = np.zeros(len(breaks))
    at[index] = tex
    return (breaks, at, index) if np.array_equal(at[index], tex) else None


def ground_grid(element) -> GroundGrid | None:
    """The grid of a ground element's mesh, or None if its mesh is not one.

    A grid: vertices in fours, each four a quad ``(x0, y0), (x1, y0), (x1, y1), (x0, y1)`` at
    z = 0 between consecutive breaks (triangles ``0 1 2`` and ``0 2 3``, facing +z), no quad
    twice, and the texture ``u`` a function of x alone and ``v`` of y alone. Within a quad the
    rasterizer's perspective-correct interpolation of such coordinates is linear in x and y, so
    a pixel's texture coordinate follows from its ray's intersection with z = 0.
    """
    verts = np.asarray(element.mesh.vertices, dtype=np.float64)
    faces = np.asarray(element.mesh.faces, dtype=np.int64)
    n = len(verts) // 4
    base = 4 * np.arange(n)[:, None]
    quad_faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    if n == 0 or len(verts) != 4 * n or not np.array_equal(faces, quad_faces) or np.any(verts[:, 2] != 0.0):
        return None
    xs, ys = _breaks(verts[:, 0], element.uv[:, 0]), _breaks(verts[:, 1], element.uv[:, 1])
    if xs is None or ys is None:
        return None
    i, j = xs[2].reshape(n, 4), ys[2].reshape(n, 4)
    i0, j0 = i[:, 0], j[:, 0]
    corners = np.stack([i0, j0, i0 + 1, j0, i0 + 1, j0 + 1, i0, j0 + 1], axis=1)
    cells = np.zeros((len(xs[0]) - 1, len(ys[0]) - 1), dtype=np.uint8)
    if not np.array_equal(np.stack([i, j], axis=2).reshape(n, 8), corners):
        return None
    cells[i0, j0] += 1
    if cells.max() > 1:
        return None
    return GroundGrid(xs[0], xs[1], ys[0], ys[1], cells)


class BatchScene:
    """The static triangles and textures of a world, and access to its added boxes.

    Args:
        world: a :class:`~uav_struct_env.sim.world.SiteWorld`; its elements must be those it
            loaded (``world.elements``) and its body ids those pybullet gave them, so the
            segmentation uses pybullet's ids.
        ground_per_pixel: draw a grid ground per pixel (:func:`ground_grid`); False: as triangles
            like every other element (the reference the per-pixel ground is measured against).

    Raises:
        TypeError: if ``world`` is not a SiteWorld.
    """

    def __init__(self, world, *, ground_per_pixel: bool = True) -> None:
        from uav_struct_env.sim.world import SiteWorld

        if not isinstance(world, SiteWorld):
            raise TypeError(f"world must be a uav_struct_env.sim.world.SiteWorld, got {type(world).__name__}")
        self.world = world
        #: Unique per scene for the life of the process (packing caches key on it).
        self.uid = next(_UIDS)
        body_ids = world.body_ids
        #: The ground drawn per pixel (:func:`ground_grid`), its texture index and body id; None:
        #: no ground, or one that is not a grid (then drawn as triangles like the rest).
        self.ground: GroundGrid | None = None
        self.ground_tex, self.ground_seg = -1, -1
        # each list starts with an empty array: a world may have no triangles but the ground's
        verts, uvs, normals = [np.zeros((0, 3, 3))], [np.zeros((0, 3, 2))], [np.zeros((0, 3))]
        tex, seg, textures = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], []
        for k, element in enumerate(world.elements):
            textures.append(np.ascontiguousarray(element.texture[:, :, :3], dtype=np.uint8))
            per_pixel = ground_per_pixel and element.kind == "ground" and self.ground is None
            grid = ground_grid(element) if per_pixel else None
            if grid is not None:
                self.ground, self.ground_tex, self.ground_seg = grid, k, body_ids[element.name]
                continue
            mesh = element.mesh
            faces = np.asarray(mesh.faces, dtype=np.int64)
            verts.append(np.asarray(mesh.vertices, dtype=np.float64)[faces])
            uvs.append(element.uv[faces])
            n = np.asarray(mesh.vertex_normals, dtype=np.float64)[faces].sum(axis=1)
            normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))
            tex.append(np.full(len(faces), k, dtype=np.int64))
            seg.append(np.full(len(faces), body_ids[element.name], dtype=np.int64))
        self.tri_v = np.ascontiguousarray(np.concatenate(verts))
        self.tri_uv = np.ascontiguousarray(np.concatenate(uvs))
        self.tri_n = np.ascontiguousarray(np.concatenate(normals))
        self.tri_tex = np.concatenate(tex)
        self.tri_seg = np.concatenate(seg)
        self.textures = textures
        #: Every texture's texels in one (N, 3) array; texture k starts at row ``tex_off[k]``.
        sizes = np.array([t.shape[0] * t.shape[1] for t in textures], dtype=np.int64)
        self.tex_off = np.cumsum(sizes) - sizes
        self.tex_w = np.array([t.shape[1] for t in textures], dtype=np.int64)
        self.tex_h = np.array([t.shape[0] for t in textures], dtype=np.int64)
        self.tex_data = np.concatenate([t.reshape(-1, 3) for t in textures])

    @property
    def n_triangles(self) -> int:
        """Static triangles drawn as triangles (site elements, markers; the ground if not a grid)."""
        return len(self.tri_v)

    def boxes(self) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """The world's added bodies now.

        Returns:
            rotations (B, 3, 3), centres (B, 3), half extents (B, 3), colours (B, 3) in 0-255 and
            body ids (B,).
        """
        ids, poses, halves, rgba = self.world.added_bodies()
        return poses[:, :3, :3], poses[:, :3, 3], halves, rgba[:, :3] * 255.0, ids


def _with_slopes(breaks: NDArray, coords: NDArray) -> NDArray:
    """(N, 2): ``coords`` and the slope from each break to the next (0 at the last)."""
    slopes = np.zeros(len(breaks))
    slopes[:-1] = np.diff(coords) / np.diff(breaks)
    return np.ascontiguousarray(np.column_stack([coords, slopes]))


class PackedScenes:
    """The static arrays of several scenes, concatenated for :func:`~.raster.render_views`.

    Attributes:
        key: the scenes' uids, in order.
        scene_tris: (S, 2) each scene's triangle range.
        scene_ground: (S, 7) each scene's ground grid: the ranges of its x breaks (and ``u``) and
            y breaks (and ``v``) in ``ground_x`` / ``ground_y`` (``ground_u`` / ``ground_v``: (N, 2),
            the coordinate at each break and its slope to the next, 0 at the last), the offset of
            its cells (x-major) in ``ground_cells``, its texture index and its body id; texture
            -1: no grid ground.
    """

    def __init__(self, scenes: Sequence[BatchScene]) -> None:
        self.key = tuple(s.uid for s in scenes)
        counts = np.array([s.n_triangles for s in scenes], dtype=np.int64)
        ends = np.cumsum(counts)
        self.scene_tris = np.stack([ends - counts, ends], axis=1)
        tex_base = np.cumsum([0] + [len(s.textures) for s in scenes])
        texel_base = np.cumsum([0] + [len(s.tex_data) for s in scenes])
        # one scene: its own arrays (np.concatenate of one array would copy the texels)
        join = (lambda arrays: arrays[0]) if len(scenes) == 1 else np.concatenate
        self.tri_v = join([s.tri_v for s in scenes])
        self.tri_uv = join([s.tri_uv for s in scenes])
        self.tri_n = join([s.tri_n for s in scenes])
        self.tri_tex = join([s.tri_tex + b for s, b in zip(scenes, tex_base, strict=False)])
        self.tri_seg = join([s.tri_seg for s in scenes])
        self.tex_off = join([s.tex_off + b for s, b in zip(scenes, texel_base, strict=False)])
        self.tex_w = join([s.tex_w for s in scenes])
        self.tex_h = join([s.tex_h for s in scenes])
        self.tex_data = join([s.tex_data for s in scenes])
        self._pack_ground(scenes, tex_base)

    def _pack_ground(self, scenes: Sequence[BatchScene], tex_base: NDArray) -> None:
        grids = [s.ground for s in scenes]
        nx = np.array([0 if g is None else len(g.x) for g in grids], dtype=np.int64)
        ny = np.array([0 if g is None else len(g.y) for g in grids], dtype=np.int64)
        nc = np.array([0 if g is None else g.cells.size for g in grids], dtype=np.int64)
        tex = [-1 if s.ground is None else s.ground_tex + b for s, b in zip(scenes, tex_base, strict=False)]
        self.scene_ground = np.stack([
            np.cumsum(nx) - nx, np.cumsum(nx), np.cumsum(ny) - ny, np.cumsum(ny), np.cumsum(nc) - nc,
            np.array(tex, dtype=np.int64), np.array([s.ground_seg for s in scenes], dtype=np.int64),
        ], axis=1)
        present = [g for g in grids if g is not None]
        self.ground_x, self.ground_y = (
            np.concatenate([np.zeros(0)] + [g[i] for g in present]) for i in (0, 2)
        )
        self.ground_u, self.ground_v = (
            np.concatenate([np.zeros((0, 2))] + [_with_slopes(g[i - 1], g[i]) for g in present])
            for i in (1, 3)
        )
        self.ground_cells = np.concatenate([np.zeros(0, np.uint8)] + [g.cells.ravel() for g in present])

    def arrays(self) -> tuple[NDArray, ...]:
        """The static arguments of :func:`~.raster.render_views`, after ``scene_boxes``."""
        return (self.tri_v, self.tri_uv, self.tri_n, self.tri_tex, self.tri_seg,
                self.tex_data, self.tex_off, self.tex_w, self.tex_h, self.scene_ground,
                self.ground_x, self.ground_u, self.ground_y, self.ground_v, self.ground_cells)
