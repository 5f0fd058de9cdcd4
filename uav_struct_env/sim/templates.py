"""Renders of the building model for the BIM-guided detector: the structure as the design has it.

:class:`SiteTemplates` follows :class:`localization.detect.guided.TemplateSource`: it draws a
:class:`~uav_struct_env.site.Site` (its built elements at the stage, the ground and the markers:
what the building model and the site plan know before the flight) with the compiled rasterizer
of :mod:`uav_struct_env.sim.batch.raster`, every element in one flat grey, lit by the default
sun. Nothing the simulator knows beyond the model enters: no textures, no site activity (workers,
equipment, materials), no as-built deviations. One call renders several views of one pose that
differ in their intrinsics (patches: a view whose principal point is moved so that it is centred
on a predicted landmark), without the batch renderer's frame-size cap, which is there for whole
frames at training resolution.

    from uav_struct_env.sim.templates import SiteTemplates

    templates = SiteTemplates(site)
    views = templates.render(cam_from_world, Ks, (64, 64))   # Ks (V, 3, 3)
    views.shade.shape, views.depth.shape, views.label.shape    # (V, 64, 64) each
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from localization.detect.guided import ModelViews
from localization.geometry.transforms import check_transform
from uav_struct_env.site import Site
from uav_struct_env.site.mesh import shared_site_elements

__all__ = ["SiteTemplates"]

#: Grey level of every element (0-255) before lighting.
_ALBEDO = 200.0
#: Clip planes of the template camera, m.
_NEAR, _FAR = 0.1, 1000.0
#: (direction towards the sun, ambient, diffuse): the default sun of ``sim.world``.
_LIGHT_COEFFS = (0.55, 0.45)
_SUN = np.array([0.45, -0.35, 1.0])



#: The ground-grid arguments of ``render_views`` for a scene without a ground (texture index -1):
#: the model views show the building alone.
_NO_GROUND = (np.array([[0, 0, 0, 0, 0, -1, -1]], np.int64), np.zeros(0), np.zeros((0, 2)), np.zeros(0),
              np.zeros((0, 2)), np.zeros(0, np.uint8))

def _orientation_label(normals: np.ndarray) -> np.ndarray:
    """(T,) int64 label of each triangle: its normal's direction quantized to 0.1 per axis.

    The label is the face orientation alone, not the element: faces of two elements that lie in
    one plane (a wall flush with a slab's edge) would fight over the same pixels in the render
    and draw a speckle of edges that the image does not show (its lighting is the same on both);
    an edge of the structure is where the orientation changes (a crease, a face turned to the
    sky against one turned to the side) or the model ends.
    """
    unit = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    q = np.round(unit * 10).astype(np.int64) + 10  # 0-20 per axis
    return q[:, 0] * 441 + q[:, 1] * 21 + q[:, 2]


class SiteTemplates:
    """The building model of ``site`` as a :class:`~localization.detect.guided.TemplateSource`.

    Args:
        site: the site as designed (the localizer's model), at its stage.

    Raises:
        TypeError: if ``site`` is not a Site.
    """

    def __init__(self, site: Site) -> None:
        if not isinstance(site, Site):
            raise TypeError(f"site must be a uav_struct_env.site.Site, got {type(site).__name__}")
        # Textures are not drawn: the smallest ones keep the set-up cheap.
        elements = shared_site_elements(site, np.random.default_rng(0), texture_size=16)
        verts, normals, labels = [], [], []
        # The ground is no structure: its far border (a horizon) is not where the image's is.
        for element in (e for e in elements if e.kind != "ground"):
            mesh = element.mesh
            faces = np.asarray(mesh.faces, dtype=np.int64)
            verts.append(np.asarray(mesh.vertices, dtype=np.float64)[faces])
            n = np.asarray(mesh.vertex_normals, dtype=np.float64)[faces].sum(axis=1)
            normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12))
            labels.append(_orientation_label(n))
        n_tri = sum(len(v) for v in verts)
        self.site = site
        self.n_triangles = n_tri
        self._tri_v = np.ascontiguousarray(np.concatenate(verts))
        self._tri_n = np.ascontiguousarray(np.concatenate(normals))
        self._tri_seg = np.concatenate(labels)
        self._tri_uv = np.zeros((n_tri, 3, 2))
        self._tri_tex = np.zeros(n_tri, dtype=np.int64)
        self._texture = (np.full((1, 3), _ALBEDO, dtype=np.uint8), np.zeros(1, np.int64),
                         np.ones(1, np.int64), np.ones(1, np.int64))
        sun = _SUN / np.linalg.norm(_SUN)
        self._light = np.array([*sun, *_LIGHT_COEFFS])

    def render(self, cam_from_world: ArrayLike, Ks: ArrayLike, size: tuple[int, int]) -> ModelViews:
        """Views of the model from ``cam_from_world`` (4, 4), one through each of ``Ks`` (V, 3, 3).

        Every view is ``size`` (W, H) pixels.

        Returns:
            :class:`~localization.detect.guided.ModelViews`: shading (V, H, W) in 0-1, depth
            along the optical axis (V, H, W; inf where no surface) and element labels (V, H, W;
            -1 where no surface).
        """
        from uav_struct_env.sim.batch.raster import render_views  # numba: compiled on first use

        T = check_transform("cam_from_world", cam_from_world)
        Ks = np.asarray(Ks, dtype=np.float64).reshape(-1, 3, 3)
        w, h = (int(v) for v in size)
        n = len(Ks)
        rgb = np.empty((n, h, w, 3), np.uint8)
        depth = np.empty((n, h, w), np.float32)
        seg = np.empty((n, h, w), np.int32)
        intr = np.stack([Ks[:, 0, 0], Ks[:, 0, 1], Ks[:, 0, 2], Ks[:, 1, 1], Ks[:, 1, 2]], axis=1)
        empty3 = np.zeros((0, 3))
        render_views(
            np.zeros(n, np.int64), np.repeat(T[None, :3, :3], n, axis=0),
            np.repeat(T[None, :3, 3], n, axis=0),
            np.ascontiguousarray(intr), np.tile([_NEAR, _FAR], (n, 1)), np.tile(self._light, (n, 1)),
            np.full(n, -1, np.int64), np.zeros(3, np.uint8),
            np.array([[0, self.n_triangles]], np.int64), np.zeros((1, 2), np.int64),
            self._tri_v, self._tri_uv, self._tri_n, self._tri_tex, self._tri_seg, *self._texture,
            *_NO_GROUND,
            np.zeros((0, 3, 3)), empty3, empty3, empty3, np.zeros(0, np.int64), rgb, depth, seg,
        )
        empty = seg < 0
        depth[empty] = np.inf
        return ModelViews(rgb[..., 0].astype(np.float32) / 255.0, depth, seg)
