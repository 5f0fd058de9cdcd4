"""Triangle meshes with texture coordinates for every element of a site, and their textures.

Each element built at the site's stage (columns, slabs with their openings cut out, beams,
walls), the ground and each marker sheet becomes a :class:`SiteElement`: a ``trimesh.Trimesh``
in the project frame with per-vertex UVs and flat normals, plus its own texture image. Elements
are built from planar rectangular :class:`Face` s; the faces of one element are laid out in a
texture atlas at a uniform scale (metres per texel), side faces of a box as one continuous strip
so the concrete grain runs around corners. Slab faces with openings are split into the
rectangles around the openings (exact for axis-aligned openings, no triangulation library
needed). Any other element (an imported IFC element with its own triangles, or a prism with a
slanted outline) becomes a :func:`solid_element`: its triangles, each textured by projection
onto the axis plane it faces.

Textures are drawn from a ``numpy.random.Generator``: each element gets its own child generator
(``rng.spawn``), so no two surfaces share a texture and adding an element does not change the
others' textures.

UV convention (Wavefront OBJ): ``v`` points up the image, so texture row 0 is at ``v = 1``.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from uav_struct_env.site.elements import Column, Element, Slab
from uav_struct_env.site.markers import ArucoMarker
from uav_struct_env.site.model import Site
from uav_struct_env.site.polygons import is_axis_aligned_rectangle
from uav_struct_env.site.textures import (
    aruco_texture,
    concrete_texture,
    ground_texture,
)

__all__ = [
    "ELEMENT_KINDS",
    "Face",
    "SiteElement",
    "box_faces",
    "build_mesh",
    "column_element",
    "ground_elements",
    "marker_element",
    "obj_files",
    "shared_site_elements",
    "site_elements",
    "slab_element",
    "solid_element",
    "write_obj",
]

ELEMENT_KINDS = ("column", "slab", "beam", "wall", "ground", "marker")

#: Gutter between atlas islands, in texels, against bilinear/mipmap bleeding.
_GUTTER_TEXELS = 4


@dataclass(frozen=True)
class Face:
    """A planar rectangle ``origin + a * axis_a + b * axis_b``, ``a, b`` within ``size``.

    The outward normal is ``axis_a x axis_b``. ``holes`` are rectangles ``(a0, b0, a1, b1)`` in
    the face's own coordinates that are cut out.
    """

    origin: tuple[float, float, float]
    axis_a: tuple[float, float, float]
    axis_b: tuple[float, float, float]
    size: tuple[float, float]
    holes: tuple[tuple[float, float, float, float], ...] = ()

    @property
    def normal(self) -> NDArray[np.float64]:
        """Unit outward normal."""
        n = np.cross(self.axis_a, self.axis_b)
        return n / np.linalg.norm(n)

    def cells(self) -> list[tuple[float, float, float, float]]:
        """The face minus its holes as rectangles ``(a0, b0, a1, b1)``."""
        la, lb = self.size
        a_breaks = sorted({0.0, la, *[h[0] for h in self.holes], *[h[2] for h in self.holes]})
        b_breaks = sorted({0.0, lb, *[h[1] for h in self.holes], *[h[3] for h in self.holes]})
        out = []
        for a0, a1 in zip(a_breaks[:-1], a_breaks[1:], strict=False):
            for b0, b1 in zip(b_breaks[:-1], b_breaks[1:], strict=False):
                am, bm = (a0 + a1) / 2, (b0 + b1) / 2
                if any(h[0] < am < h[2] and h[1] < bm < h[3] for h in self.holes):
                    continue
                out.append((a0, b0, a1, b1))
        return out


@dataclass(frozen=True, eq=False)
class SiteElement:
    """One renderable element: a textured mesh in the project frame.

    Attributes:
        name: unique, readable (``"column C1-03"``, ``"slab S1"``, ``"ground"``, ``"marker 4"``).
        kind: one of :data:`ELEMENT_KINDS`.
        mesh: triangles in the project frame with ``mesh.visual.uv`` (N, 2) and flat vertex normals.
        texture: ``(H, W, 3)`` uint8 RGB, row 0 at the top (``v = 1``).
    """

    name: str
    kind: str
    mesh: trimesh.Trimesh
    texture: NDArray[np.uint8] = field(repr=False)

    @property
    def uv(self) -> NDArray[np.float64]:
        """(N, 2) texture coordinates, one per mesh vertex."""
        return np.asarray(self.mesh.visual.uv, dtype=np.float64)


# --------------------------------------------------------------------------------------- geometry
def box_faces(lo: ArrayLike, hi: ArrayLike) -> tuple[list[Face], list[Face], list[Face]]:
    """Faces of the axis-aligned box ``lo..hi``: ``(sides, [top], [bottom])``.

    The sides run counter-clockwise seen from above (-y, +x, +y, -x), each starting where the
    previous one ends, so they unwrap into one continuous strip.
    """
    (x0, y0, z0), (x1, y1, z1) = np.asarray(lo, float), np.asarray(hi, float)
    if not (x1 > x0 and y1 > y0 and z1 > z0):
        raise ValueError(f"box needs lo < hi on every axis, got lo={lo}, hi={hi}")
    h = z1 - z0
    up = (0.0, 0.0, 1.0)
    sides = [
        Face((x0, y0, z0), (1.0, 0.0, 0.0), up, (x1 - x0, h)),
        Face((x1, y0, z0), (0.0, 1.0, 0.0), up, (y1 - y0, h)),
        Face((x1, y1, z0), (-1.0, 0.0, 0.0), up, (x1 - x0, h)),
        Face((x0, y1, z0), (0.0, -1.0, 0.0), up, (y1 - y0, h)),
    ]
    top = Face((x0, y0, z1), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (x1 - x0, y1 - y0))
    bottom = Face((x0, y1, z0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (x1 - x0, y1 - y0))
    return sides, [top], [bottom]


def _pack(
    strips: Sequence[Sequence[Face]], gutter: float
) -> tuple[list[tuple[float, float]], float]:
    """Shelf-pack strips (faces laid side by side along u) into a square atlas.

    Returns the (u, v) offset in metres of each strip's lower-left corner and the atlas side in
    metres. Strips are placed tallest first; the atlas width grows until the packing is square.
    """
    dims = [(sum(f.size[0] for f in s), max(f.size[1] for f in s)) for s in strips]
    order = sorted(range(len(strips)), key=lambda k: -dims[k][1])
    width = max(max(w for w, _ in dims), math.sqrt(sum(w * h for w, h in dims))) + 2 * gutter
    while True:
        offsets: list[tuple[float, float]] = [(0.0, 0.0)] * len(strips)
        u, v, shelf = gutter, gutter, 0.0
        for k in order:
            w, h = dims[k]
            if u + w + gutter > width + 1e-9 and u > gutter:
                u, v, shelf = gutter, v + shelf + gutter, 0.0
            offsets[k] = (u, v)
            u += w + gutter
            shelf = max(shelf, h)
        height = v + shelf + gutter
        if height <= width + 1e-9:
            return offsets, width
        width *= 1.05


def build_mesh(
    strips: Sequence[Sequence[Face]], *, gutter: float = 0.0
) -> tuple[trimesh.Trimesh, float]:
    """Triangulate faces and lay them out in one texture atlas.

    Args:
        strips: groups of faces; the faces of a group are placed side by side (continuous texture).
        gutter: space between groups in the atlas, metres.

    Returns:
        ``(mesh, atlas_side)``: the mesh with UVs in [0, 1] and flat normals, and the side of the
        square area (metres) that the texture covers.
    """
    offsets, side = _pack(strips, gutter)
    verts: list[NDArray[np.float64]] = []
    uvs: list[NDArray[np.float64]] = []
    normals: list[NDArray[np.float64]] = []
    for strip, (u0, v0) in zip(strips, offsets, strict=False):
        du = 0.0
        for face in strip:
            o, a, b = (np.asarray(x, float) for x in (face.origin, face.axis_a, face.axis_b))
            for a0, b0, a1, b1 in face.cells():
                corners = np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]])
                verts.append(o + corners[:, :1] * a + corners[:, 1:] * b)
                uvs.append((corners + [u0 + du, v0]) / side)
                normals.append(np.repeat(face.normal[None], 4, axis=0))
            du += face.size[0]
    v = np.concatenate(verts)
    n_quads = len(v) // 4
    base = 4 * np.arange(n_quads)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    mesh = trimesh.Trimesh(
        vertices=v,
        faces=faces,
        vertex_normals=np.concatenate(normals),
        visual=trimesh.visual.TextureVisuals(uv=np.concatenate(uvs)),
        process=False,
    )
    return mesh, side


def _texture_px(extent: float, texel_size: float, max_size: int) -> int:
    """Power-of-two texture side giving about ``texel_size`` metres per texel, capped."""
    want = extent / texel_size
    return int(min(max_size, max(64, 2 ** math.ceil(math.log2(max(want, 1.0))))))


def column_element(
    column: Column, rng: np.random.Generator, *, texel_size: float = 0.015, max_texture: int = 512
) -> SiteElement:
    """A column: a box with its four sides as one strip, top and bottom separately."""
    sx, sy = column.section
    sides, top, bottom = box_faces(
        (column.x - sx / 2, column.y - sy / 2, column.z_bottom),
        (column.x + sx / 2, column.y + sy / 2, column.z_top),
    )
    size = _texture_px(column.z_top - column.z_bottom, texel_size, max_texture)
    gutter = _GUTTER_TEXELS * (column.z_top - column.z_bottom) / size
    mesh, extent = build_mesh([sides, top, bottom], gutter=gutter)
    return SiteElement(f"column {column.name}", "column", mesh, concrete_texture(rng, size, extent))


def slab_element(
    slab: Slab, rng: np.random.Generator, *, texel_size: float = 0.015, max_texture: int = 1024
) -> SiteElement:
    """A slab: top and bottom with the openings cut out, the edge strip and each opening's walls."""
    xmin, ymin, xmax, ymax = slab.bounds
    z1, z0 = slab.z_top, slab.z_top - slab.thickness
    sides, _, _ = box_faces((xmin, ymin, z0), (xmax, ymax, z1))
    top_holes, bottom_holes, strips = [], [], []
    for op in slab.openings:
        ox0, oy0, ox1, oy1 = op.bounds
        top_holes.append((ox0 - xmin, oy0 - ymin, ox1 - xmin, oy1 - ymin))
        bottom_holes.append((ox0 - xmin, ymax - oy1, ox1 - xmin, ymax - oy0))
        t, up = slab.thickness, (0.0, 0.0, 1.0)
        strips.append([  # walls facing into the opening, continuous around it
            Face((ox1, oy0, z0), (-1.0, 0.0, 0.0), up, (ox1 - ox0, t)),
            Face((ox0, oy0, z0), (0.0, 1.0, 0.0), up, (oy1 - oy0, t)),
            Face((ox0, oy1, z0), (1.0, 0.0, 0.0), up, (ox1 - ox0, t)),
            Face((ox1, oy1, z0), (0.0, -1.0, 0.0), up, (oy1 - oy0, t)),
        ])
    top = Face((xmin, ymin, z1), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (xmax - xmin, ymax - ymin),
               tuple(top_holes))
    bottom = Face((xmin, ymax, z0), (1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (xmax - xmin, ymax - ymin),
                  tuple(bottom_holes))
    approx_side = 2.0 * max(xmax - xmin, ymax - ymin)
    size = _texture_px(approx_side, texel_size, max_texture)
    gutter = _GUTTER_TEXELS * approx_side / size
    # The edge faces go in separately: as one strip the 40 m perimeter would set the atlas width.
    mesh, extent = build_mesh([[top], [bottom], *[[f] for f in sides], *strips], gutter=gutter)
    return SiteElement(f"slab {slab.name}", "slab", mesh, concrete_texture(rng, size, extent))


def _element_triangles(element: Element) -> NDArray[np.float64]:
    """(F, 3, 3) triangles of an element: its own mesh, or its prism triangulated."""
    if element.mesh is not None:
        return element.mesh.vertices[element.mesh.faces]
    import shapely

    holes = [h.outline for h in getattr(element, "holes", ())]
    polygon = shapely.Polygon(element.outline, holes)
    caps = shapely.get_parts(shapely.constrained_delaunay_triangles(polygon))
    tri2d = np.array([np.asarray(t.exterior.coords)[:3] for t in caps])  # (T, 3, 2)
    ccw = ((tri2d[:, 1, 0] - tri2d[:, 0, 0]) * (tri2d[:, 2, 1] - tri2d[:, 0, 1])
           - (tri2d[:, 1, 1] - tri2d[:, 0, 1]) * (tri2d[:, 2, 0] - tri2d[:, 0, 0])) > 0
    tri2d[~ccw] = tri2d[~ccw][:, ::-1]
    z0, z1 = element.z_bottom, element.z_top
    top = np.concatenate([tri2d, np.full((*tri2d.shape[:2], 1), z1)], axis=2)
    bottom = np.concatenate([tri2d[:, ::-1], np.full((*tri2d.shape[:2], 1), z0)], axis=2)
    walls = []
    for ring in [element.outline, *[h[::-1] for h in holes]]:
        a, b = ring, np.roll(ring, -1, axis=0)
        lo_a, lo_b = np.column_stack([a, np.full(len(a), z0)]), np.column_stack([b, np.full(len(b), z0)])
        hi_a, hi_b = np.column_stack([a, np.full(len(a), z1)]), np.column_stack([b, np.full(len(b), z1)])
        walls += [np.stack([lo_a, lo_b, hi_b], axis=1), np.stack([lo_a, hi_b, hi_a], axis=1)]
    return np.concatenate([top, bottom, *walls])


def solid_element(
    element: Element, rng: np.random.Generator, *, texel_size: float = 0.015, max_texture: int = 1024
) -> SiteElement:
    """Any element as textured triangles: each triangle projected onto the axis plane it faces.

    The texture covers a square of the element's largest extent, so the concrete grain has the
    same scale on every face; vertices are not shared (flat normals per triangle).
    """
    tri = _element_triangles(element)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1)
    tri, n = tri[length > 1e-12], n[length > 1e-12] / length[length > 1e-12, None]
    dominant = np.argmax(np.abs(n), axis=1)
    planes = np.array([[1, 2], [0, 2], [0, 1]])[dominant]  # x-facing -> (y, z), ...
    lo = tri.reshape(-1, 3).min(axis=0)
    extent = float(np.max(tri.reshape(-1, 3).max(axis=0) - lo))
    rel = (tri - lo) / extent  # (F, 3, 3) in [0, 1]
    uv = np.take_along_axis(rel, planes[:, None, :].repeat(3, axis=1), axis=2)
    size = _texture_px(extent, texel_size, max_texture)
    mesh = trimesh.Trimesh(
        vertices=tri.reshape(-1, 3),
        faces=np.arange(3 * len(tri)).reshape(-1, 3),
        vertex_normals=np.repeat(n, 3, axis=0),
        visual=trimesh.visual.TextureVisuals(uv=uv.reshape(-1, 2)),
        process=False,
    )
    return SiteElement(f"{element.kind} {element.name}", element.kind, mesh,
                       concrete_texture(rng, size, extent))


def element_mesh(
    element: Element, rng: np.random.Generator, *, texel_size: float = 0.015, max_texture: int = 512
) -> SiteElement:
    """The renderable mesh of one built element: exact boxes where it is one, else triangles."""
    if isinstance(element, Column) and element.is_box:
        return column_element(element, rng, texel_size=texel_size, max_texture=max_texture)
    if isinstance(element, Slab) and element.is_box and all(
        is_axis_aligned_rectangle(h.outline) for h in element.holes
    ):
        return slab_element(element, rng, texel_size=texel_size, max_texture=2 * max_texture)
    return solid_element(element, rng, texel_size=texel_size, max_texture=2 * max_texture)


def _axis_aligned(marker: ArucoMarker) -> bool:
    q = (marker.yaw / (math.pi / 2)) % 1.0
    return min(q, 1.0 - q) < 1e-9


def _marker_holes(site: Site, x0: float, y0: float, size: float) -> tuple[tuple[float, ...], ...]:
    """Footprints of the axis-aligned ground markers lying inside the square ``x0, y0, size``.

    The ground is cut out under each marker sheet, so the sheet (1 cm above the ground) never
    competes with it in the depth buffer, however far away it is seen.
    """
    holes = []
    for m in site.markers:
        x, y, z = m.center
        h = m.footprint_half_extent
        if not (_axis_aligned(m) and 0.0 < z <= 0.05):
            continue
        a0, b0, a1, b1 = x - h - x0, y - h - y0, x + h - x0, y + h - y0
        if a0 > 0 and b0 > 0 and a1 < size and b1 < size:
            holes.append((a0, b0, a1, b1))
    return tuple(holes)


def _ground_warp(d: NDArray[np.float64], core: float, k: float) -> NDArray[np.float64]:
    """Texture coordinate (texture metres) of a ground offset ``d`` (m) from the site centre.

    Identity within ``core`` metres, logarithmic beyond (``core + k log(1 + (|d| - core) / k)``):
    full detail where cameras look, ever coarser towards the horizon, one texture and no seam.
    """
    a = np.abs(d)
    return np.sign(d) * np.where(a <= core, a, core + k * np.log1p(np.maximum(a - core, 0.0) / k))


def ground_elements(
    site: Site,
    rng: np.random.Generator,
    *,
    core: float = 20.0,
    falloff: float = 10.0,
    texture_size: int = 1024,
) -> list[SiteElement]:
    """The ground at z = 0: a square of ``site.ground_size`` centred on the building footprint.

    One mesh and one texture, mapped at full scale within ``core`` metres of the building centre
    and logarithmically compressed beyond (:func:`_ground_warp`), so the texture's detail sits
    where the cameras look and there is no seam (a seam would be a false straight edge for a
    corner detector). The ground is cut out under axis-aligned marker sheets.
    """
    xmin, ymin, xmax, ymax = site.footprint_bounds
    cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
    half = site.ground_size / 2
    core = min(max(core, 0.6 * max(xmax - xmin, ymax - ymin) + 6.0), half)
    s_half = float(_ground_warp(np.array(half), core, falloff))
    # Breaks: the core edges, then uniform 2-texture-metre steps in the warped coordinate.
    s_steps = np.arange(float(_ground_warp(np.array(core), core, falloff)), s_half, 2.0)[1:]
    outer = core + falloff * np.expm1((s_steps - core) / falloff)
    breaks = np.unique(np.concatenate([[-half, -core, core, half], outer, -outer]))
    x0, y0 = cx - half, cy - half
    holes = _marker_holes(site, x0, y0, 2 * half)
    a_breaks = np.unique(np.concatenate([breaks + half, [h[i] for h in holes for i in (0, 2)]]))
    b_breaks = np.unique(np.concatenate([breaks + half, [h[i] for h in holes for i in (1, 3)]]))
    verts, uvs = [], []
    for a0, a1 in zip(a_breaks[:-1], a_breaks[1:], strict=False):
        for b0, b1 in zip(b_breaks[:-1], b_breaks[1:], strict=False):
            am, bm = (a0 + a1) / 2, (b0 + b1) / 2
            if any(h[0] < am < h[2] and h[1] < bm < h[3] for h in holes):
                continue
            q = np.array([[a0, b0], [a1, b0], [a1, b1], [a0, b1]])
            verts.append(np.column_stack([q[:, 0] + x0, q[:, 1] + y0, np.zeros(4)]))
            uvs.append((_ground_warp(q - half, core, falloff) + s_half) / (2 * s_half))
    v = np.concatenate(verts)
    base = 4 * np.arange(len(v) // 4)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    mesh = trimesh.Trimesh(
        vertices=v, faces=faces, vertex_normals=np.tile([0.0, 0.0, 1.0], (len(v), 1)),
        visual=trimesh.visual.TextureVisuals(uv=np.concatenate(uvs)), process=False,
    )
    texture = ground_texture(rng, texture_size, 2 * s_half)
    return [SiteElement("ground", "ground", mesh, texture)]


def marker_element(marker: ArucoMarker, *, module_px: int = 16) -> SiteElement:
    """A marker sheet: a thin box from the ground up to the marker's plane, pattern on top.

    The top face carries the pattern and quiet zone over its whole texture; the texture's
    top-left pixel is at the sheet corner ``(-h, +h)`` of the marker frame, so the printed
    top-left marker corner is ``marker.corners_world[0]`` (OpenCV order). The four edge faces
    (only where the marker lies above z = 0) sample the quiet zone's white corner texel.
    """
    texture = aruco_texture(marker, module_px)
    h = marker.footprint_half_extent
    T = marker.world_from_marker
    x_axis, y_axis, centre = T[:3, 0], T[:3, 1], T[:3, 3]
    corners2d = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])  # CCW seen from above
    top = centre + corners2d[:, :1] * x_axis + corners2d[:, 1:] * y_axis
    verts = [top]
    uvs = [(corners2d + h) / (2 * h)]
    normals = [np.repeat([[0.0, 0.0, 1.0]], 4, axis=0)]
    if centre[2] > 0:
        corner_uv = 0.5 / texture.shape[0]
        for k in range(4):
            a, b = top[k], top[(k + 1) % 4]
            low = np.array([0.0, 0.0, centre[2]])
            verts.append(np.array([a - low, b - low, b, a]))
            uvs.append(np.full((4, 2), corner_uv))
            n = np.cross(b - a, [0.0, 0.0, 1.0])
            normals.append(np.repeat([n / np.linalg.norm(n)], 4, axis=0))
    v = np.concatenate(verts)
    base = 4 * np.arange(len(v) // 4)[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    mesh = trimesh.Trimesh(
        vertices=v, faces=faces, vertex_normals=np.concatenate(normals),
        visual=trimesh.visual.TextureVisuals(uv=np.concatenate(uvs)), process=False,
    )
    return SiteElement(f"marker {marker.id}", "marker", mesh, texture)


def site_elements(
    site: Site,
    rng: np.random.Generator,
    *,
    texel_size: float = 0.015,
    texture_size: int = 512,
) -> tuple[SiteElement, ...]:
    """Every renderable element of ``site`` at its stage, with its own texture.

    Args:
        site: the site.
        rng: generator; element ``k`` draws from ``rng.spawn(...)[k]``.
        texel_size: target metres per texel of the concrete textures.
        texture_size: cap on a column texture's side in pixels; the slab and the ground get
            twice this (they are an order of magnitude larger).

    Returns:
        The built elements kind by kind (columns, slabs, beams, walls; each in the site's element
        order), the ground, then markers.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    check_number("texture_size (pixels)", texture_size, 16, integer=True, type_error=ValueError)
    if not (isinstance(texel_size, (int, float)) and texel_size > 0):
        raise ValueError(f"texel_size must be a positive length in metres, got {texel_size!r}")
    built = [e for kind in ELEMENT_KINDS for e in site.built if e.kind == kind]
    rngs = iter(rng.spawn(len(built) + 1))
    elements = [element_mesh(e, next(rngs), texel_size=texel_size, max_texture=texture_size) for e in built]
    elements += ground_elements(site, next(rngs), texture_size=2 * texture_size)
    elements += [marker_element(m) for m in site.markers]
    return tuple(elements)


#: How many sites' elements :func:`shared_site_elements` keeps (least recently used dropped first).
SHARED_SITES = 4

_SHARED: OrderedDict[tuple, tuple[SiteElement, ...]] = OrderedDict()
_SHARED_LOCK = threading.Lock()


def shared_site_elements(
    site: Site,
    rng: np.random.Generator,
    *,
    texel_size: float = 0.015,
    texture_size: int = 512,
) -> tuple[SiteElement, ...]:
    """:func:`site_elements`, built once per process for the same arguments and then shared.

    The same site, the same sizes and a generator in the same state of its seed sequence (the
    textures depend on nothing else: they are drawn from ``rng.spawn`` children) return the same
    element objects, whose textures are read-only; ``rng`` is advanced as :func:`site_elements`
    advances it. The worlds of one site and seed in a process (envs and studies made again with
    the same settings, a test suite's) then build its meshes and textures once; a vector env's
    copies draw their own textures (``texture_seed + k``) and share nothing. A generator whose bit
    generator has no :class:`numpy.random.SeedSequence` is not shared (built every time).
    """
    key = _shared_key(site, rng, texel_size, texture_size)
    if key is None:
        return site_elements(site, rng, texel_size=texel_size, texture_size=texture_size)
    with _SHARED_LOCK:
        elements = _SHARED.get(key)
        if elements is not None:
            _SHARED.move_to_end(key)
    if elements is not None:
        rng.spawn(len(site.built) + 1)  # as site_elements spawns
        return elements
    elements = site_elements(site, rng, texel_size=texel_size, texture_size=texture_size)
    for e in elements:
        e.texture.setflags(write=False)
    with _SHARED_LOCK:
        _SHARED[key] = elements
        while len(_SHARED) > SHARED_SITES:
            _SHARED.popitem(last=False)
    return elements


def _shared_key(site: Site, rng: np.random.Generator, texel_size: float, texture_size: int) -> tuple | None:
    """What :func:`site_elements`' output depends on, or None where it cannot be told (not shared)."""
    seeds = getattr(getattr(rng, "bit_generator", None), "seed_seq", None)
    if (not isinstance(site, Site) or not isinstance(seeds, np.random.SeedSequence)
            or not isinstance(texel_size, (int, float)) or not isinstance(texture_size, int)):
        return None  # site_elements builds (or refuses) it
    return (site, type(rng.bit_generator).__name__, repr(seeds.entropy), seeds.spawn_key,
            seeds.n_children_spawned, seeds.pool_size, float(texel_size), texture_size)


def write_obj(element: SiteElement, directory: str | Path, stem: str) -> Path:
    """Write ``element`` as ``stem.obj`` + ``stem.mtl`` + ``stem.bmp`` in ``directory``.

    The files of :func:`obj_files`. Returns the OBJ path.
    """
    directory = Path(directory)
    for name, data in obj_files(element, stem).items():
        (directory / name).write_bytes(data)
    return directory / f"{stem}.obj"


def obj_files(element: SiteElement, stem: str) -> dict[str, bytes]:
    """``element`` as the bytes of ``stem.bmp``, ``stem.mtl`` and ``stem.obj``, by file name.

    The OBJ has positions, UVs and normals and one material whose ``map_Kd`` is the texture
    image, which both pybullet renderers load.
    """
    import io

    from PIL import Image

    # BMP: both renderers read it (stb_image) and it is written 15x faster than even a
    # store-only PNG; the files live only as long as the world.
    bmp = io.BytesIO()
    Image.fromarray(element.texture).save(bmp, format="BMP")
    mtl = f"newmtl {stem}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd {stem}.bmp\n"
    m = element.mesh
    f = np.repeat(np.asarray(m.faces, dtype=np.int64) + 1, 3, axis=1)  # a/a/a b/b/b c/c/c
    obj = (f"mtllib {stem}.mtl\no {stem}\nusemtl {stem}\n"
           + _rows("v %.6f %.6f %.6f\n", m.vertices) + _rows("vt %.6f %.6f\n", element.uv)
           + _rows("vn %.6f %.6f %.6f\n", m.vertex_normals) + _rows("f %d/%d/%d %d/%d/%d %d/%d/%d\n", f))
    return {f"{stem}.bmp": bmp.getvalue(), f"{stem}.mtl": mtl.encode(), f"{stem}.obj": obj.encode()}


def _rows(row: str, values: NDArray) -> str:
    """``row`` formatted with each row of ``values``.

    One ``%`` for the whole array: an OBJ of a few thousand vertices is written several times
    faster than line by line, to the same bytes.
    """
    values = np.asarray(values)
    return (row * len(values)) % tuple(values.ravel().tolist())
