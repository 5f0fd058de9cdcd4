import numpy as np
import pytest

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site import (
    ArucoMarker,
    Building,
    ColumnGrid,
    Opening,
    building_site,
    make_site,
    paper_building,
    paper_site,
    random_site,
)


def test_paper_building_matches_the_paper():
    b = paper_building()
    assert b.grid.shape == (3, 4)
    np.testing.assert_allclose(b.grid.xs, [0, 4, 8])
    np.testing.assert_allclose(b.grid.ys, [0, 4, 7, 11])
    (stair,) = b.openings
    assert sorted(stair.size) == [2.6, 3.6]


def test_stage_slab_exposes_slab_and_opening_corners_but_no_column_tops():
    site = paper_site("slab")
    assert len(site.landmarks("slab_corners")) == 4
    assert len(site.landmarks("opening_corners")) == 4
    assert len(site.landmarks("column_tops")) == 0
    assert len(site.columns) == 12  # ground storey only


def test_stage_columns_exposes_twelve_column_tops_above_the_slab():
    site = paper_site("columns")
    tops = site.landmarks("column_tops")
    assert len(tops) == 12
    assert len(site.columns) == 24
    slab_z = site.slabs[0].z_top
    assert np.all(tops.xyz[:, 2] > slab_z + 2.5)
    # every top is at a grid point
    grid = {(x, y) for x in site.building.grid.xs for y in site.building.grid.ys}
    assert {(x, y) for x, y, _ in tops.xyz} == grid


def test_landmark_ids_are_unique_and_stable_across_stages():
    a, b = paper_site("slab"), paper_site("columns")
    for name in ("slab_corners", "opening_corners", "aruco"):
        np.testing.assert_array_equal(a.landmarks(name).ids, b.landmarks(name).ids)
        np.testing.assert_allclose(a.landmarks(name).xyz, b.landmarks(name).xyz)
    ids = b.landmarks("all").ids
    assert len(set(ids.tolist())) == len(ids) == 20


def test_slab_and_opening_corner_positions():
    site = paper_site("slab")
    np.testing.assert_allclose(
        site.landmarks("slab_corners").xyz,
        [[-0.3, -0.3, 3.5], [8.3, -0.3, 3.5], [8.3, 11.3, 3.5], [-0.3, 11.3, 3.5]],
    )
    np.testing.assert_allclose(
        site.landmarks("opening_corners").xyz,
        [[0.2, 4.2, 3.5], [3.8, 4.2, 3.5], [3.8, 6.8, 3.5], [0.2, 6.8, 3.5]],
    )


def test_markers_two_per_side_about_three_metres_out():
    site = paper_site("slab", marker_size=0.5)
    assert len(site.markers) == 8
    assert all(m.dictionary == "DICT_4X4_50" and m.side == 0.5 for m in site.markers)
    xmin, ymin, xmax, ymax = site.building.slab_bounds
    for m in site.markers:
        x, y, _ = m.center
        gap = max(xmin - x, x - xmax, ymin - y, y - ymax)
        assert 2.5 <= gap <= 3.5
    corners = site.landmarks("aruco")
    assert len(corners) == 32
    # OpenCV order: top-left, top-right, bottom-right, bottom-left in the marker's own frame
    c = site.markers[0].corners_world
    assert c[0, 0] < c[1, 0] and c[1, 1] > c[2, 1] and c[3, 0] < c[2, 0]
    assert paper_site(marker_size=None).markers == ()


def test_marker_pose_with_yaw_rotates_corners():
    m = ArucoMarker(id=3, side=1.0, center=(10.0, 0.0, 0.0), yaw=np.pi / 2)
    np.testing.assert_allclose(m.corners_world[0], [9.5, -0.5, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (
            dict(openings=(Opening("stair", (2.0, 5.5), (3.6, 2.6)),), column_section=(0.5, 0.5)),
            r"opening 'stair' .* overlaps the column at \(0\.0, 4\.0\)",
        ),
        (
            dict(openings=(Opening("hole", (8.0, 5.5), (1.0, 1.0)),)),
            r"opening 'hole' .* outside the slab",
        ),
        (dict(column_section=(4.5, 0.4)), r"columns overlap: spans_x\[0\] = 4\.0 m"),
        (dict(slab_thickness=-0.1), r"slab_thickness \(m\) must be a number in \(0, 5\], got -0\.1"),
        (
            dict(storey_heights=(3.5, 0.2)),
            r"storey_heights\[1\] = 0\.2 m must exceed slab_thickness",
        ),
        (dict(slab_overhang=0.05), r"slab_overhang = 0\.05 m must cover"),
    ],
)
def test_impossible_buildings_raise_naming_the_value(kwargs, match):
    base = dict(grid=ColumnGrid((4.0, 4.0), (4.0, 3.0, 4.0)))
    with pytest.raises(SiteGeometryError, match=match):
        Building(**{**base, **kwargs})


def test_impossible_grid_and_opening_sizes_raise():
    with pytest.raises(
        SiteGeometryError, match=r"spans_y\[1\] \(m\) must be a number in \(0, 200\], got 0"
    ):
        ColumnGrid((4.0,), (4.0, 0.0))
    with pytest.raises(SiteGeometryError, match=r"spans_x must be a non-empty"):
        ColumnGrid((), (4.0,))
    with pytest.raises(SiteGeometryError,
                       match=r"opening 'o' size\[1\] \(m\) must be a number in \(0, 2000\], got -2"):
        Opening("o", (1.0, 1.0), (1.0, -2.0))
    with pytest.raises(TypeError, match=r"spans_x\[0\] \(m\) must be a number, got '4'"):
        ColumnGrid(("4",), (4.0,))


def test_sites_with_bad_markers_or_stage_raise():
    b = paper_building()
    m = ArucoMarker(id=1, side=1.0, center=(-4.0, 0.0, 0.01))
    with pytest.raises(SiteGeometryError, match=r"duplicate marker ids \[1\]"):
        building_site(b, markers=(m, ArucoMarker(id=1, side=1.0, center=(-4.0, 6.0, 0.01))))
    with pytest.raises(
        SiteGeometryError, match=r"marker 2 at \(4\.0, 4\.0\) lies under the building"
    ):
        building_site(b, markers=(ArucoMarker(id=2, side=1.0, center=(4.0, 4.0, 0.0)),))
    with pytest.raises(SiteGeometryError, match=r"markers 1 and 5 overlap"):
        building_site(b, markers=(m, ArucoMarker(id=5, side=1.0, center=(-4.2, 0.5, 0.01))))
    with pytest.raises(SiteGeometryError, match=r"marker id must be an int in \[0, 50\).*got 50"):
        ArucoMarker(id=50, side=1.0, center=(0, 0, 0))
    with pytest.raises(SiteGeometryError,
                       match=r"marker 0 side \(m\) must be a number in \(0, 10\], got 0\.0"):
        ArucoMarker(id=0, side=0.0, center=(0, 0, 0))
    with pytest.raises(
        SiteGeometryError,
        match=r"stage must be one of \('Level 1/slab', 'slab', 'Level 1/columns', 'columns', "
        r"'Level 2/slab'\), got 'roof'",
    ):
        building_site(b, stage="roof")
    with pytest.raises(ValueError, match=r"landmark set must be one of .* got 'doors'"):
        paper_site().landmarks("doors")


def test_any_building_is_expressible():
    b = Building(
        grid=ColumnGrid((6.0, 5.0, 5.0, 6.0), (7.0,)),
        storey_heights=(4.2, 3.6, 3.6),
        column_section=(0.5, 0.3),
        slab_thickness=0.3,
        slab_overhang=0.4,
        openings=(
            Opening("stair", (8.5, 3.5), (2.0, 5.0)),
            Opening("shaft", (17.0, 3.5), (1.5, 1.5)),
        ),
    )
    site = building_site(b, stage="columns")
    assert len(site.landmarks("column_tops")) == 10
    assert len(site.landmarks("opening_corners")) == 8
    np.testing.assert_allclose(site.landmarks("column_tops").xyz[:, 2], 4.2 + 3.6 - 0.3)


def test_random_sites_are_seeded_and_plausible():
    a = [random_site(np.random.default_rng(7)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(0)
    sites = [random_site(rng) for _ in range(300)]
    assert len({s.building for s in sites}) > 250
    assert {s.stage for s in sites} == {"slab", "columns"}
    for s in sites:
        assert len(s.landmarks("opening_corners")) == 4
        assert len(s.markers) == 8


def test_make_site_resolves_names_and_errors():
    assert make_site("paper", stage="slab").stage == "slab"
    assert make_site(paper_site("slab"), stage="columns").stage == "columns"
    with pytest.raises(
        ValueError,
        match=r"site must be a Site, 'random', a site file \(\*\.json\) or one of \['paper'\], got 'moon'",
    ):
        make_site("moon")
    with pytest.raises(ValueError, match=r"site='random' needs a numpy.random.Generator"):
        make_site("random")


def test_site_files_round_trip_and_resize_markers(tmp_path):
    from uav_struct_env.site.io import load_site, save_site, site_from_dict

    site = paper_site("slab", marker_size=0.5)
    path = tmp_path / "site.json"
    save_site(site, path)
    assert load_site(path) == site
    resolved = make_site(str(path), stage="columns", marker_size=1.0)
    assert resolved.stage == "columns" and {m.side for m in resolved.markers} == {1.0}
    assert resolved.building == site.building
    with pytest.raises(SiteGeometryError, match=r"site.building has unknown keys \['floors'\]"):
        site_from_dict({"building": {"grid": {"spans_x": [4], "spans_y": [4]}, "floors": 2}})
    with pytest.raises(SiteGeometryError, match=r"columns overlap: spans_x\[0\] = 0\.3 m"):
        site_from_dict({"building": {"grid": {"spans_x": [0.3], "spans_y": [4]}}})
    with pytest.raises(FileNotFoundError, match=r"site file '.*nope.json' does not exist"):
        load_site(tmp_path / "nope.json")
