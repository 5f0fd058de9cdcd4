"""IFC import and export (uav_struct_env.site.ifc) on a real building and on synthetic messy files."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX, messy_site  # noqa: E402

from uav_struct_env.errors import ConfigError, IfcImportError, SiteGeometryError  # noqa: E402
from uav_struct_env.site import (  # noqa: E402
    Slab,
    ifc_report,
    ifc_stages,
    load_ifc,
    make_site,
    paper_site,
    random_site,
)
from uav_struct_env.site import ifc as ifc_module  # noqa: E402
from uav_struct_env.site.landmarks import check_landmarks  # noqa: E402
from uav_struct_env.site.model import Site  # noqa: E402
from uav_struct_env.site.polygons import rectangle  # noqa: E402

STRUCTURAL = ("slab_corners", "opening_corners", "column_tops")


# ----------------------------------------------------------------------------- independent geometry
def _axis2placement(a) -> np.ndarray:
    """4x4 of an IfcAxis2Placement3D, composed by hand (no ifcopenshell.util, no geom)."""
    m = np.eye(4)
    z = np.array(a.Axis.DirectionRatios if a.Axis else (0.0, 0.0, 1.0), dtype=float)
    x = np.array(a.RefDirection.DirectionRatios if a.RefDirection else (1.0, 0.0, 0.0), dtype=float)
    z /= np.linalg.norm(z)
    x = x - (x @ z) * z
    x /= np.linalg.norm(x)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, np.cross(z, x), z
    m[:3, 3] = a.Location.Coordinates
    return m


def _object_placement(lp) -> np.ndarray:
    """World matrix of an IfcLocalPlacement chain."""
    m = _axis2placement(lp.RelativePlacement)
    return m if lp.PlacementRelTo is None else _object_placement(lp.PlacementRelTo) @ m


def _length_unit_m(f) -> float:
    for u in f.by_type("IfcUnitAssignment")[0].Units:
        if u.is_a("IfcSIUnit") and u.UnitType == "LENGTHUNIT":
            return {None: 1.0, "MILLI": 1e-3, "CENTI": 1e-2}[u.Prefix]
    raise AssertionError("no SI length unit")


def _raw_slab_outline(f, guid: str) -> tuple[np.ndarray, float]:
    """A slab's extruded profile corners (K, 2) in world metres and its top elevation."""
    slab = f.by_guid(guid)
    solid = next(i for r in slab.Representation.Representations for i in r.Items
                 if i.is_a("IfcExtrudedAreaSolid"))
    curve = solid.SweptArea.OuterCurve
    pts2 = np.array([p.Coordinates for p in curve.Points], dtype=float)[:-1]  # closed polyline
    world = _object_placement(slab.ObjectPlacement) @ _axis2placement(solid.Position)
    local = np.column_stack([pts2, np.zeros(len(pts2)), np.ones(len(pts2))])
    xyz = (world @ local.T).T[:, :3]
    top = world @ np.array([*(solid.Depth * np.array(solid.ExtrudedDirection.DirectionRatios)), 1.0])
    scale = _length_unit_m(f)
    z = scale * max(xyz[:, 2].max(), top[2])
    return scale * xyz[:, :2], float(z)


def _same_points(a: np.ndarray, b: np.ndarray, tol: float = 1e-3) -> None:
    """Equal point sets within ``tol`` (one-to-one, any order)."""
    assert a.shape == b.shape, (a.shape, b.shape)
    if len(a) == 0:
        return
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    assert (d.min(axis=1) <= tol).all() and (d.min(axis=0) <= tol).all(), d.min(axis=1).max()


# ----------------------------------------------------------------------------- the duplex
@pytest.fixture(scope="module")
def duplex_l2() -> Site:
    return load_ifc(DUPLEX, stage="Level 2/slab")


def test_duplex_stages_in_build_order():
    # Level 1's floor is slab on grade at terrain level: no stage (tests/site/test_ifc_damaged.py)
    assert ifc_stages(DUPLEX) == ["Level 2/slab", "Roof/slab"]
    site = load_ifc(DUPLEX)  # stage None: the last
    assert site.stage == "Roof/slab" and site.building is None and site.markers == ()
    assert [s.name for s in site.storeys] == ["T/FDN", "Level 1", "Level 2", "Roof"]
    assert site.source["schema"] == "IFC2X3" and site.source["units"]["length_unit_in_m"] == 1.0
    assert site.source["site_placement"] is not None and "true_north" in site.source
    assert site.ground_size >= 160


def test_duplex_level2_landmarks_match_raw_placements_and_profiles(duplex_l2):
    """Slab and stair-opening corners against the IFC's own profiles and placements, by hand."""
    f = ifcopenshell.open(str(DUPLEX))
    pieces = [s for s in f.by_type("IfcSlab") if (s.Name or "").startswith("Floor:Residential - Wood Joist")]
    assert len(pieces) == 2
    want_slab, want_open = [], []
    for piece in pieces:
        xy, z_top = _raw_slab_outline(f, piece.GlobalId)
        assert len(xy) == 8  # a rectangle with the stair notch drawn into it
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        box = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        on_box = np.linalg.norm(xy[:, None] - box[None], axis=-1).min(axis=1) < 1e-6
        assert on_box.sum() == 4
        want_slab += [(x, y, z_top) for x, y in box]
        want_open += [(x, y, z_top) for x, y in xy[~on_box]]  # the notch's four corners
    slab = duplex_l2.landmarks("slab_corners")
    opening = duplex_l2.landmarks("opening_corners")
    _same_points(slab.xyz, np.array(want_slab))
    _same_points(opening.xyz, np.array(want_open))
    assert abs(slab.xyz[:, 2] - 3.1).max() < 1e-3
    assert len(duplex_l2.landmarks("column_tops")) == 0
    assert all(h.source == "outline" for s in duplex_l2.floor for h in s.holes)


def test_duplex_roof_voids_and_level1_on_grade():
    roof = load_ifc(DUPLEX, stage="Roof/slab")
    (slab,) = roof.floor
    assert [h.source for h in slab.holes] == ["void", "void"]
    f = ifcopenshell.open(str(DUPLEX))
    voids = {r.RelatedOpeningElement.GlobalId for r in f.by_guid(slab.guid).HasOpenings}
    assert {h.guid for h in slab.holes} == voids
    assert len(roof.landmarks("slab_corners")) == 4 and len(roof.landmarks("opening_corners")) == 8
    # The slabs on grade are rendered without landmarks; at Level 2 the Level 1 walls stand, the
    # Level 2 walls do not.
    level2 = roof.with_stage("Level 2/slab")
    built = {e.guid for e in level2.built}
    on_grade = [e for e in roof.elements if e.kind == "slab" and e.storey == 1]
    assert len(on_grade) == 4 and all(not e.structural and e.guid in built for e in on_grade)
    walls = {k: {e.guid for e in roof.elements if e.kind == "wall" and e.storey == k} for k in (1, 2)}
    assert walls[1] and walls[1] <= built and walls[2] and not walls[2] & built


def test_duplex_ids_unique_stable_and_traceable(duplex_l2):
    ifc_module._parse_cached.cache_clear()
    again = load_ifc(DUPLEX, stage="Level 2/slab")
    f = ifcopenshell.open(str(DUPLEX))
    guids = {e.GlobalId for e in f.by_type("IfcRoot")}
    for name in ("all", *STRUCTURAL):
        a, b = duplex_l2.landmarks(name), again.landmarks(name)
        np.testing.assert_array_equal(a.ids, b.ids)
        assert a.elements == b.elements and a.labels == b.labels
        assert len(set(a.ids.tolist())) == len(a)
        for element in a.elements:
            assert set(element.split("#")[0].split("+")) <= guids
    every = [i for st in ifc_stages(DUPLEX) for i in load_ifc(DUPLEX, stage=st).landmarks("all").ids]
    assert len(set(every)) == len(every)  # no id reused across floors


def test_duplex_report_drops_finish_floors_and_skips_non_structural(duplex_l2):
    report = ifc_report(DUPLEX)
    assert report == duplex_l2.source["report"]
    finish = [d for d in report.dropped if "Finish Floor" in d[2]]
    assert len(finish) == 14 and all("finish floor" in d[3] for d in finish)
    skipped = {c: n for c, n, _ in report.skipped}
    assert skipped["IfcFurnishingElement"] == 61 and skipped["IfcDoor"] == 14
    assert skipped["IfcWindow"] == 24
    kept_slabs = [k for k in report.kept if k[1] == "IfcSlab"]
    assert len(kept_slabs) == 7
    text = report.summary()
    assert "dropped 14" in text and "finish floor" in text


def test_duplex_renders_with_its_floor_in_view(duplex_l2):
    from localization.geometry.transforms import look_at
    from uav_struct_env.sim.camera import Camera
    from uav_struct_env.sim.world import SiteWorld

    with SiteWorld(duplex_l2, renderer="tiny", image_size=(160, 90)) as world:
        c = duplex_l2.center
        pose = look_at(c + [-14.0, -16.0, 12.0 - c[2]], c)
        result = world.render(pose, Camera().scaled(160, 90), segmentation=True)
        floor = [world.body_ids[f"slab {s.name}"] for s in duplex_l2.floor]
        assert np.isin(result.segmentation, floor).mean() > 0.1


# ----------------------------------------------------------------------------- round trip
def _assert_same_landmarks(a: Site, b: Site) -> float:
    worst = 0.0
    for name in STRUCTURAL:
        la, lb = a.landmarks(name), b.landmarks(name)
        assert len(la) == len(lb), (a.stage, name)
        np.testing.assert_array_equal(la.ids, lb.ids)
        if len(la):
            worst = max(worst, float(np.abs(la.xyz - lb.xyz).max()))
    assert worst <= 1e-3
    return worst


@pytest.mark.parametrize("make", [lambda: paper_site("slab", None)] + [
    (lambda seed=seed: random_site(np.random.default_rng(seed), marker_size=None)) for seed in (1, 7, 23)
])
def test_round_trip_to_ifc_and_back(make, tmp_path):
    site = make()
    path = site.to_ifc(tmp_path / "site.ifc")
    assert ifcopenshell.open(str(path)).schema == "IFC4"
    assert ifc_stages(path) == [st.name for st in site.stages]
    for stage in ifc_stages(path):
        back = load_ifc(path, stage=stage)
        assert [s.name for s in back.storeys] == [s.name for s in site.storeys]
        _assert_same_landmarks(site.with_stage(stage), back)
    # The paper's two stages by their aliases.
    if site.name == "paper":
        for alias, stage in (("slab", "Level 1/slab"), ("columns", "Level 1/columns")):
            _assert_same_landmarks(site.with_stage(alias), load_ifc(path, stage=stage))
        assert [h.source for h in load_ifc(path).floor[0].holes] == ["void"]


def test_exporting_an_imported_site_keeps_its_landmarks(duplex_l2, tmp_path):
    path = duplex_l2.to_ifc(tmp_path / "duplex4.ifc")
    back = load_ifc(path, stage="Level 2/slab")
    for name in STRUCTURAL:
        _same_points(back.landmarks(name).xyz, duplex_l2.landmarks(name).xyz)


# ----------------------------------------------------------------------------- messy input, synthetic
@pytest.fixture(scope="module")
def messy_path(tmp_path_factory) -> Path:
    return messy_site().to_ifc(tmp_path_factory.mktemp("messy") / "messy.ifc")


def test_messy_file_decisions_are_reported(messy_path):
    report = ifc_report(messy_path)
    f = ifcopenshell.open(str(messy_path))
    by_tag = {e.Tag: e.GlobalId for e in f.by_type("IfcElement")}
    dropped = {g: why for g, _, _, why in report.dropped}
    assert "coincident duplicate" in dropped[by_tag["s1-copy"]]
    assert "finish floor 15 mm" in dropped[by_tag["fin"]]
    kept = {g: role for g, _, _, role in report.kept}
    assert "sloped" in kept[by_tag["roof"]]
    assert "one slab with 1 more piece" in kept[by_tag["pa"]]
    assert ifc_stages(messy_path) == ["L1/slab", "L1/columns", "L2/slab"]


def test_messy_file_landmarks(messy_path):
    f = ifcopenshell.open(str(messy_path))
    by_tag = {e.Tag: e.GlobalId for e in f.by_type("IfcElement")}
    l1 = load_ifc(messy_path, stage="L1/slab")
    assert len(l1.landmarks("slab_corners")) == 4 and len(l1.landmarks("column_tops")) == 0
    assert len(load_ifc(messy_path, stage="L1/columns").landmarks("column_tops")) == 4
    l2 = load_ifc(messy_path, stage="L2/slab")
    merged = next(s for s in l2.floor if "+" in s.guid)
    assert merged.guid == f"{by_tag['pa']}+{by_tag['pb']}"
    _same_points(merged.outline, rectangle(-.5, -.5, 8.5, 6.5))
    assert len(l2.floor) == 2  # the merged planks and the balcony
    assert len(l2.landmarks("slab_corners")) == 8
    # The upper columns' tops are covered by the L2 slab, the lower ones by L1: none exposed.
    assert len(l2.landmarks("column_tops")) == 0
    roof = next(e for e in l2.elements if e.guid == by_tag["roof"])
    assert isinstance(roof, Slab) and not roof.structural and roof.guid not in l2.current_stage.built


def test_notch_rule_fills_slots_but_keeps_l_shapes():
    slot = np.array([[0, 0], [10, 0], [10, 4], [9, 4], [9, 6], [10, 6], [10, 10], [0, 10]], float)
    outer, notches = ifc_module._fill_notches(slot)
    _same_points(outer, rectangle(0, 0, 10, 10))
    assert len(notches) == 1
    _same_points(notches[0], rectangle(9, 4, 10, 6))
    ell = np.array([[0, 0], [10, 0], [10, 5], [5, 5], [5, 10], [0, 10]], float)
    assert len(ifc_module._fill_notches(ell)[0]) == 6
    courtyard = np.array([[0, 0], [10, 0], [10, 2], [3, 2], [3, 8], [10, 8], [10, 10], [0, 10]], float)
    assert len(ifc_module._fill_notches(courtyard)[1]) == 0  # 42 % of the floor: part of the outline


def test_transform_moves_every_landmark(tmp_path):
    site = paper_site("columns", None)
    path = site.to_ifc(tmp_path / "paper.ifc")
    c, s = np.cos(0.3), np.sin(0.3)
    project_from_ifc = np.array([[c, -s, 0, 10], [s, c, 0, -5], [0, 0, 1, 2], [0, 0, 0, 1.0]])
    moved = load_ifc(path, stage="Level 1/columns", transform=project_from_ifc)
    want = site.landmarks("column_tops").xyz @ project_from_ifc[:3, :3].T + project_from_ifc[:3, 3]
    np.testing.assert_allclose(moved.landmarks("column_tops").xyz, want, atol=1e-6)
    assert moved.source["transform"] == project_from_ifc.tolist()
    assert moved.storeys[1].elevation == pytest.approx(3.5 + 2)
    with pytest.raises(ValueError, match="rigid"):
        load_ifc(path, transform=np.diag([2.0, 2.0, 2.0, 1.0]))


# ----------------------------------------------------------------------------- bad input
def test_missing_file():
    with pytest.raises(FileNotFoundError, match="nope.ifc"):
        load_ifc("nope.ifc")


def test_not_an_ifc_file(tmp_path):
    path = tmp_path / "site.ifc"
    path.write_text('{"elements": []}')
    with pytest.raises(IfcImportError, match="is not an IFC file"):
        load_ifc(path)


def test_ifc_without_slab_or_column(tmp_path):
    import ifcopenshell.api.root

    f = ifcopenshell.api.project.create_file(version="IFC4")
    ifcopenshell.api.root.create_entity(f, ifc_class="IfcProject", name="empty")
    ifcopenshell.api.root.create_entity(f, ifc_class="IfcWall", name="w")
    ifcopenshell.api.root.create_entity(f, ifc_class="IfcDoor", name="d")
    path = tmp_path / "walls.ifc"
    f.write(str(path))
    with pytest.raises(IfcImportError, match="no IfcSlab and no IfcColumn") as info:
        load_ifc(path)
    assert "IfcWall x1" in str(info.value) and "IfcDoor x1" in str(info.value)


def test_unknown_stage_lists_the_valid_ones():
    with pytest.raises(ConfigError, match=r"Level 2/slab.*Roof/slab.*got 'columns'"):
        load_ifc(DUPLEX, stage="columns")
    with pytest.raises(ConfigError, match="Level 2/slab"):
        make_site(str(DUPLEX), stage="Level 3/slab")


def test_too_few_landmarks_names_what_would_work(duplex_l2):
    assert len(check_landmarks(duplex_l2, "slab_corners")) == 8
    want = r"exposes 0 column_tops.*slab_corners.*stages with at least 4 column_tops: none"
    with pytest.raises(SiteGeometryError, match=want):
        check_landmarks(duplex_l2, "column_tops")


def test_without_ifcopenshell_the_error_names_the_extra(monkeypatch):
    for name in [m for m in sys.modules if m == "ifcopenshell" or m.startswith("ifcopenshell.")]:
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(ImportError, match=r"pip install 'uav-struct-env\[ifc\]'"):
        load_ifc(DUPLEX)
    with pytest.raises(ImportError, match=r"\[ifc\]"):
        paper_site().to_ifc("never.ifc")


def test_georeference_is_recorded_not_applied(tmp_path):
    site = paper_site("slab", None)
    f = ifcopenshell.open(str(site.to_ifc(tmp_path / "plain.ifc")))
    context = next(c for c in f.by_type("IfcGeometricRepresentationContext", include_subtypes=False)
                   if c.ContextType == "Model")
    context.TrueNorth = f.createIfcDirection((-0.5, 0.8660254))  # north 30 deg counter-clockwise of +y
    crs = f.createIfcProjectedCRS("EPSG:25832", None, None, None, None, None, None)
    f.createIfcMapConversion(context, crs, 500000.0, 5400000.0, 120.0, 1.0, 0.0, 1.0)
    path = tmp_path / "geo.ifc"
    f.write(str(path))
    geo = load_ifc(path, stage="Level 1/slab")
    mc = geo.source["map_conversion"]
    assert mc["eastings"] == 500000.0 and mc["northings"] == 5400000.0 and mc["target_crs"] == "EPSG:25832"
    assert geo.source["true_north"]["direction"] == pytest.approx((-0.5, 0.8660254))
    assert geo.source["true_north"]["angle_from_y_deg"] == pytest.approx(30.0)
    want = site.landmarks("slab_corners").xyz
    np.testing.assert_allclose(geo.landmarks("slab_corners").xyz, want, atol=1e-6)
