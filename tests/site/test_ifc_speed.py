"""The import's speed tool: the parse's breakdown.

``benchmarks/ifc_import.py --breakdown`` splits a cold parse into the geometry kernel, the plan
footprints and the other rules, and the kernel's time by body representation; these tests check
what it counts on the shipped duplex (the times themselves are the benchmark's, never asserted).
"""

from __future__ import annotations

from pathlib import Path

import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX  # noqa: E402

from uav_struct_env.site import ifc as ifc_module  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "ifc_import.py"


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
