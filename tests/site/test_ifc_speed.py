"""The import's speed: the parse's breakdown, the faster plan union, and the before/after diff.

``benchmarks/ifc_import.py --breakdown`` splits a cold parse into the geometry kernel, the plan
footprints and the other rules, and the kernel's time by body representation; these tests check
what it counts on the shipped duplex (the times themselves are the benchmark's, never asserted).
``benchmarks/ifc_import_diff.py`` says what a change to the importer moves, file by file.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX  # noqa: E402

from uav_struct_env.site import ifc as ifc_module  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "ifc_import.py"
DIFF = SCRIPT.with_name("ifc_import_diff.py")


@pytest.fixture(scope="module")
def bench(load_script):
    return load_script(SCRIPT)


def test_the_kernel_is_counted_by_body_representation(bench):
    rows = bench.kernel_by_kind(DUPLEX)
    counts = {kind: n for kind, n, _, _ in rows}
    assert counts == {
        "IfcExtrudedAreaSolid/IfcRectangleProfileDef": 57,
        "IfcExtrudedAreaSolid/IfcArbitraryClosedProfileDef": 24,
        "IfcBooleanClippingResult[2]/IfcExtrudedAreaSolid/IfcRectangleProfileDef": 3,
        "IfcBooleanClippingResult[1]/IfcExtrudedAreaSolid/IfcRectangleProfileDef": 1,
        "IfcFaceBasedSurfaceModel": 1,
    }
    assert all(tri > 0 and cpu >= 0 for _, _, tri, cpu in rows)
    assert [r[3] for r in rows] == sorted((r[3] for r in rows), reverse=True)


def test_the_breakdown_adds_up_and_leaves_the_importer_as_it_was(bench, capsys):
    before = ifc_module._tessellate, ifc_module._footprint, ifc_module._slab_top
    out = bench.breakdown(DUPLEX)
    parts = out["kernel_cpu_s"] + out["footprint_cpu_s"] + out["slab_top_cpu_s"] + out["rules_cpu_s"]
    assert parts == pytest.approx(out["total_cpu_s"])
    assert out["kernel_cpu_s"] > 0 and out["footprint_cpu_s"] > 0 and out["rules_cpu_s"] > 0
    assert (ifc_module._tessellate, ifc_module._footprint, ifc_module._slab_top) == before
    assert "IfcExtrudedAreaSolid/IfcRectangleProfileDef" in capsys.readouterr().out


def _box(x0: float, y0: float, x1: float, y1: float, z0: float = 3.0, z1: float = 3.3) -> np.ndarray:
    """(12, 3, 3) triangles of an axis-aligned box: a beam's tessellation."""
    c = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return np.array([c[[q[0], q[k], q[k + 1]]] for q in quads for k in (1, 2)])


@pytest.fixture
def grid_unions(monkeypatch):
    """The ``grid_size`` of every ``shapely.union_all`` call the importer makes (None: floating point)."""
    import shapely

    calls = []
    original = shapely.union_all

    def spy(geoms, grid_size=None, **kwargs):
        calls.append(grid_size)
        return original(geoms, grid_size=grid_size, **kwargs)

    monkeypatch.setattr(shapely, "union_all", spy)
    return calls


def test_a_beam_footprint_is_unioned_in_floating_point_and_agrees_with_the_grid(grid_unions):
    tri = np.concatenate([_box(0.0, 0.0, 6.0, 0.3), _box(5.85, -0.15, 6.15, 0.45)])  # a beam and its cleat
    fast = ifc_module._footprint(tri, fast=True)
    assert grid_unions == [None]
    exact = ifc_module._footprint(tri)
    assert grid_unions == [None, 1e-6]
    import shapely

    a, b = shapely.Polygon(fast), shapely.Polygon(exact)
    assert a.area == pytest.approx(6.0 * 0.3 + 0.3 * 0.6 - 0.15 * 0.3, rel=1e-9)
    assert a.hausdorff_distance(b) <= ifc_module.OUTLINE_TOL


def test_a_sliver_is_unioned_on_the_grid_even_when_fast(grid_unions):
    """A 4 mm strip (a notch's sliver, thinner than _FAST_MIN_WIDTH): the grid decides its outline."""
    tri = _box(0.0, 0.0, 2.0, 0.004)
    fast = ifc_module._footprint(tri, fast=True)
    assert grid_unions == [None, 1e-6]
    np.testing.assert_array_equal(fast, ifc_module._footprint(tri))



def test_the_diff_sees_a_landmark_moved_and_a_row_changed(load_script):
    diff = load_script(DIFF)
    snap = diff.snapshot(str(DUPLEX))
    assert len(snap["landmarks"]) == 28 and len(snap["elements"]) == 72
    same = diff._differences(snap, copy.deepcopy(snap))
    assert same["landmark_max_m"] == 0.0 and same["outline_max_m"] == 0.0 and same["meshes_changed"] == 0
    assert not {"kept", "dropped"} & same.keys()
    moved = copy.deepcopy(snap)
    key = sorted(moved["landmarks"])[0]
    moved["landmarks"][key] = moved["landmarks"][key] + [0.0, 0.002, 0.0]
    row = ("guid", "IfcBeam", "a beam", "no plan footprint or no height")
    moved["report"]["dropped"] = (*moved["report"]["dropped"], row)
    d = diff._differences(snap, moved)
    assert d["landmark_max_m"] == pytest.approx(0.002)
    assert d["dropped"] == ([], [row])
