"""A SiteWorld's renderable geometry as flat arrays, and batches of scenes packed together.

:class:`BatchScene` reads a :class:`~uav_struct_env.sim.world.SiteWorld` once: every triangle of
its site elements (project-frame corners, texture coordinates, flat normal, texture, the
element's pybullet body id) and every element's texture. The bodies added with
``SiteWorld.add_body`` (airframes, workers, equipment, materials) are oriented boxes read from
the world at each render (:meth:`BatchScene.boxes`), so they are drawn where pybullet draws them.
:class:`PackedScenes` concatenates the static arrays of several scenes for one compiled call and
is kept while the same scenes are rendered together.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["BatchScene", "PackedScenes"]

_UIDS = itertools.count()


class BatchScene:
    """The static triangles and textures of a world, and access to its added boxes.

    Args:
        world: a :class:`~uav_struct_env.sim.world.SiteWorld`; its elements must be those it
            loaded (``world.elements``) and its body ids those pybullet gave them, so the
            segmentation uses pybullet's ids.

    Raises:
        TypeError: if ``world`` is not a SiteWorld.
    """

    def __init__(self, world) -> None:
        from uav_struct_env.sim.world import SiteWorld

        if not isinstance(world, SiteWorld):
            raise TypeError(f"world must be a uav_struct_env.sim.world.SiteWorld, got {type(world).__name__}")
        self.world = world
        #: Unique per scene for the life of the process (packing caches key on it).
        self.uid = next(_UIDS)
        body_ids = world.body_ids
        verts, uvs, normals, tex, seg, textures = [], [], [], [], [], []
        for k, element in enumerate(world.elements):
            mesh = element.mesh
            faces = np.asarray(mesh.faces, dtype=np.int64)
            verts.append(np.asarray(mesh.vertices, dtype=np.float64)[faces])
            uvs.append(element.uv[faces])
            n = np.asarray(mesh.vertex_normals, dtype=np.float64)[faces].sum(axis=1)
            normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))
            tex.append(np.full(len(faces), k, dtype=np.int64))
            seg.append(np.full(len(faces), body_ids[element.name], dtype=np.int64))
            textures.append(np.ascontiguousarray(element.texture[:, :, :3], dtype=np.uint8))
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
        """Static triangles (site elements, ground, markers)."""
        return len(self.tri_v)

    def boxes(self) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """The world's added bodies now.

        Returns:
            rotations (B, 3, 3), centres (B, 3), half extents (B, 3), colours (B, 3) in 0-255 and
            body ids (B,).
        """
        ids, poses, halves, rgba = self.world.added_bodies()
        return poses[:, :3, :3], poses[:, :3, 3], halves, rgba[:, :3] * 255.0, ids


class PackedScenes:
    """The static arrays of several scenes, concatenated for :func:`~.raster.render_views`.

    Attributes:
        key: the scenes' uids, in order.
        scene_tris: (S, 2) each scene's triangle range.
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

    def arrays(self) -> tuple[NDArray, ...]:
        """The static arguments of :func:`~.raster.render_views`, after ``scene_boxes``."""
        return (self.tri_v, self.tri_uv, self.tri_n, self.tri_tex, self.tri_seg,
                self.tex_data, self.tex_off, self.tex_w, self.tex_h)
