"""As-built deviations (site/as_built.py): limits, determinism, ids, and what the env renders."""

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.errors import ConfigError, SiteGeometryError
from uav_struct_env.site import Column, Slab, paper_site, random_site
from uav_struct_env.site.as_built import ACI117, AsBuilt, max_landmark_shift, offset_edges


def _by_guid(site):
    return {e.guid: e for e in site.elements}


@pytest.mark.parametrize("scale", [1.0, 4.0])
def test_every_deviation_is_within_the_scaled_aci117_limits(scale):
    designs = [paper_site()] + [random_site(np.random.default_rng(s)) for s in range(6)]
    column_dev, slab_dev, edge_dev = [], [], []
    for design in designs:
        built = AsBuilt("aci117", scale, seed=3).apply(design)
        moved = _by_guid(built)
        for e in design.elements:
            b = moved[e.guid]
            if isinstance(e, Column):
                d = b.outline - e.outline
                assert np.allclose(d, d[0]), "a column moves as a whole"
                np.testing.assert_allclose(np.subtract(b.axis, e.axis), d[0])
                assert (b.z_bottom, b.z_top) == (e.z_bottom, e.z_top)
                column_dev += list(d[0])
            elif isinstance(e, Slab):
                np.testing.assert_array_equal(b.outline, e.outline)
                assert b.z_top - e.z_top == pytest.approx(b.z_bottom - e.z_bottom)
                slab_dev.append(b.z_top - e.z_top)
                for h0, h1 in zip(e.holes, b.holes, strict=True):
                    # Rectangular openings stay rectangles; each edge moved on its own.
                    edge_dev += list(np.subtract(h1.bounds, h0.bounds))
    for devs, limit in ((column_dev, ACI117.column_lateral_m), (slab_dev, ACI117.slab_elevation_m),
                        (edge_dev, ACI117.opening_edge_m)):
        devs = np.abs(devs) / (limit * scale)
        assert devs.max() <= 1 + 1e-9
        assert devs.mean() > 0.2, "deviations are drawn with the limit as 2 sigma, not near zero"
    # The limit is the 2-sigma value: about 5 % of the lateral deviations sit at it.
    at_limit = np.mean(np.isclose(np.abs(column_dev), ACI117.column_lateral_m * scale))
    assert 0.0 < at_limit < 0.15


def test_scale_zero_is_the_design_and_ids_match_the_design():
    design = paper_site()
    assert AsBuilt(scale=0).apply(design) is design
    built = AsBuilt(scale=4, seed=1).apply(design)
    for name in ("slab_corners", "opening_corners", "column_tops", "aruco", "all"):
        np.testing.assert_array_equal(built.landmarks(name).ids, design.landmarks(name).ids)
    # Every landmark within the largest possible combined deviation of its element(s).
    worst = 4 * np.hypot(np.hypot(ACI117.column_lateral_m, ACI117.column_lateral_m), 0)
    assert 0 < max_landmark_shift(design, built, "column_tops") <= worst + 1e-9
    assert max_landmark_shift(design, built, "aruco") == 0.0
    assert built.source["as_built"] == {
        "tolerances": {"name": "aci117", "column_lateral_m": 0.025, "slab_elevation_m": 0.019,
                       "opening_edge_m": 0.013},
        "scale": 4.0,
        "seed": 1,
    }


def test_an_elements_deviation_depends_on_seed_and_guid_only():
    design = paper_site("columns")
    a, b = AsBuilt(seed=5).apply(design), AsBuilt(seed=5).apply(design.with_stage("slab"))
    np.testing.assert_array_equal(a.landmarks("slab_corners").xyz,
                                  b.with_stage("columns").landmarks("slab_corners").xyz)
    np.testing.assert_array_equal(a.landmarks("column_tops").xyz,
                                  b.with_stage("columns").landmarks("column_tops").xyz)
    other = AsBuilt(seed=6).apply(design)
    assert not np.array_equal(a.landmarks("column_tops").xyz, other.landmarks("column_tops").xyz)


def test_offset_edges_moves_each_edge_along_its_outward_normal():
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    # Edges: bottom (y=0), right (x=2), top (y=1), left (x=0); outward offsets 0.1, 0.2, 0.3, 0.4.
    np.testing.assert_allclose(
        offset_edges(square, [0.1, 0.2, 0.3, 0.4]),
        [[-0.4, -0.1], [2.2, -0.1], [2.2, 1.3], [-0.4, 1.3]],
    )
    # A slanted edge: the right triangle's hypotenuse x + y = 1 moved out by d keeps its slope.
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    d = 0.05
    out = offset_edges(tri, [0.0, d, 0.0])
    np.testing.assert_allclose(out[1:].sum(axis=1), 1 + d * np.sqrt(2))
    np.testing.assert_allclose(out[0], [0, 0])


def test_bad_as_built_settings_are_refused_with_the_value():
    with pytest.raises(SiteGeometryError, match=r"one of \('aci117',\), got 'aci318'"):
        AsBuilt("aci318")
    with pytest.raises(SiteGeometryError, match="as-built scale must be .*got -1"):
        AsBuilt(scale=-1)
    with pytest.raises(SiteGeometryError, match="as-built scale must be .*got nan"):
        AsBuilt(scale=float("nan"))
    with pytest.raises(ConfigError, match="as_built must be None, an AsBuilt or one of"):
        uav_struct_env.parallel_env(as_built=4)


def test_the_env_renders_the_as_built_building_and_reports_it_as_truth():
    """Rendered depth sits on the as-built column tops, not on the design's (moved ~0.5 m)."""
    as_built = AsBuilt(scale=20, seed=0)  # up to 0.5 m: the design top is off a 0.35 m column
    env = uav_struct_env.parallel_env(as_built=as_built, renderer="tiny",
                                      observe_depth=True, marker_size=None)
    try:
        obs, infos = env.reset(seed=0, options={"viewpoint": 0})
        design = env.site.landmarks("column_tops")
        assert env.built_site is not env.site
        on_built, on_design = [], []
        for agent in env.agents:
            truth = infos[agent]["landmarks"]["column_tops"]
            # Moved 0.5 m, some ground-storey columns stick out past the slab edge: their tops
            # are exposed as built (the design has only the 12 upper tops).
            assert set(design.ids.tolist()) < set(truth["ids"].tolist())
            keep = np.isin(truth["ids"], design.ids)
            truth = {k: np.asarray(v)[keep] for k, v in truth.items()}
            np.testing.assert_array_equal(truth["ids"], design.ids)
            cam_from_world = np.linalg.inv(infos[agent]["world_from_cam"])
            K = infos[agent]["intrinsics"]
            depth = obs[agent]["depth"]
            for xyz_built, xyz_design, vis in zip(truth["xyz"], design.xyz, truth["visible"], strict=True):
                if not vis or np.linalg.norm(xyz_built[:2] - xyz_design[:2]) < 0.3:
                    continue
                for xyz, out in ((xyz_built, on_built), (xyz_design, on_design)):
                    p = cam_from_world[:3, :3] @ xyz + cam_from_world[:3, 3]
                    u, v = (K @ p)[:2] / p[2]
                    out.append(abs(depth[int(v), int(u)] - p[2]))
        assert len(on_built) >= 4
        # The depth at the top's pixel is the top face's (within a pixel's footprint on that
        # oblique face); at the design position the ray misses the moved column.
        assert np.median(on_built) < 0.05
        assert np.mean(np.less(on_built, 0.15)) >= 0.9
        assert np.median(on_design) > 1.0
    finally:
        env.close()
