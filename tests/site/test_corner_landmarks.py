"""Corner landmarks are the outline vertices where it turns by at least MIN_CORNER_TURN_DEG.

A kink in one edge or the polygon an exporter makes of a curved edge is no corner a detector can
place; the paper site, random sites and the train buildings (all 90 deg corners) keep every vertex.
"""

from __future__ import annotations

import numpy as np
import pytest

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site import paper_site
from uav_struct_env.site.elements import Hole, Slab, Stage, Storey
from uav_struct_env.site.landmarks import MIN_CORNER_TURN_DEG, check_landmarks, corner_vertices
from uav_struct_env.site.model import Site
from uav_struct_env.site.polygons import rectangle


def _arc(cx, cy, r, a0, a1, n):
    a = np.radians(np.linspace(a0, a1, n + 1))
    return np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], axis=1)


def _stadium(length=12.0, r=3.0, n=16):
    """A slab with straight sides and round ends, each end a polygon of ``n`` segments."""
    right = _arc(length / 2, 0.0, r, -90, 90, n)
    left = _arc(-length / 2, 0.0, r, 90, 270, n)
    return np.concatenate([right, left])


def _site(outline, holes=()) -> Site:
    slab = Slab(guid="s", name="deck", storey=0, outline=outline, z_bottom=3.0, z_top=3.3, holes=holes)
    stage = Stage("deck/slab", frozenset({"s"}), ("s",))
    return Site(elements=(slab,), storeys=(Storey("deck", 0.0),), stages=(stage,), stage="deck/slab",
                name="curved")


def test_turns_below_the_threshold_are_no_corners():
    square = rectangle(0, 0, 4, 3)
    assert corner_vertices(square) == [0, 1, 2, 3]
    # an octagon turns by 45 deg at each vertex, a 36-gon by 10
    assert len(corner_vertices(_arc(0, 0, 2, 0, 315, 7))) == 8
    assert corner_vertices(_arc(0, 0, 2, 0, 350, 35)) == []
    # a kink of 10 deg in the long edge of a rectangle, and a notch whose corners turn by 90
    kinked = np.array([[0, 0], [5, 0], [10, 0.88], [10, 4], [0, 4]])
    assert corner_vertices(kinked) == [0, 2, 3, 4]
    notch = np.array([[0, 0], [4, 0], [4, 1], [3, 1], [3, 2], [4, 2], [4, 4], [0, 4]])
    assert len(corner_vertices(notch)) == 8  # re-entrant corners turn the other way by 90 deg
    # exactly at the threshold: a corner
    t = np.radians(MIN_CORNER_TURN_DEG)
    assert 1 in corner_vertices(np.array([[0, 0], [5, 0], [5 + 5 * np.cos(t), 5 * np.sin(t)], [0, 6]]))


def test_a_stadium_slab_has_no_slab_corners_and_its_round_opening_none_either():
    ring = Hole("light well", _arc(0.0, 0.0, 1.0, 0, 345, 23))
    square = Hole("stair", rectangle(3.0, -1.0, 5.0, 1.0))
    site = _site(_stadium(), holes=(ring, square))
    assert len(site.current_stage.floor) == 1 and len(site.slabs[0].outline) == 34
    assert len(site.landmarks("slab_corners")) == 0
    openings = site.landmarks("opening_corners")
    assert len(openings) == 4 and all(label.startswith("stair corner") for label in openings.labels)
    np.testing.assert_allclose(np.sort(openings.xyz[:, 0]), [3, 3, 5, 5])
    with pytest.raises(SiteGeometryError, match="slab_corners"):
        check_landmarks(site, "slab_corners")


def test_a_rounded_corner_keeps_none_of_its_vertices_and_the_square_corners_keep_their_ids():
    # a rectangle whose one corner is a fillet of 6 segments (15 deg each)
    fillet = _arc(8.0, 4.0, 2.0, 0, 90, 6)
    outline = np.concatenate([[[0.0, 0.0], [10.0, 0.0]], fillet, [[0.0, 6.0]]])
    site = _site(outline)
    corners = site.landmarks("slab_corners")
    np.testing.assert_allclose(corners.xyz[:, :2], [[0, 0], [10, 0], [0, 6]])
    assert corners.labels == ("deck corner 0", "deck corner 1", "deck corner 9")


def test_the_paper_site_keeps_every_vertex():
    site = paper_site("slab")
    assert len(site.landmarks("slab_corners")) == len(site.slabs[0].outline) == 4
