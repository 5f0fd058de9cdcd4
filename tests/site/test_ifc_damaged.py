"""Any real building imports, and a damaged file is refused rather than imported as another building.

Files are written by our own exporter (``Site.to_ifc``) and then damaged as real files are: a tiny
opening that has no outline at the importer's tolerance, a coordinate written as NaN / Inf /
1e300, a file cut short, a file too large; and a ground-bearing slab at terrain level.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX, messy_site  # noqa: E402

from uav_struct_env.errors import IfcImportError  # noqa: E402
from uav_struct_env.site import ifc as ifc_module  # noqa: E402
from uav_struct_env.site import ifc_report, ifc_stages, load_ifc  # noqa: E402
from uav_struct_env.site.elements import Hole, Slab  # noqa: E402
from uav_struct_env.site.ifc_file import MAX_FILE_MB_VARIABLE  # noqa: E402
from uav_struct_env.site.polygons import rectangle  # noqa: E402


def _write(site, tmp_path: Path, name: str) -> Path:
    return site.to_ifc(tmp_path / name)


def _with(site, guid: str, **changes):
    return dataclasses.replace(site, elements=tuple(
        dataclasses.replace(e, **changes) if e.guid == guid else e for e in site.elements))


@pytest.fixture(scope="module")
def messy(tmp_path_factory) -> Path:
    return _write(messy_site(), tmp_path_factory.mktemp("damaged"), "messy.ifc")


def test_a_degenerate_opening_is_dropped_and_reported_not_fatal(tmp_path):
    """A 2 cm opening has no outline at OUTLINE_TOL; it sank the whole file before."""
    site = _with(messy_site(), "s1", holes=(Hole("pin", rectangle(2, 2, 2.02, 2.02), guid="pin"),))
    path = _write(site, tmp_path, "pinhole.ifc")
    report = ifc_report(path)
    [row] = [d for d in report.dropped if "degenerate" in d[3]]
    assert row[1] == "IfcOpeningElement" and "opening at (2.00, 2.00)" in row[0]
    assert "the slab is kept" in row[3] and "enclosing an area" in row[3]
    assert ifc_stages(path) == ["L1/slab", "L1/columns", "L2/slab"]
    l1 = load_ifc(path, stage="L1/slab")
    assert len(l1.landmarks("slab_corners")) == 4 and len(l1.landmarks("opening_corners")) == 0


def test_a_ground_bearing_slab_bears_no_landmarks(tmp_path):
    site = messy_site()
    ground = Slab(guid="sog", name="slab on grade", storey=0, outline=rectangle(-1, -1, 9, 7),
                  z_bottom=-0.15, z_top=0.05)
    site = dataclasses.replace(site, elements=(*site.elements, ground))
    path = _write(site, tmp_path, "grade.ifc")
    kept = {name: role for _, _, name, role in ifc_report(path).kept}
    assert "ground-bearing slab, top at z = 0.05 m" in kept["slab on grade"]
    assert ifc_stages(path) == ["L1/slab", "L1/columns", "L2/slab"]  # no "Ground/slab"
    l1 = load_ifc(path, stage="L1/slab")
    slab = next(e for e in l1.elements if e.name == "slab on grade")
    assert not slab.structural and slab.guid in l1.current_stage.built  # rendered, no landmarks


def test_the_duplex_ground_floor_is_no_stage():
    """The duplex's Level 1 floor is slab on grade at z = 0: its renders show only the ground."""
    assert ifc_stages(DUPLEX) == ["Level 2/slab", "Roof/slab"]
    grade = [r for r in ifc_report(DUPLEX).kept if "ground-bearing" in r[3]]
    assert {r[2].split(":")[1] for r in grade} == {"127mm Slab on Grade", "150mm Exterior Slab on Grade"}


@pytest.mark.parametrize("bad", ["NAN", "INF", "-1.E300"])
def test_a_damaged_coordinate_refuses_the_file(messy, tmp_path, bad):
    text = messy.read_text()
    point = re.search(r"#(\d+)=IFCCARTESIANPOINT\(\(0\.,0\.,2\.4000000000000004\)\);", text)
    damaged = tmp_path / "damaged.ifc"
    damaged.write_text(text.replace(point.group(0), f"#{point.group(1)}=IFCCARTESIANPOINT((0.,{bad},2.4));"))
    with pytest.raises(IfcImportError, match=rf"damaged coordinate: #{point.group(1)} IFCCARTESIANPOINT "
                                             rf"holds '{re.escape(bad)}'"):
        load_ifc(damaged)


def test_a_damaged_point_list_or_direction_refuses_the_file(messy, tmp_path):
    text = messy.read_text()
    damaged = tmp_path / "list.ifc"
    damaged.write_text(text.replace("(8.5,6.5,1.2)));", "(8.5,NAN,1.2)));", 1))
    with pytest.raises(IfcImportError, match="IFCCARTESIANPOINTLIST3D holds 'NAN'"):
        ifc_stages(damaged)
    damaged.write_text(text.replace("IFCDIRECTION((0.,0.,1.));", "IFCDIRECTION((0.,INF,1.));", 1))
    with pytest.raises(IfcImportError, match="IFCDIRECTION holds 'INF'"):
        ifc_stages(damaged)


@pytest.mark.parametrize("fraction", [0.005, 0.03])
def test_a_truncated_file_is_refused(tmp_path, fraction):
    data = DUPLEX.read_bytes()
    cut = tmp_path / "cut.ifc"
    cut.write_bytes(data[: int(len(data) * (1 - fraction))])
    with pytest.raises(IfcImportError, match="is truncated: an IFC-SPF file ends with 'END-ISO-10303-21;'"):
        ifc_stages(cut)


def test_the_size_guard_refuses_before_parsing(messy, monkeypatch):
    ifc_module._parse_cached.cache_clear()
    monkeypatch.setenv(MAX_FILE_MB_VARIABLE, "0.001")
    too_big = rf"MB, more than the 0 MB an import may parse.*{MAX_FILE_MB_VARIABLE}"
    with pytest.raises(IfcImportError, match=too_big):
        ifc_stages(messy)
    monkeypatch.setenv(MAX_FILE_MB_VARIABLE, "lots")
    not_a_number = rf"{MAX_FILE_MB_VARIABLE} must be a positive number of MB, got 'lots'"
    with pytest.raises(IfcImportError, match=not_a_number):
        ifc_stages(messy)
    monkeypatch.setenv(MAX_FILE_MB_VARIABLE, "50")
    assert ifc_stages(messy) == ["L1/slab", "L1/columns", "L2/slab"]


def test_the_report_prints_short_and_its_summary_lists_every_element():
    report = ifc_report(DUPLEX)
    assert repr(report).startswith(f"ImportReport({str(DUPLEX)!r}: kept ") and len(repr(report)) < 300
    assert repr(report).endswith("classes not imported; .summary() lists every element)")
    rows = len(report.kept) + len(report.dropped) + len(report.skipped)
    assert len(report.summary().splitlines()) == 1 + rows


def test_same_named_elements_whose_guids_share_a_long_prefix_get_unique_names(tmp_path):
    """Revit copies an element level by level: the copies' GlobalIds can share 14 characters."""
    import ifcopenshell

    path = messy_site().to_ifc(tmp_path / "copies.ifc")
    f = ifcopenshell.open(str(path))
    columns = sorted(f.by_type("IfcColumn"), key=lambda c: c.Tag)[:3]
    for k, c in enumerate(columns):
        c.Name = "Column:600x600:1"
        c.GlobalId = "0ZBert7zf3GhTh" + "dO12NKA" + "abc"[k]  # 22 characters, same first 21
    f.write(str(path))
    site = load_ifc(path)
    names = [e.name for e in site.elements if e.kind == "column"]
    assert len(set(names)) == len(names)
    copies = sorted(n for n in names if n.startswith("Column:600x600:1 ["))
    assert copies == [f"Column:600x600:1 [0ZBert7zf3GhThdO12NKA{c}]" for c in "abc"]
