"""Site files under hostile input: every field checked at load time, naming it; absurd sizes fast."""

from __future__ import annotations

import copy
import json
import time

import numpy as np
import pytest

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site import Building, ColumnGrid, Opening
from uav_struct_env.site.io import load_site, site_from_dict
from uav_struct_env.site.landmarks import STRUCTURAL_SETS
from uav_struct_env.site.parametric import building_site

BASE = {
    "building": {"grid": {"spans_x": [4, 4], "spans_y": [4, 3, 4]},
                 "storey_heights": [3.5, 3.5], "column_section": [0.35, 0.35],
                 "slab_thickness": 0.25, "slab_overhang": 0.3,
                 "openings": [{"name": "stair", "center": [2.0, 5.5], "size": [3.6, 2.6]}]},
    "stage": "columns",
    "markers": [{"id": 0, "side": 1.0, "center": [2.0, -3.3, 0.01]}],
}
NAN, INF = float("nan"), float("inf")


def _with(path: str, value):
    """BASE with the entry at ``path`` (dotted, list indices as numbers) set to ``value``."""
    data = copy.deepcopy(BASE)
    *parents, last = [int(k) if k.isdigit() else k for k in path.split(".")]
    node = data
    for k in parents:
        node = node[k]
    node[last] = value
    return data


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("building.openings.0.center", [NAN, 5.5], r"opening 'stair' center\[0\] \(m\) must be .*got nan"),
        ("building.openings.0.center", [1.0], r"opening 'stair' center must be 2 numbers, got \(1.0,\)"),
        ("building.openings.0.size", [3.6, INF], r"opening 'stair' size\[1\] \(m\) must be .*got inf"),
        ("building.openings.0.name", 3, r"opening name must be a non-empty string, got 3"),
        ("building.openings", 5, r"site.building.openings must be a JSON list, got 5"),
        ("markers.0.center", [NAN, -3.3, 0.0], r"marker 0 center\[0\] \(m\) must be .*got nan"),
        ("markers.0.center", [2.0, -3.3], r"marker 0 center must be 3 numbers, got \(2.0, -3.3\)"),
        ("markers.0.yaw", NAN, r"marker 0 yaw \(rad\) must be finite, got nan"),
        ("markers.0.quiet_zone", NAN, r"marker 0 quiet_zone must be a number in \[0, 10\], got nan"),
        ("markers.0.side", 1e6, r"marker 0 side \(m\) must be a number in \(0, 10\], got 1000000.0"),
        ("markers", {"id": 0}, r"site.markers must be a JSON list"),
        ("building.grid.spans_x", [1e308, 4],
         r"spans_x\[0\] \(m\) must be a number in \(0, 200\], got 1e\+308"),
        ("building.grid.spans_x", [[[[4]]]], r"spans_x\[0\] \(m\) must be a number, got \[\[\[4\]\]\]"),
        ("building.grid.spans_y", "434", r"spans_y must be a non-empty list, got '434'"),
        ("building.storey_heights", [1e6],
         r"storey_heights\[0\] \(m\) must be a number in \(0, 50\], got 1000000"),
        ("building.storey_heights", [], r"storey_heights must be a non-empty list, got 0 entries"),
        ("building.column_section", [0.35], r"column_section must be 2 numbers, got 1 entries"),
        ("building.slab_overhang", "0.3", r"slab_overhang \(m\) must be a number, got '0.3'"),
        ("building.slab_thickness", NAN, r"slab_thickness \(m\) must be a number in \(0, 5\], got nan"),
        ("ground_size", NAN, r"ground_size \(m\) must be a number in \(0, 20000\], got nan"),
        ("name", 5, r"site name must be a string, got 5"),
    ],
)
def test_a_malformed_field_is_refused_at_load_time_naming_it(path, value, message):
    with pytest.raises(SiteGeometryError, match=message):
        site_from_dict(_with(path, value))


def test_the_untouched_file_loads():
    site = site_from_dict(copy.deepcopy(BASE))
    assert len(site.landmarks("column_tops")) == 12


@pytest.mark.parametrize(
    ("spans_x", "spans_y", "message"),
    [
        ([4] * 1000, [4] * 1000, "a grid of 1001 x 1001 columns exceeds the 10000 supported"),
        ([4] * 1_000_000, [4], "a grid of 1000001 x 2 columns exceeds the 10000 supported"),
        ([150] * 20, [4], r"spans_x add up to 3000.0 m, more than the 2000.0 m supported"),
    ],
)
def test_absurd_sizes_are_refused_in_milliseconds(spans_x, spans_y, message):
    data = _with("building.grid", {"spans_x": spans_x, "spans_y": spans_y})
    t0 = time.perf_counter()
    with pytest.raises(SiteGeometryError, match=message):
        site_from_dict(data)
    assert time.perf_counter() - t0 < 0.25  # measured 0.1-40 ms (the 1e6-entry list is the slowest)


def test_too_many_openings_are_refused_before_the_overlap_checks():
    many = [{"name": f"o{k}", "center": [2.0, 5.5], "size": [0.1, 0.1]} for k in range(5000)]
    t0 = time.perf_counter()
    with pytest.raises(SiteGeometryError, match="site.building.openings has 5000 entries, more than the 200"):
        site_from_dict(_with("building.openings", many))
    assert time.perf_counter() - t0 < 0.25


def test_deeply_nested_json_is_a_site_error(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text("[" * 200_000 + "]" * 200_000)
    with pytest.raises(SiteGeometryError, match="nested too deeply"):
        load_site(path)


def test_landmark_ids_are_unique_with_30_openings_and_800_columns():
    # 20 x 20 grid lines, two storeys: 800 columns; 30 openings in the cells between them.
    spans = (5.0,) * 19
    cells = [(ix, iy) for iy in range(19) for ix in range(19)][::12][:30]
    openings = tuple(Opening(f"o{k}", (5.0 * ix + 2.5, 5.0 * iy + 2.5), (2.0, 2.0))
                     for k, (ix, iy) in enumerate(cells))
    building = Building(ColumnGrid(spans, spans), storey_heights=(3.5, 3.5), openings=openings)
    site = building_site(building, stage="slab")
    assert sum(1 for e in site.elements if e.kind == "column") == 800 and len(openings) == 30
    seen: dict[tuple[str, str, str], int] = {}
    for stage in site.stage_names:
        at = site.with_stage(stage)
        ids = np.concatenate([at.landmarks(n).ids for n in STRUCTURAL_SETS])
        assert len(np.unique(ids)) == len(ids), stage
        for name in STRUCTURAL_SETS:  # the same landmark keeps its id at every stage
            lm = at.landmarks(name)
            for i, guid, label in zip(lm.ids.tolist(), lm.elements, lm.labels, strict=True):
                assert seen.setdefault((name, guid, label), i) == i
    assert len(set(seen.values())) == len(seen)
    assert len(site.landmarks("opening_corners")) == 120


def test_site_file_round_trip_keeps_its_values(tmp_path):
    path = tmp_path / "site.json"
    path.write_text(json.dumps(BASE))
    site = load_site(path)
    assert site.building.openings[0].center == (2.0, 5.5)
    assert site.markers[0].center == (2.0, -3.3, 0.01)
