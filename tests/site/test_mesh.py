"""Site meshes: one textured element per column, slab, ground and marker; UVs, normals, areas."""

from __future__ import annotations

import numpy as np
import pytest

from uav_struct_env.site import mesh as mesh_module
from uav_struct_env.site import paper_site, random_site
from uav_struct_env.site.mesh import (
    Face,
    box_faces,
    build_mesh,
    marker_element,
    shared_site_elements,
    site_elements,
    write_obj,
)


@pytest.fixture(scope="module")
def elements():
    return site_elements(paper_site("columns"), np.random.default_rng(1))


def _by_kind(elements, kind):
    return [e for e in elements if e.kind == kind]


def test_one_element_per_column_slab_ground_and_marker(elements):
    site = paper_site("columns")
    assert len(_by_kind(elements, "column")) == len(site.columns) == 24
    assert len(_by_kind(elements, "slab")) == 1
    assert len(_by_kind(elements, "ground")) == 1
    assert len(_by_kind(elements, "marker")) == 8
    assert len({e.name for e in elements}) == len(elements)
    slab_stage = site_elements(paper_site("slab", marker_size=None), np.random.default_rng(1))
    assert len(_by_kind(slab_stage, "column")) == 12 and not _by_kind(slab_stage, "marker")


def test_uvs_and_texture_shapes(elements):
    for e in elements:
        uv = e.uv
        assert uv.shape == (len(e.mesh.vertices), 2)
        assert uv.min() >= 0.0 and uv.max() <= 1.0, e.name
        assert e.texture.dtype == np.uint8 and e.texture.ndim == 3 and e.texture.shape[2] == 3


def test_column_box_geometry_and_outward_normals(elements):
    site = paper_site("columns")
    for column, e in zip(site.columns, _by_kind(elements, "column"), strict=False):
        sx, sy = column.section
        h = column.z_top - column.z_bottom
        assert e.mesh.area == pytest.approx(2 * (sx + sy) * h + 2 * sx * sy)
        lo, hi = e.mesh.bounds
        np.testing.assert_allclose(lo, [column.x - sx / 2, column.y - sy / 2, column.z_bottom])
        np.testing.assert_allclose(hi, [column.x + sx / 2, column.y + sy / 2, column.z_top])
        centre = e.mesh.vertices.mean(axis=0)
        tri_centres = e.mesh.triangles_center
        assert np.all(np.einsum("ij,ij->i", e.mesh.face_normals, tri_centres - centre) > 0)
        # Stored vertex normals agree with the winding.
        vn = e.mesh.vertex_normals[e.mesh.faces[:, 0]]
        np.testing.assert_allclose(vn, e.mesh.face_normals, atol=1e-9)


def test_slab_has_its_opening_cut_out(elements):
    site = paper_site("columns")
    slab = site.slabs[0]
    (e,) = _by_kind(elements, "slab")
    xmin, ymin, xmax, ymax = slab.bounds
    op = slab.openings[0]
    ox, oy = op.size
    t = slab.thickness
    plan = (xmax - xmin) * (ymax - ymin) - ox * oy
    expected = 2 * plan + 2 * (xmax - xmin + ymax - ymin) * t + 2 * (ox + oy) * t
    assert e.mesh.area == pytest.approx(expected)
    # No triangle of the top face covers the opening centre.
    top = np.isclose(e.mesh.triangles[:, :, 2], slab.z_top).all(axis=1)
    cx, cy = op.center
    for tri in e.mesh.triangles[top]:
        x0, y0 = tri[:, :2].min(axis=0)
        x1, y1 = tri[:, :2].max(axis=0)
        assert not (x0 < cx < x1 and y0 < cy < y1)
    # The opening walls face into the opening.
    walls = ~np.isclose(np.abs(e.mesh.face_normals[:, 2]), 1.0)
    inner = walls & (np.abs(e.mesh.triangles_center[:, 0] - cx) < ox / 2 + 1e-9) & (
        np.abs(e.mesh.triangles_center[:, 1] - cy) < oy / 2 + 1e-9)
    assert inner.sum() == 8
    to_centre = np.array([cx, cy, 0.0]) - e.mesh.triangles_center[inner] * [1, 1, 0]
    assert np.all(np.einsum("ij,ij->i", e.mesh.face_normals[inner], to_centre) > 0)


def test_ground_is_cut_under_markers_and_covers_the_site(elements):
    site = paper_site("columns")
    (ground,) = _by_kind(elements, "ground")
    sheets = sum((2 * m.footprint_half_extent) ** 2 for m in site.markers)
    assert ground.mesh.area == pytest.approx(site.ground_size**2 - sheets)
    assert np.allclose(ground.mesh.vertices[:, 2], 0.0)
    assert np.all(ground.mesh.face_normals[:, 2] > 0.99)


def test_marker_sheet_texture_orientation():
    site = paper_site("columns")
    marker = site.markers[3]
    e = marker_element(marker)
    top = np.isclose(e.mesh.vertices[:, 2], marker.center[2]) & np.isclose(
        e.mesh.vertex_normals[:, 2], 1.0)
    h = marker.footprint_half_extent
    cx, cy, _ = marker.center
    for vertex, uv in zip(e.mesh.vertices[top], e.uv[top], strict=False):
        # (-h, +h) in the marker frame, the printed top-left, is texture (u, v) = (0, 1).
        expected = [(vertex[0] - cx + h) / (2 * h), (vertex[1] - cy + h) / (2 * h)]
        np.testing.assert_allclose(uv, expected)
    assert e.mesh.area == pytest.approx((2 * h) ** 2 + 4 * 2 * h * marker.center[2])


def test_textures_are_seeded_and_never_shared(elements):
    again = site_elements(paper_site("columns"), np.random.default_rng(1))
    other = site_elements(paper_site("columns"), np.random.default_rng(2))
    concrete = [e for e in elements if e.kind in ("column", "slab")]
    for a, b, c in zip(elements, again, other, strict=False):
        np.testing.assert_array_equal(a.texture, b.texture)
        if a.kind != "marker":
            assert not np.array_equal(a.texture, c.texture)
    for i, a in enumerate(concrete):
        for b in concrete[i + 1:]:
            if a.texture.shape == b.texture.shape:
                assert np.abs(a.texture.astype(int) - b.texture).mean() > 2.0, (a.name, b.name)


def test_shared_elements_are_built_once_and_equal_to_a_fresh_build(monkeypatch):
    site = paper_site("columns")
    monkeypatch.setattr(mesh_module, "_SHARED", type(mesh_module._SHARED)())
    a_rng, b_rng, fresh_rng = (np.random.default_rng(1) for _ in range(3))
    a = shared_site_elements(site, a_rng, texture_size=16)
    b = shared_site_elements(paper_site("columns"), b_rng, texture_size=16)  # an equal site
    fresh = site_elements(site, fresh_rng, texture_size=16)
    assert a is b and len(a) == len(fresh) == 34
    for x, y in zip(a, fresh, strict=True):
        assert x.name == y.name and not x.texture.flags.writeable
        np.testing.assert_array_equal(x.texture, y.texture)
        np.testing.assert_array_equal(x.mesh.vertices, y.mesh.vertices)
    # Each generator is left as site_elements leaves it: the next draws agree.
    assert a_rng.random() == b_rng.random() == fresh_rng.random()
    # The same generator again is one step further on: other textures, built anew.
    again = shared_site_elements(site, a_rng, texture_size=16)
    assert again is not a and not np.array_equal(again[0].texture, a[0].texture)
    assert shared_site_elements(site, np.random.default_rng(1), texture_size=32) is not a
    assert shared_site_elements(paper_site("slab"), np.random.default_rng(1), texture_size=16) is not a


def test_shared_elements_keep_the_latest_sites_only(monkeypatch):
    monkeypatch.setattr(mesh_module, "_SHARED", type(mesh_module._SHARED)())
    site = paper_site("columns")
    first = shared_site_elements(site, np.random.default_rng(0), texture_size=16)
    for seed in range(1, mesh_module.SHARED_SITES + 1):
        shared_site_elements(site, np.random.default_rng(seed), texture_size=16)
    assert len(mesh_module._SHARED) == mesh_module.SHARED_SITES
    assert shared_site_elements(site, np.random.default_rng(0), texture_size=16) is not first


def test_shared_elements_refuse_what_site_elements_refuses():
    with pytest.raises(TypeError, match="rng must be"):
        shared_site_elements(paper_site(), rng=0)
    with pytest.raises(ValueError, match="texture_size"):
        shared_site_elements(paper_site(), np.random.default_rng(0), texture_size=4)
    with pytest.raises(ValueError, match="texture_size"):
        shared_site_elements(paper_site(), np.random.default_rng(0), texture_size=4.5)


def test_random_sites_build(rng):
    for _ in range(3):
        site = random_site(rng)
        els = site_elements(site, rng, texture_size=64)
        assert len(_by_kind(els, "column")) == len(site.columns)


def test_face_cells_and_packing():
    hole = (1.0, 1.0, 2.0, 2.0)
    face = Face((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (4.0, 3.0), (hole,))
    cells = face.cells()
    assert sum((a1 - a0) * (b1 - b0) for a0, b0, a1, b1 in cells) == pytest.approx(11.0)
    sides, top, bottom = box_faces((0, 0, 0), (1, 2, 5))
    mesh, extent = build_mesh([sides, top, bottom], gutter=0.05)
    assert extent >= 5.0 and mesh.area == pytest.approx(2 * (1 * 2 + 1 * 5 + 2 * 5))
    # Strips do not overlap in the atlas: total UV area equals total 3D area / extent^2.
    uv_tri = mesh.visual.uv[mesh.faces]
    e1, e2 = uv_tri[:, 1] - uv_tri[:, 0], uv_tri[:, 2] - uv_tri[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    assert uv_area == pytest.approx(mesh.area / extent**2)
    with pytest.raises(ValueError, match="lo < hi"):
        box_faces((0, 0, 0), (1, 0, 1))


def test_bad_arguments_raise():
    with pytest.raises(TypeError, match="rng must be"):
        site_elements(paper_site(), rng=0)
    with pytest.raises(ValueError, match="texture_size"):
        site_elements(paper_site(), np.random.default_rng(0), texture_size=4)


def test_write_obj_round_trip(tmp_path, elements):
    import trimesh

    path = write_obj(elements[0], tmp_path, "col")
    assert (tmp_path / "col.bmp").exists()
    assert "map_Kd col.bmp" in (tmp_path / "col.mtl").read_text()
    loaded = trimesh.load(path, process=False, force="mesh")
    assert loaded.area == pytest.approx(elements[0].mesh.area, rel=1e-5)
