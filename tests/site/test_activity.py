"""Site activity as plain data (site/activity.py): presets, seeded layouts, placement rules, motion."""

from pathlib import Path

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.sim.uav import Obstacles
from uav_struct_env.site import load_ifc, paper_site, random_site
from uav_struct_env.site.activity import (
    ACTIVITY_PRESETS,
    EQUIPMENT_KINDS,
    MAX_EQUIPMENT_HEIGHT,
    WORKER_HEIGHT,
    Activity,
    SiteActivity,
    make_activity,
)

DUPLEX = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"


def _sites():
    return {
        "paper slab": paper_site("slab"),
        "paper columns": paper_site("columns"),
        "random": random_site(np.random.default_rng(11), stage="columns"),
        "duplex": load_ifc(DUPLEX),
    }


SITES = _sites()


def _signature(layout: SiteActivity) -> list:
    out = [(b.name, b.world_from_box.tobytes(), b.half_extents.tobytes()) for b in layout.static]
    out += [(w.name, w.waypoints.tobytes(), w.speed, w.phase) for w in layout.workers]
    return out


def test_presets_and_config_errors():
    assert make_activity("none").is_none and not make_activity("busy").is_none
    assert make_activity(ACTIVITY_PRESETS["light"]) is ACTIVITY_PRESETS["light"]
    assert set(ACTIVITY_PRESETS["busy"].equipment) == set(EQUIPMENT_KINDS)
    with pytest.raises(ConfigError, match=r"activity must be one of \['busy', 'light', 'none'\].*'crowded'"):
        make_activity("crowded")
    with pytest.raises(ConfigError, match=r"equipment must be drawn from .*\['tower_crane'\]"):
        Activity(equipment=("truck", "tower_crane"))
    with pytest.raises(ConfigError, match="slab_workers"):
        Activity(slab_workers=-1)
    with pytest.raises(ConfigError, match=r"walking_speed\[1\]"):
        Activity(walking_speed=(1.5, 1.0))


@pytest.mark.parametrize("name", list(SITES))
def test_same_seed_same_layout_and_other_seed_another(name):
    site = SITES[name]
    a, b = SiteActivity(site, "busy", 3), SiteActivity(site, "busy", 3)
    assert _signature(a) == _signature(b)
    for t in (0.0, 7.5, 123.25):
        pa, pb = a.worker_points(t), b.worker_points(t)
        assert all(np.array_equal(pa[k], pb[k]) for k in pa)
    assert _signature(SiteActivity(site, "busy", 4)) != _signature(a)
    assert SiteActivity(site, "none", 3).static == () and SiteActivity(site, "none", 3).workers == ()


@pytest.mark.parametrize("name", list(SITES))
def test_busy_layout_places_every_category_by_the_rules(name):
    site = SITES[name]
    layout = SiteActivity(site, "busy", 5)
    kinds = {b.kind for b in layout.static}
    assert set(EQUIPMENT_KINDS) <= kinds, f"equipment missing on {name}: {kinds}"
    assert kinds & {"rebar", "formwork_panels", "pallet"}
    longest = max(np.linalg.norm(np.diff(np.vstack([f.outline, f.outline[:1]]), axis=0), axis=1).max()
                  for f in site.floor)
    # a run needs 2 m between the corner clearances (2 m each): none on a small slab
    assert ("scaffold" in kinds) == (longest >= 2 * layout.activity.landmark_clearance + 2.0), longest
    assert len(layout.workers) >= 12
    assert {w.surface for w in layout.workers} == {"slab", "ground"}
    # equipment stays low (under the schedule's 10 m lowest viewpoint) and outside the building
    building = Obstacles.from_site(site)
    for b in layout.static:
        lo, hi = b.aabb
        if b.kind in EQUIPMENT_KINDS:
            assert hi[2] <= MAX_EQUIPMENT_HEIGHT + 1e-9, b.name
            assert lo[2] >= -1e-9, b.name
            assert building.distances(b.corners).min() > 1.0, b.name
    # materials and equipment keep the clearance from the landmarks they could hide
    clearance = layout.activity.landmark_clearance
    low = np.concatenate([site.landmarks(n).xyz for n in ("slab_corners", "opening_corners")])
    for b in layout.static:
        if b.kind in ("rebar", "formwork_panels", "pallet") or b.kind in EQUIPMENT_KINDS:
            near = np.abs(low[:, 2] - b.aabb[0][2]) < 2.0
            if near.any():
                d = np.linalg.norm(low[near, None, :2] - b.corners[None, :, :2], axis=2).min()
                assert d >= clearance - 0.75, (b.name, d)  # corners vs. rectangle: within a box half


@pytest.mark.parametrize("name", list(SITES))
def test_workers_walk_on_their_surface_at_walking_speed(name):
    site = SITES[name]
    layout = SiteActivity(site, "busy", 8)
    floor_tops = {round(s.z_top, 6) for s in site.floor}
    times = np.arange(0.0, 60.0, 0.5)
    for w in layout.workers:
        feet = np.array([w.points_at(t)[0] for t in times])
        head = np.array([w.points_at(t)[1] for t in times])
        np.testing.assert_allclose(head - feet, [[0, 0, WORKER_HEIGHT]] * len(times))
        speed = np.linalg.norm(np.diff(feet[:, :2], axis=0), axis=1) / 0.5
        assert speed.max() <= w.speed + 1e-9
        assert 0.8 <= w.speed <= 1.4
        if w.surface == "slab":
            assert round(w.z, 6) in floor_tops
            slab = next(s for s in site.floor if abs(s.z_top - w.z) < 1e-6 and s.covers(feet[:1, :2])[0])
            assert slab.covers(feet[:, :2]).all(), f"{w.name} left its slab"
            for c in site.columns:
                if c.z_top > w.z + 0.1 and c.z_bottom < w.z + 0.1:  # columns standing on the floor
                    xmin, ymin, xmax, ymax = c.bounds
                    inside = ((feet[:, 0] > xmin - 0.25) & (feet[:, 0] < xmax + 0.25)
                              & (feet[:, 1] > ymin - 0.25) & (feet[:, 1] < ymax + 0.25))
                    assert not inside.any(), f"{w.name} walks through {c.name}"
        else:
            assert w.z == 0.0
            assert Obstacles.from_site(site).distances(np.c_[feet[:, :2], feet[:, 2] + 0.5]).min() > 0.5
    moving = [w for w in layout.workers if len(w.waypoints) > 1]
    assert len(moving) >= len(layout.workers) - 2
    w = moving[0]
    assert not np.array_equal(w.points_at(0.0), w.points_at(2.0))


def test_scaffold_and_formwork_follow_the_elements():
    site = paper_site("columns")
    layout = SiteActivity(site, "busy", 1)
    scaffold = [b for b in layout.static if b.kind == "scaffold"]
    assert scaffold, "no scaffold on the paper site"
    slab = site.floor[0]
    # every scaffold part stands outside the floor slab, at most slab top + 1 m high
    for b in scaffold:
        assert not slab.covers(b.corners[:, :2]).any(), b.name
        assert b.aabb[1][2] <= slab.z_top + 1.0 + 0.03
    formwork = [b for b in layout.static if b.kind == "formwork"]
    exposed = {c.name: c for c in site.exposed_columns}
    assert len(formwork) == round(0.5 * len(exposed))
    for b in formwork:
        column = exposed[b.name.removeprefix("formwork ")]
        assert b.aabb[1][2] < column.z_top - 1.0  # the column top (a landmark) stays free
