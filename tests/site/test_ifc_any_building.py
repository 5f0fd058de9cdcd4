"""Issue 44, item 5: a real building with slabs or columns loads, or is refused in one line saying why.

Synthetic files written by ``write_ifc`` (then edited as real exporters write them): a steel frame
without an elevated floor gets columns-only stages; one with too few column tops is refused; a
file that writes ``*`` where ``$`` belongs (Renga) loads as the same building.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from ifc_sites import messy_site  # noqa: E402

from uav_struct_env.errors import IfcImportError  # noqa: E402
from uav_struct_env.site import ifc as ifc_module  # noqa: E402
from uav_struct_env.site import ifc_report, ifc_stages, load_ifc, write_ifc  # noqa: E402
from uav_struct_env.site.elements import Beam, Column, Slab, Stage, Storey  # noqa: E402
from uav_struct_env.site.ifc_file import star_arguments  # noqa: E402
from uav_struct_env.site.model import Site  # noqa: E402
from uav_struct_env.site.polygons import rectangle  # noqa: E402

AXES = [(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]


def _frame(n_columns: int = 4) -> Site:
    """Two storeys of columns, beams on the lower ones, and a slab on grade: no elevated floor."""
    storeys = (Storey("Ground", 0.0), Storey("L1", 3.0))
    low = [Column(guid=f"c{k}", name=f"c{k}", storey=0, axis=(x, y), z_bottom=0.0, z_top=2.7,
                  outline=rectangle(x - .15, y - .15, x + .15, y + .15)) for k, (x, y) in enumerate(AXES)]
    up = [Column(guid=f"u{k}", name=f"u{k}", storey=1, axis=(x, y), z_bottom=3.0, z_top=5.7,
                 outline=rectangle(x - .1, y - .1, x + .1, y + .1))
          for k, (x, y) in enumerate(AXES[:n_columns])]
    beams = [Beam(guid=f"b{k}", name=f"b{k}", storey=0, outline=rectangle(-.2, y - .2, 8.2, y + .2),
                  z_bottom=2.7, z_top=3.0) for k, y in enumerate((0.0, 6.0))]
    grade = Slab(guid="sog", name="slab on grade", storey=0, outline=rectangle(-1, -1, 9, 7),
                 z_bottom=-0.2, z_top=0.0)
    # a base plate exported as IfcColumn (Tekla does): 0.3 m tall, 0.4 m wide
    plate = Column(guid="p", name="plate", storey=0, axis=(4.0, 3.0), z_bottom=0.0, z_top=0.3,
                   outline=rectangle(3.8, 2.99, 4.2, 3.01))
    elements = (*low, *up, *beams, grade, plate)
    stage = Stage("all", frozenset(e.guid for e in elements), ())
    return Site(elements=elements, storeys=storeys, stages=(stage,), stage="all", name="frame")


def test_a_frame_without_a_floor_gets_columns_only_stages(tmp_path):
    path = write_ifc(_frame(), tmp_path / "frame.ifc")
    assert ifc_stages(path) == ["Ground/columns", "L1/columns"]
    site = load_ifc(path)
    assert site.stage == "L1/columns"  # the default: where the columns end
    tops = site.landmarks("column_tops")
    # the upper columns' tops; the lower ones lie under the beams
    np.testing.assert_allclose(np.sort(tops.xyz[:, 2]), [5.7] * 4, atol=1e-6)
    assert {label.split()[0] for label in tops.labels} == {"u0", "u1", "u2", "u3"}
    assert len(site.landmarks("slab_corners")) == 0  # the slab on grade bears none
    built = {e.name for e in site.built}
    assert {"b0", "b1", "slab on grade", "c0", "u0"} <= built
    ground = load_ifc(path, stage="Ground/columns")
    assert sorted(np.round(ground.landmarks("column_tops").xyz[:, 2], 6)) == [2.7] * 4  # not the plate
    plate = next(e for e in site.elements if e.name == "plate")
    assert plate.kind == "beam" and plate.guid in site.current_stage.built  # rendered, no landmark
    role = next(role for _, _, name, role in ifc_report(path).kept if name == "plate")
    assert role.startswith("IfcColumn 0.30 m tall and 0.40 m wide (a plate or post, not a column")
    assert not {"b0", "b1"} & {e.name for e in ground.built}  # the beams come after the columns


def test_too_few_column_tops_and_no_floor_is_refused_in_one_line(tmp_path):
    site = _frame(n_columns=3)
    # without the lower storey's columns (under beams, so no stage of their own either)
    path = write_ifc(site, tmp_path / "frame3.ifc")
    assert ifc_stages(path) == ["Ground/columns"]  # the lower columns still stand exposed there
    low_only = Site(elements=tuple(e for e in site.elements if e.storey == 1 or e.kind == "slab"),
                    storeys=site.storeys, stages=(Stage("all", frozenset(), ()),), stage="all", name="f")
    path = write_ifc(low_only, tmp_path / "three_columns.ifc")
    with pytest.raises(IfcImportError) as info:
        ifc_stages(path)
    message = str(info.value)
    assert "\n" not in message
    assert "has no stage a camera can use" in message
    assert "1 IfcSlab: 1 ground-bearing at the terrain" in message
    assert "3 IfcColumn, 3 kept" in message


def test_star_arguments_reads_top_level_arguments_only():
    text = (b"#1=IFCSLAB('g',$,*,'a,(*)''s',*,#5,#6,*,.FLOOR.);\n"
            b"#2=IFCSIUNIT(*,.LENGTHUNIT.,.MILLI.,.METRE.);\n"
            b"#3=IFCPROPERTYSINGLEVALUE('x*',$,IFCLABEL('*'),$);\n"
            b"#4=IFCCARTESIANPOINT((0.,0.));\n")
    assert star_arguments(text) == [(1, "IFCSLAB", (2, 4, 7)), (2, "IFCSIUNIT", (0,))]


def test_a_star_where_the_schema_wants_a_value_loads_the_same_building(tmp_path):
    clean = write_ifc(messy_site(), tmp_path / "clean.ifc")
    text = clean.read_text()
    # Renga's way: '*' for the products' names and the profiles' unset names
    starred = re.sub(r"^(#\d+=IFC(?:SLAB|COLUMN)\('[^']*',\$,)'[^']*'", r"\1*", text, flags=re.M)
    starred = re.sub(r"(IFCARBITRARYCLOSEDPROFILEDEF\(\.AREA\.,)\$", r"\1*", starred)
    assert starred != text
    path = tmp_path / "starred.ifc"
    path.write_text(starred)
    model = ifcopenshell.open(str(path))  # held: an instance outlives no file
    with pytest.raises(RuntimeError, match="derived"):  # what the kernel does with it unrepaired
        ifcopenshell.geom.create_shape(ifcopenshell.geom.settings(), model.by_type("IfcSlab")[0])
    assert ifc_stages(path) == ifc_stages(clean)
    for stage in ifc_stages(clean):
        a, b = load_ifc(clean, stage=stage), load_ifc(path, stage=stage)
        for name in ("slab_corners", "opening_corners", "column_tops"):
            np.testing.assert_array_equal(a.landmarks(name).xyz, b.landmarks(name).xyz)
    repaired = {c: n for c, n, _ in ifc_report(path).repaired}
    assert repaired["IfcArbitraryClosedProfileDef"] > 0 and repaired["IfcSlab"] > 0
    assert ifc_report(clean).repaired == ()


def test_the_duplicate_search_finds_a_twin_across_a_cell_boundary():
    """A twin 3 mm away whose bounding box corner falls into the next search cell is still found."""
    tri = np.array([[[0.999, 0.0, 0.0], [4.999, 0.0, 0.0], [0.999, 4.0, 0.3]]])
    shifted = tri + [0.003, 0.0, 0.0]
    raws = [ifc_module._Raw(k, guid, "IfcBeam", guid, "beam", 0, None, t)
            for k, (guid, t) in enumerate([("a", tri), ("far", tri + [5.0, 0, 0]), ("twin", shifted)])]
    footprints = {r.guid: ifc_module._safe_footprint(r.tri) for r in raws}
    unique, dropped = ifc_module._coincident_duplicates(raws, footprints)
    assert [r.guid for r in unique] == ["a", "far"]
    assert dropped[0][0] == "twin" and "coincident duplicate of a" in dropped[0][3]


def test_a_columns_only_stage_is_its_own_columns_role_and_the_study_evaluates_it(tmp_path):
    from uav_struct_env.study.protocol import StudyConfig

    path = write_ifc(_frame(), tmp_path / "frame.ifc")
    site = load_ifc(path)
    assert site.floor_stage("columns") == "L1/columns"
    assert site.floor_stage("slab") is None
    config = StudyConfig(site=str(path))
    keys = [m.key for m in config.selected_methods]
    assert "column_tops" in keys
    assert config.skip_reasons["slab_corners"] == ("stage 'L1/columns' has no floor (a frame of "
                                                   "columns only)")
