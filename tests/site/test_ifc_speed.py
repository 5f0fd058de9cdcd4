"""The import's speed tools: footprints made only where a rule needs them, and the parse's breakdown.

``benchmarks/ifc_import.py --breakdown`` splits a cold parse into the geometry kernel, the plan
footprints and the other rules, and the kernel's time by body representation; these tests check
what it counts on the shipped duplex (the times themselves are the benchmark's, never asserted).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX  # noqa: E402

from uav_struct_env.site import ifc as ifc_module  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "ifc_import.py"


@pytest.fixture(scope="module")
def bench(load_script):
    return load_script(SCRIPT)


def test_a_footprint_is_made_only_where_a_rule_needs_it(monkeypatch):
    """Every element outlined by its footprint gets one; a floor slab only when a rule compares it.

    On the duplex the finish-floor rule compares the two Level 2 floor slabs with the finish floors
    lying on them; nothing compares the roof slab, whose outline is its top face.
    """
    made: list[str] = []
    real = ifc_module._Footprints.__missing__

    def counted(self, guid):
        made.append(guid)
        return real(self, guid)

    monkeypatch.setattr(ifc_module._Footprints, "__missing__", counted)
    parsed = ifc_module._parse(DUPLEX, np.eye(4))
    floor_guids = {g for st in parsed.stages for g in st.floor}
    floors = {e.guid: e.name for e in parsed.elements if e.guid in floor_guids}
    outlined = {e.guid for e in parsed.elements if e.guid not in floors}
    assert len(made) == len(set(made))  # each made once
    assert outlined <= set(made) and len(outlined) == 69
    unmade = sorted(name.split(":")[-1] for g, name in floors.items() if g not in made)
    assert unmade == ["184483"]  # the roof slab
    assert sum(g in made for g in floors) == 2


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
