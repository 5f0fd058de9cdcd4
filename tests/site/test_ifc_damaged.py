"""Any real building imports, and a damaged file is refused rather than imported as another building.

Files are written by our own exporter (``Site.to_ifc``) and then damaged as real files are: a tiny
opening that has no outline at the importer's tolerance, a coordinate written as NaN / Inf /
1e300, a file cut short, a file too large; a ground-bearing slab at terrain level; and a small
steel plate whose plan union the outline cleaning used to empty.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import shapely

pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX, messy_site  # noqa: E402

from uav_struct_env.errors import IfcImportError  # noqa: E402
from uav_struct_env.site import ifc as ifc_module  # noqa: E402
from uav_struct_env.site import ifc_report, ifc_stages, load_ifc  # noqa: E402
from uav_struct_env.site.elements import Beam, Hole, Slab, TriangleMesh  # noqa: E402
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


# A 65 x 130 mm steel plate with a chamfered corner where a Tekla export puts it (tekla_steel_frame's
# angle cleat 2fpUCqylr77AsNpLdZi4sR, reduced to the vertices that matter), with a 0.7 mm2 sliver of
# the same element touching it at one vertex and 7 um from another: the closing of this plan union
# (GEOS's mitre buffer out and back in, by 0.1 mm) returned an EMPTY polygon, and the plate was
# dropped as "no plan footprint".
_PLATE = np.array([[13.02735, 6.7645], [13.02735, 6.8945], [13.09235, 6.8945], [13.09235, 6.892],
                   [13.092212, 6.890776], [13.090284, 6.887709]])
_SLIVER = np.array([[13.090281, 6.887702], [13.092212, 6.890776], [13.091805, 6.889614]])
_PLATE_Z = (3.84795, 3.92795)


def _prism(ring: np.ndarray, z0: float, z1: float) -> np.ndarray:
    """(T, 3, 3) triangles of the prism over ``ring`` (star-shaped from its first vertex)."""
    ring = ring if shapely.LinearRing(ring).is_ccw else ring[::-1]
    fan = np.array([[ring[0], ring[k], ring[k + 1]] for k in range(1, len(ring) - 1)])
    top = np.concatenate([fan, np.full((len(fan), 3, 1), z1)], axis=2)
    bottom = np.concatenate([fan[:, ::-1], np.full((len(fan), 3, 1), z0)], axis=2)
    lo = np.column_stack([ring, np.full(len(ring), z0)])
    lo_next, up = np.roll(lo, -1, axis=0), np.array([0.0, 0.0, z1 - z0])
    walls = [np.stack([lo, lo_next, lo_next + up], axis=1), np.stack([lo, lo_next + up, lo + up], axis=1)]
    return np.concatenate([top, bottom, *walls])


def _plate_triangles() -> np.ndarray:
    return np.concatenate([_prism(_PLATE, *_PLATE_Z), _prism(_SLIVER, *_PLATE_Z)])


def _mesh(tri: np.ndarray) -> TriangleMesh:
    return TriangleMesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3))


def test_a_plate_whose_closing_fails_keeps_its_real_footprint():
    tri = _plate_triangles()
    union = shapely.union_all(ifc_module._tri_polygons(tri[:, :, :2]), grid_size=1e-6)
    assert union.geom_type == "MultiPolygon" and union.area == pytest.approx(4.3157e-3, rel=1e-3)
    cleaned = ifc_module._clean(union)
    assert cleaned.area >= union.area - 3e-6  # the simplification at OUTLINE_TOL only (was 0.0)
    outline = ifc_module._footprint(tri)
    assert outline is not None
    np.testing.assert_allclose(outline.max(axis=0) - outline.min(axis=0), [0.065, 0.130], atol=1e-9)
    assert shapely.Polygon(outline).area == pytest.approx(shapely.Polygon(_PLATE).area, rel=1e-3)


def test_a_small_plate_is_imported_and_a_degenerate_member_still_dropped(tmp_path):
    """Through the exporter and the whole import: the plate is a member of L1, a flat sheet is dropped."""
    plate = Beam(guid="plate", name="plate", storey=1, outline=_PLATE, z_bottom=_PLATE_Z[0],
                 z_top=_PLATE_Z[1], mesh=_mesh(_plate_triangles()))
    flat = np.array([[[0, 3, 3], [1, 3, 3], [1, 3, 4]], [[0, 3, 3], [1, 3, 4], [0, 3, 4]]], dtype=float)
    sheet = Beam(guid="sheet", name="sheet", storey=1, outline=rectangle(0, 3, 1, 3.01), z_bottom=3.0,
                 z_top=4.0, mesh=_mesh(flat))  # a vertical sheet: no area in plan
    site = messy_site()
    site = dataclasses.replace(site, elements=(*site.elements, plate, sheet))
    path = _write(site, tmp_path, "plate.ifc")
    report = ifc_report(path)
    assert {r[2]: r[3] for r in report.kept}["plate"] == "beam of L1"
    assert {r[2]: r[3] for r in report.dropped}["sheet"] == "no plan footprint or no height"
    [imported] = [e for e in load_ifc(path, stage="L1/columns").elements if e.name == "plate"]
    np.testing.assert_allclose(imported.outline.max(axis=0) - imported.outline.min(axis=0), [0.065, 0.130],
                               atol=1e-6)
