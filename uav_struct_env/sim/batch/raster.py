"""The compiled rasterizer: triangles and oriented boxes into RGB, depth and body ids, many views per call.

One call renders every view of a batch (:func:`render_views`); each view reads the triangles of
its own scene (a range of the packed triangle arrays), its ground grid (:func:`.scene.ground_grid`)
and the boxes of its scene (a range of the box arrays). Per view:

0. **Ground pass** (after the triangles and boxes of pass 1, over the pixels where the ground is
   nearest or as near: it wins ties, as if drawn first). The ground, a grid of quads at z = 0
   facing up, is drawn per pixel rather than per triangle: each pixel's ray meets z = 0 at a
   point whose ``1/z`` is affine on the image; it is kept when it lies within ``[near, far]``,
   on the grid, not behind what is drawn there and not in a missing cell
   (a hole under a marker sheet; a point on a hole's edge belongs to the quad beside it, as a
   pixel centre on an edge is covered), and its texture coordinate is interpolated linearly in
   x and y within its cell -- what the perspective-correct interpolation over the cell's two
   triangles gives, as the grid's ``u`` depends on x alone and ``v`` on y alone. Seen from
   below (camera at ``z <= 0``) the ground is culled, as its triangles would be.
1. **Visibility pass.** Each triangle is moved to the camera frame (OpenCV: x right, y down,
   z forward), rejected when all three corners lie beyond one side of the view frustum, clipped
   against the near plane (a polygon of at most four corners, each carrying its barycentric
   weights in the original triangle), dropped when it faces away from the camera (its corners
   run clockwise seen from the camera; meshes wind counter-clockwise seen from outside, and
   TinyRenderer culls back faces too: an element whose faces are wound inward is invisible to
   both), and scan-converted: a pixel is covered when its centre,
   at integer ``(u, v)``, lies inside or on the projected triangle (the convention of
   :mod:`localization.geometry` and of both pybullet renderers, ``sim/camera.py``). The depth
   along the optical axis is interpolated perspective-correctly (``1/z`` is affine on the
   image); the nearest surface within ``[near, far]`` wins and the pixel keeps its triangle and
   its perspective-correct barycentric weights.
2. **Shading pass.** Each covered pixel is shaded once: texture (nearest texel, OBJ convention:
   ``v`` up, texture row 0 at ``v = 1``) or the box's colour, times
   ``ambient + diffuse * max(0, n . l)`` (TinyRenderer's lighting model with pybullet's
   ``lightAmbientCoeff`` / ``lightDiffuseCoeff``; the specular term is 0 in the project), clamped
   to 255. Uncovered pixels get the sky colour, depth ``far`` and body id -1.

Deferred shading touches each pixel's texture once, whatever the overdraw.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["BOX_TRIANGLES", "GROUND_ID", "render_views"]

#: The value of the per-pixel triangle index where the ground (drawn per pixel) is nearest.
GROUND_ID = -2

#: The 12 triangles of the unit box ``[-1, 1]^3`` (corner signs), outward winding, two per face.
BOX_TRIANGLES = np.array([
    [[-1, -1, -1], [1, -1, -1], [1, -1, 1]], [[-1, -1, -1], [1, -1, 1], [-1, -1, 1]],  # -y
    [[1, -1, -1], [1, 1, -1], [1, 1, 1]], [[1, -1, -1], [1, 1, 1], [1, -1, 1]],  # +x
    [[1, 1, -1], [-1, 1, -1], [-1, 1, 1]], [[1, 1, -1], [-1, 1, 1], [1, 1, 1]],  # +y
    [[-1, 1, -1], [-1, -1, -1], [-1, -1, 1]], [[-1, 1, -1], [-1, -1, 1], [-1, 1, 1]],  # -x
    [[-1, -1, 1], [1, -1, 1], [1, 1, 1]], [[-1, -1, 1], [1, 1, 1], [-1, 1, 1]],  # +z
    [[-1, 1, -1], [1, 1, -1], [1, -1, -1]], [[-1, 1, -1], [1, -1, -1], [-1, -1, -1]],  # -z
], dtype=np.float64)
#: The outward normal of each of :data:`BOX_TRIANGLES`.
BOX_NORMALS = np.repeat(
    np.array([[0, -1, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]], np.float64), 2, axis=0
)


#: Barycentric weights of a triangle's own corners (the unclipped case).
_CORNERS = np.eye(3)


@njit(cache=True, nogil=True)
def _clip_near(cam: NDArray, near: float, poly: NDArray, weights: NDArray) -> int:
    """Clip the camera-frame triangle ``cam`` (3, 3) to ``z >= near``; corners into ``poly``.

    ``weights`` (4, 3) receives each corner's barycentric weights in the original triangle.
    Returns the corner count (0, 3 or 4).
    """
    n = 0
    for k in range(3):
        a, b = k, (k + 1) % 3
        za, zb = cam[a, 2], cam[b, 2]
        if za >= near:
            for c in range(3):
                poly[n, c] = cam[a, c]
                weights[n, c] = 1.0 if c == a else 0.0
            n += 1
        if (za >= near) != (zb >= near):
            s = (near - za) / (zb - za)
            for c in range(3):
                poly[n, c] = cam[a, c] + s * (cam[b, c] - cam[a, c])
                weights[n, c] = 0.0
            weights[n, a] = 1.0 - s
            weights[n, b] = s
            n += 1
    return n


@njit(cache=True, nogil=True)
def _span(a: float, inv_a: float, c: float, d: float, v: float, lo: float, hi: float) -> tuple[float, float]:
    """Narrow ``[lo, hi]`` to the ``u`` where ``a u + c v + d >= 0`` on row ``v`` (``inv_a = 1/a``)."""
    e = c * v + d
    if a > 0.0:
        lo = max(lo, -e * inv_a)
    elif a < 0.0:
        hi = min(hi, -e * inv_a)
    elif e < 0.0:
        hi = -1.0
    return lo, hi


@njit(cache=True, nogil=True)
def _scan(
    p: NDArray, w: NDArray, i0: int, i1: int, i2: int, tri: int, intr: NDArray, far: float,
    izbuf: NDArray, ids: NDArray, bary: NDArray,
) -> None:
    """Scan-convert the sub-triangle ``p[i0], p[i1], p[i2]`` (camera frame, all ``z >= near``).

    The screen barycentrics ``b_k = a_k u + c_k v + d_k`` and ``1/z`` are affine on the image;
    each row is scanned over the span where all three ``b_k >= 0`` only. ``izbuf`` holds ``1/z``
    (0: nothing drawn).
    """
    fx, sk, cx, fy, cy = intr[0], intr[1], intr[2], intr[3], intr[4]
    H, W = izbuf.shape
    iz0, iz1, iz2 = 1.0 / p[i0, 2], 1.0 / p[i1, 2], 1.0 / p[i2, 2]
    u0 = (fx * p[i0, 0] + sk * p[i0, 1]) * iz0 + cx
    v0 = fy * p[i0, 1] * iz0 + cy
    u1 = (fx * p[i1, 0] + sk * p[i1, 1]) * iz1 + cx
    v1 = fy * p[i1, 1] * iz1 + cy
    u2 = (fx * p[i2, 0] + sk * p[i2, 1]) * iz2 + cx
    v2 = fy * p[i2, 1] * iz2 + cy
    area = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    if not area < 0.0:  # back-facing (clockwise on the image, v down), edge-on or not finite
        return
    vmin = max(int(np.ceil(min(v0, v1, v2))), 0)
    vmax = min(int(np.floor(max(v0, v1, v2))), H - 1)
    umin = max(np.ceil(min(u0, u1, u2)), 0.0)
    umax = min(np.floor(max(u0, u1, u2)), W - 1.0)
    if vmin > vmax or umin > umax:
        return
    r = 1.0 / area
    a0, c0, d0 = (v1 - v2) * r, (u2 - u1) * r, (u1 * v2 - u2 * v1) * r
    a1, c1, d1 = (v2 - v0) * r, (u0 - u2) * r, (u2 * v0 - u0 * v2) * r
    a2, c2, d2 = (v0 - v1) * r, (u1 - u0) * r, (u0 * v1 - u1 * v0) * r
    inv_far = 1.0 / far
    r0 = 1.0 / a0 if a0 != 0.0 else 0.0
    r1 = 1.0 / a1 if a1 != 0.0 else 0.0
    r2 = 1.0 / a2 if a2 != 0.0 else 0.0
    for v in range(vmin, vmax + 1):
        lo, hi = _span(a0, r0, c0, d0, v, umin, umax)
        lo, hi = _span(a1, r1, c1, d1, v, lo, hi)
        lo, hi = _span(a2, r2, c2, d2, v, lo, hi)
        if lo > hi:
            continue
        for u in range(int(np.ceil(lo)), int(np.floor(hi)) + 1):
            b0 = a0 * u + c0 * v + d0
            b1 = a1 * u + c1 * v + d1
            b2 = a2 * u + c2 * v + d2
            if b0 < 0.0 or b1 < 0.0 or b2 < 0.0:
                continue
            q0, q1, q2 = b0 * iz0, b1 * iz1, b2 * iz2
            inv_z = q0 + q1 + q2
            if inv_z <= izbuf[v, u] or inv_z < inv_far:
                continue
            izbuf[v, u] = inv_z
            ids[v, u] = tri
            # weights of the original triangle's corners 1 and 2 (corner 0: the rest)
            z = 1.0 / inv_z
            bary[v, u, 0] = (q0 * w[i0, 1] + q1 * w[i1, 1] + q2 * w[i2, 1]) * z
            bary[v, u, 1] = (q0 * w[i0, 2] + q1 * w[i1, 2] + q2 * w[i2, 2]) * z


@njit(cache=True, nogil=True)
def _culled(cam: NDArray, intr: NDArray, near: float, W: int, H: int) -> bool:
    """True when the camera-frame triangle ``cam`` is beyond a frustum plane or faces away."""
    z0, z1, z2 = cam[0, 2], cam[1, 2], cam[2, 2]
    if z0 < near and z1 < near and z2 < near:
        return True
    if z0 > 0.0 and z1 > 0.0 and z2 > 0.0:
        # det[c0, c1, c2] = z0 z1 z2 x (twice the signed image area): back-facing when >= 0
        det = (cam[0, 0] * (cam[1, 1] * z2 - z1 * cam[2, 1]) - cam[0, 1] * (cam[1, 0] * z2 - z1 * cam[2, 0])
               + z0 * (cam[1, 0] * cam[2, 1] - cam[1, 1] * cam[2, 0]))
        if not det < 0.0:
            return True
    fx, sk, cx, fy, cy = intr[0], intr[1], intr[2], intr[3], intr[4]
    # y / z limits, then x / z limits (skew folded into x)
    lo_y, hi_y = (-0.5 - cy) / fy, (H - 0.5 - cy) / fy
    left = right = top = bottom = True
    for k in range(3):
        x, y, z = cam[k, 0], cam[k, 1], cam[k, 2]
        top &= y < lo_y * z
        bottom &= y > hi_y * z
        xs = fx * x + sk * y  # u - cx, times z
        left &= xs < (-0.5 - cx) * z
        right &= xs > (W - 0.5 - cx) * z
    return left or right or top or bottom


@njit(cache=True, nogil=True)
def _draw(
    cam: NDArray, tri: int, intr: NDArray, near: float, far: float, poly: NDArray, weights: NDArray,
    izbuf: NDArray, ids: NDArray, bary: NDArray,
) -> None:
    """Clip and scan-convert one camera-frame triangle ``cam`` (3, 3) as ``tri``.

    Cull first (:func:`_culled`): a call with a dozen array arguments costs more than the test.
    """
    if cam[0, 2] >= near and cam[1, 2] >= near and cam[2, 2] >= near:
        _scan(cam, _CORNERS, 0, 1, 2, tri, intr, far, izbuf, ids, bary)
        return
    n = _clip_near(cam, near, poly, weights)
    for k in range(1, n - 1):
        _scan(poly, weights, 0, k, k + 1, tri, intr, far, izbuf, ids, bary)


@njit(cache=True, nogil=True)
def _walk(breaks: NDArray, lo: int, hi: int, x: float, i: int) -> int:
    """The cell ``i`` (``breaks[lo + i] <= x <= breaks[lo + i + 1]``) from the guess ``i``.

    ``x`` lies within the breaks; along an image row the ground point moves monotonically, so
    the walk from the last pixel's cell is a step or none.
    """
    while i > 0 and x < breaks[lo + i]:
        i -= 1
    while lo + i + 2 < hi and x > breaks[lo + i + 1]:
        i += 1
    return i


@njit(cache=True, nogil=True)
def _cell_beside(gx: NDArray, gy: NDArray, g: NDArray, cells: NDArray, x: float, y: float, i: int,
                 j: int) -> tuple[int, int]:
    """An existing cell containing ``(x, y)`` among ``(i, j)`` and its neighbours; ``(-1, -1)``: none."""
    nx, ny = g[1] - g[0] - 1, g[3] - g[2] - 1
    for ii in range(max(i - 1, 0), min(i + 2, nx)):
        for jj in range(max(j - 1, 0), min(j + 2, ny)):
            if (cells[g[4] + ii * ny + jj] and gx[g[0] + ii] <= x <= gx[g[0] + ii + 1]
                    and gy[g[2] + jj] <= y <= gy[g[2] + jj + 1]):
                return ii, jj
    return -1, -1


@njit(cache=True, nogil=True)
def _draw_ground(
    R: NDArray, t: NDArray, intr: NDArray, near: float, far: float, g: NDArray, gx: NDArray, gu: NDArray,
    gy: NDArray, gv: NDArray, cells: NDArray, izbuf: NDArray, ids: NDArray, bary: NDArray,
) -> None:
    """Draw the ground grid ``g`` (a row of ``scene_ground``) per pixel (module docstring, pass 0).

    Drawn after the triangles: a pixel they hold nearer keeps them, so the ground's cell and
    texture coordinate are worked out only where it shows.

    Pixels it covers get :data:`GROUND_ID` and its texture coordinate ``(u, v)`` in ``bary``.
    """
    H, W = izbuf.shape
    fx, sk, cx, fy, cy = intr[0], intr[1], intr[2], intr[3], intr[4]
    # camera centre in the world, -R^T t
    ox = -(R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2])
    oy = -(R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2])
    oz = -(R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2])
    if not oz > 0.0:
        return
    x_lo, x_hi, y_lo, y_hi = gx[g[0]], gx[g[1] - 1], gy[g[2]], gy[g[3] - 1]
    inv_far, inv_near, inv_oz = 1.0 / far, 1.0 / near, 1.0 / oz
    ny = g[3] - g[2] - 1
    i = j = 0
    for v in range(H):
        # the ray through (u, v), world frame: R^T (x/z, y/z, 1) with x/z = u / fx + e
        dy = (v - cy) / fy
        e = -(cx + sk * dy) / fx
        bx, by, bz = (e * R[0, 0] + dy * R[1, 0] + R[2, 0], e * R[0, 1] + dy * R[1, 1] + R[2, 1],
                      e * R[0, 2] + dy * R[1, 2] + R[2, 2])
        sx, sy, sz = R[0, 0] / fx, R[0, 1] / fx, R[0, 2] / fx
        for u in range(W):
            inv_z = -(bz + u * sz) * inv_oz
            # beyond the far plane, nearer than near, looking up, or behind what is drawn (ties: ours)
            if inv_z < inv_far or inv_z > inv_near or inv_z < izbuf[v, u]:
                continue
            z = 1.0 / inv_z
            x = ox + (bx + u * sx) * z
            y = oy + (by + u * sy) * z
            if x < x_lo or x > x_hi or y < y_lo or y > y_hi:
                continue
            i = _walk(gx, g[0], g[1], x, i)
            j = _walk(gy, g[2], g[3], y, j)
            if not cells[g[4] + i * ny + j]:
                i, j = _cell_beside(gx, gy, g, cells, x, y, i, j)
                if i < 0:
                    i = j = 0
                    continue
            izbuf[v, u] = inv_z
            ids[v, u] = GROUND_ID
            a, b = g[0] + i, g[2] + j
            bary[v, u, 0] = gu[a, 0] + (x - gx[a]) * gu[a, 1]
            bary[v, u, 1] = gv[b, 0] + (y - gy[b]) * gv[b, 1]


@njit(cache=True, nogil=True)
def _draw_triangles(
    R: NDArray, t: NDArray, intr: NDArray, near: float, far: float, hide: int,
    tri_v: NDArray, tri_seg: NDArray, t_lo: int, t_hi: int, izbuf: NDArray, ids: NDArray, bary: NDArray,
) -> None:
    """Draw the static triangles ``t_lo`` to ``t_hi`` (those of body ``hide`` excepted)."""
    H, W = izbuf.shape
    cam = np.empty((3, 3))
    poly = np.empty((4, 3))
    weights = np.empty((4, 3))
    for i in range(t_lo, t_hi):
        if tri_seg[i] == hide:
            continue
        for k in range(3):
            for r in range(3):
                cam[k, r] = (R[r, 0] * tri_v[i, k, 0] + R[r, 1] * tri_v[i, k, 1] + R[r, 2] * tri_v[i, k, 2]
                             + t[r])
        if not _culled(cam, intr, near, W, H):
            _draw(cam, i, intr, near, far, poly, weights, izbuf, ids, bary)


@njit(cache=True, nogil=True)
def _draw_boxes(
    R: NDArray, t: NDArray, intr: NDArray, near: float, far: float, hide: int, first_id: int,
    box_R: NDArray, box_c: NDArray, box_h: NDArray, box_seg: NDArray, b_lo: int, b_hi: int,
    izbuf: NDArray, ids: NDArray, bary: NDArray,
) -> None:
    """Draw the boxes ``b_lo`` to ``b_hi`` (body ``hide`` excepted); ids ``first_id + 12 b + k``."""
    H, W = izbuf.shape
    cam = np.empty((3, 3))
    poly = np.empty((4, 3))
    weights = np.empty((4, 3))
    world = np.empty(3)
    for b in range(b_lo, b_hi):
        if box_seg[b] == hide:
            continue
        # skip a box wholly behind the near plane (its bounding sphere)
        zc = (R[2, 0] * box_c[b, 0] + R[2, 1] * box_c[b, 1] + R[2, 2] * box_c[b, 2] + t[2])
        radius = np.sqrt(box_h[b, 0] ** 2 + box_h[b, 1] ** 2 + box_h[b, 2] ** 2)
        if zc + radius < near:
            continue
        for j in range(12):
            for k in range(3):
                for a in range(3):
                    world[a] = box_c[b, a]
                    for c in range(3):
                        world[a] += box_R[b, a, c] * BOX_TRIANGLES[j, k, c] * box_h[b, c]
                for r in range(3):
                    cam[k, r] = R[r, 0] * world[0] + R[r, 1] * world[1] + R[r, 2] * world[2] + t[r]
            if not _culled(cam, intr, near, W, H):
                _draw(cam, first_id + 12 * b + j, intr, near, far, poly, weights, izbuf, ids, bary)


@njit(cache=True, nogil=True)
def _shade_pass(
    ids: NDArray, bary: NDArray, izbuf: NDArray, light: NDArray, sky: NDArray, far: float,
    tri_uv: NDArray, tri_n: NDArray, tri_tex: NDArray, tri_seg: NDArray,
    tex_data: NDArray, tex_off: NDArray, tex_w: NDArray, tex_h: NDArray, ground_tex: int, ground_seg: int,
    box_R: NDArray, box_rgb: NDArray, box_seg: NDArray,
    rgb: NDArray, depth: NDArray, seg: NDArray,
) -> None:
    """Shade one view's covered pixels and fill its depth and body ids (module docstring)."""
    H, W = ids.shape
    n_static = tri_uv.shape[0]
    lx, ly, lz, amb, dif = light[0], light[1], light[2], light[3], light[4]
    for v in range(H):
        for u in range(W):
            i = ids[v, u]
            if i == -1:
                rgb[v, u, 0], rgb[v, u, 1], rgb[v, u, 2] = sky[0], sky[1], sky[2]
                depth[v, u] = far
                seg[v, u] = -1
                continue
            depth[v, u] = 1.0 / izbuf[v, u]
            if i < n_static:
                if i == GROUND_ID:
                    seg[v, u] = ground_seg
                    ndotl = lz  # the ground's normal is +z
                    tu, tv = bary[v, u, 0], bary[v, u, 1]
                    x = ground_tex
                else:
                    seg[v, u] = tri_seg[i]
                    ndotl = tri_n[i, 0] * lx + tri_n[i, 1] * ly + tri_n[i, 2] * lz
                    b1, b2 = bary[v, u, 0], bary[v, u, 1]
                    b0 = 1.0 - b1 - b2
                    tu = b0 * tri_uv[i, 0, 0] + b1 * tri_uv[i, 1, 0] + b2 * tri_uv[i, 2, 0]
                    tv = b0 * tri_uv[i, 0, 1] + b1 * tri_uv[i, 1, 1] + b2 * tri_uv[i, 2, 1]
                    x = tri_tex[i]
                col = min(max(int(tu * tex_w[x]), 0), tex_w[x] - 1)
                row = min(max(int((1.0 - tv) * tex_h[x]), 0), tex_h[x] - 1)
                base = tex_off[x] + row * tex_w[x] + col
                c0, c1, c2 = tex_data[base, 0], tex_data[base, 1], tex_data[base, 2]
            else:
                b = (i - n_static) // 12
                j = (i - n_static) % 12
                seg[v, u] = box_seg[b]
                ndotl = 0.0
                for a in range(3):
                    n_world = (box_R[b, a, 0] * BOX_NORMALS[j, 0] + box_R[b, a, 1] * BOX_NORMALS[j, 1]
                               + box_R[b, a, 2] * BOX_NORMALS[j, 2])
                    ndotl += n_world * (lx if a == 0 else ly if a == 1 else lz)
                c0, c1, c2 = box_rgb[b, 0], box_rgb[b, 1], box_rgb[b, 2]
            gain = amb + dif * max(ndotl, 0.0)
            rgb[v, u, 0] = min(int(gain * c0), 255)
            rgb[v, u, 1] = min(int(gain * c1), 255)
            rgb[v, u, 2] = min(int(gain * c2), 255)


@njit(cache=True, nogil=True)
def render_views(
    view_scene: NDArray, view_R: NDArray, view_t: NDArray, view_intr: NDArray, view_clip: NDArray,
    view_light: NDArray, view_hide: NDArray, sky: NDArray,
    scene_tris: NDArray, scene_boxes: NDArray,
    tri_v: NDArray, tri_uv: NDArray, tri_n: NDArray, tri_tex: NDArray, tri_seg: NDArray,
    tex_data: NDArray, tex_off: NDArray, tex_w: NDArray, tex_h: NDArray, scene_ground: NDArray,
    ground_x: NDArray, ground_u: NDArray, ground_y: NDArray, ground_v: NDArray, ground_cells: NDArray,
    box_R: NDArray, box_c: NDArray, box_h: NDArray, box_rgb: NDArray, box_seg: NDArray,
    rgb: NDArray, depth: NDArray, seg: NDArray,
) -> None:
    """Render every view of a batch into ``rgb`` (V, H, W, 3), ``depth`` (V, H, W), ``seg`` (V, H, W).

    Per view ``k``: its scene ``view_scene[k]`` (whose triangles are ``scene_tris[s, 0]`` to
    ``scene_tris[s, 1]``, ground grid ``scene_ground[s]`` (``scene.PackedScenes``) and boxes
    ``scene_boxes[s, 0]`` to ``scene_boxes[s, 1]``),
    ``cam_from_world`` as ``view_R[k]`` (3, 3) and ``view_t[k]`` (3,), intrinsics
    ``view_intr[k]`` = (fx, skew, cx, fy, cy), clip planes ``view_clip[k]`` = (near, far),
    light ``view_light[k]`` = (unit direction towards the sun (3,), ambient, diffuse) and a body
    id not drawn, ``view_hide[k]`` (-1: none).
    """
    V, H, W = seg.shape
    izbuf = np.empty((H, W))
    ids = np.empty((H, W), dtype=np.int64)
    bary = np.empty((H, W, 2))
    for k in range(V):
        s = view_scene[k]
        near, far = view_clip[k, 0], view_clip[k, 1]
        izbuf[:] = 0.0
        ids[:] = -1
        R, t, intr, hide = view_R[k], view_t[k], view_intr[k], view_hide[k]
        _draw_triangles(R, t, intr, near, far, hide, tri_v, tri_seg, scene_tris[s, 0], scene_tris[s, 1],
                        izbuf, ids, bary)
        _draw_boxes(R, t, intr, near, far, hide, tri_v.shape[0], box_R, box_c, box_h, box_seg,
                    scene_boxes[s, 0], scene_boxes[s, 1], izbuf, ids, bary)
        g = scene_ground[s]
        if g[5] >= 0 and g[6] != hide:
            _draw_ground(R, t, intr, near, far, g, ground_x, ground_u, ground_y, ground_v, ground_cells,
                         izbuf, ids, bary)
        _shade_pass(ids, bary, izbuf, view_light[k], sky, far, tri_uv, tri_n, tri_tex, tri_seg,
                    tex_data, tex_off, tex_w, tex_h, g[5], g[6], box_R, box_rgb, box_seg,
                    rgb[k], depth[k], seg[k])
