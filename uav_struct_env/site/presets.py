"""Named site presets and a seeded generator of random plausible layouts.

* :func:`paper_site` — the building of the paper's study: a 3 x 4 column grid, spans 4 m one way
  and 4, 3, 4 m the other, a first-floor slab with a 2.6 m x 3.6 m stair opening in the middle
  bay, eight DICT_4X4_50 markers 3 m outside the slab edge, two per side.
* :func:`random_site` — domain randomization: grid size, spans, storey heights, column section,
  opening size and position, marker layout, all drawn from a ``numpy.random.Generator``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from uav_struct_env.errors import ConfigError
from uav_struct_env.site.markers import ArucoMarker
from uav_struct_env.site.model import Site
from uav_struct_env.site.parametric import Building, ColumnGrid, Opening, building_site

__all__ = ["PRESETS", "make_site", "markers_around", "paper_building", "paper_site", "random_site"]


def paper_building() -> Building:
    """The paper's reinforced-concrete frame (see the module docstring)."""
    return Building(
        grid=ColumnGrid(spans_x=(4.0, 4.0), spans_y=(4.0, 3.0, 4.0)),
        storey_heights=(3.5, 3.5),
        column_section=(0.35, 0.35),
        slab_thickness=0.25,
        slab_overhang=0.3,
        # 3.6 m along x, 2.6 m along y, centred in the middle (3 m) bay of the first x bay.
        openings=(Opening("stair", center=(2.0, 5.5), size=(3.6, 2.6)),),
    )


def markers_around(
    building: Building | Site,
    side: float,
    distance: float = 3.0,
    per_side: int = 2,
    first_id: int = 0,
    dictionary: str = "DICT_4X4_50",
) -> tuple[ArucoMarker, ...]:
    """``per_side`` markers on the ground ``distance`` m outside each footprint edge, evenly spaced.

    ``building`` is a parametric :class:`Building` (its slab outline) or any :class:`Site` (the
    bounding box of its footprint). Order: south (y min), north (y max), west (x min), east
    (x max); ids count up from ``first_id``.
    """
    xmin, ymin, xmax, ymax = (
        building.footprint_bounds if isinstance(building, Site) else building.slab_bounds
    )
    fractions = (np.arange(per_side) + 0.5) / per_side
    centres: list[tuple[float, float]] = []
    for y in (ymin - distance, ymax + distance):
        centres += [(xmin + f * (xmax - xmin), y) for f in fractions]
    for x in (xmin - distance, xmax + distance):
        centres += [(x, ymin + f * (ymax - ymin)) for f in fractions]
    return tuple(
        ArucoMarker(id=first_id + k, side=side, center=(cx, cy, 0.01), dictionary=dictionary)
        for k, (cx, cy) in enumerate(centres)
    )


def paper_site(stage: str = "columns", marker_size: float | None = 1.0) -> Site:
    """The paper's site at ``stage`` with markers of side ``marker_size`` m (None: no markers)."""
    building = paper_building()
    markers: tuple[ArucoMarker, ...] = ()
    if marker_size is not None:
        markers = tuple(
            ArucoMarker(id=k, side=marker_size, center=(x, y, 0.01))
            for k, (x, y) in enumerate(_PAPER_MARKER_CENTRES)
        )
    return building_site(building, stage=stage, markers=markers, name="paper")


# Two per side, 3 m outside the slab edge (slab: x -0.3..8.3, y -0.3..11.3): S, N, W, E.
_PAPER_MARKER_CENTRES = (
    (2.0, -3.3),
    (6.0, -3.3),
    (2.0, 14.3),
    (6.0, 14.3),
    (-3.3, 3.0),
    (-3.3, 8.0),
    (11.3, 3.0),
    (11.3, 8.0),
)


def random_site(rng: np.random.Generator, stage: str | None = None, marker_size: float | None = 1.0) -> Site:
    """A random plausible site for domain randomization.

    Draws 2-4 x 2-5 columns, spans 3-6.5 m, storey heights 3-4 m, square column sections
    0.3-0.5 m, a stair opening in a random bay (where one fits) and markers 2-4 m outside the
    slab. ``stage=None`` draws the stage too.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    nx, ny = int(rng.integers(2, 5)), int(rng.integers(2, 6))
    spans_x = tuple(np.round(rng.uniform(3.0, 6.5, nx - 1), 2))
    spans_y = tuple(np.round(rng.uniform(3.0, 6.5, ny - 1), 2))
    grid = ColumnGrid(spans_x, spans_y)
    section = float(np.round(rng.uniform(0.3, 0.5), 2))
    heights = tuple(np.round(rng.uniform(3.0, 4.0, 2), 2))
    # Opening inside one bay, clear of the columns by at least 0.1 m.
    bx, by = int(rng.integers(0, nx - 1)), int(rng.integers(0, ny - 1))
    x0, y0 = grid.xs[bx], grid.ys[by]
    room_x = spans_x[bx] - section - 0.2
    room_y = spans_y[by] - section - 0.2
    sx = float(np.round(rng.uniform(0.5, 1.0) * room_x, 2))
    sy = float(np.round(rng.uniform(0.5, 1.0) * room_y, 2))
    cx = x0 + spans_x[bx] / 2 + rng.uniform(-1, 1) * (room_x - sx) / 2
    cy = y0 + spans_y[by] / 2 + rng.uniform(-1, 1) * (room_y - sy) / 2
    building = Building(
        grid=grid,
        storey_heights=heights,
        column_section=(section, section),
        slab_thickness=float(np.round(rng.uniform(0.2, 0.3), 2)),
        slab_overhang=float(np.round(section / 2 + rng.uniform(0.05, 0.4), 2)),
        openings=(Opening("stair", center=(float(cx), float(cy)), size=(sx, sy)),),
    )
    if stage is None:
        stage = str(rng.choice(["slab", "columns"]))
    markers = (
        ()
        if marker_size is None
        else markers_around(building, marker_size, distance=float(rng.uniform(2.0, 4.0)))
    )
    return building_site(building, stage=stage, markers=markers, name="random")


PRESETS = {"paper": paper_site}


def make_site(
    site: str | Site = "paper",
    stage: str | None = None,
    marker_size: float | None = 1.0,
    rng: np.random.Generator | None = None,
) -> Site:
    """Resolve a site argument at ``stage``.

    ``site`` is a :class:`Site`, a preset name, ``"random"`` (needs ``rng``), the path of a
    site file (``*.json``, see :mod:`uav_struct_env.site.io`) or of an IFC file (``*.ifc``,
    :func:`~uav_struct_env.site.ifc.load_ifc`). ``stage`` None keeps a Site's (or site file's)
    own stage; for a preset it means ``"columns"``; an IFC file needs one.

    For a :class:`Site` or a site file, ``marker_size`` resizes its markers (a site without
    markers gets two per side 3 m out); None removes them.
    """
    if isinstance(site, str) and site.lower().endswith(".ifc"):
        from uav_struct_env.site.ifc import load_ifc

        site = load_ifc(site, stage=stage)
    elif isinstance(site, str) and (site.endswith(".json") or Path(site).is_file()):
        from uav_struct_env.site.io import load_site

        site = load_site(site)
    if isinstance(site, Site):
        stage = site.stage if stage is None else stage
        if marker_size is None:
            markers: tuple[ArucoMarker, ...] = ()
        elif site.markers:
            markers = tuple(dataclasses.replace(m, side=marker_size) for m in site.markers)
        else:
            markers = markers_around(site, marker_size)
        if markers == site.markers and site.stage == stage:
            return site
        return dataclasses.replace(site, stage=stage, markers=markers)
    stage = "columns" if stage is None else stage
    if site == "random":
        if rng is None:
            raise ConfigError("site='random' needs a numpy.random.Generator (rng)")
        return random_site(rng, stage=stage, marker_size=marker_size)
    if site not in PRESETS:
        raise ConfigError(
            f"site must be a Site, 'random', a site file (*.json) or one of {sorted(PRESETS)}, got {site!r}"
        )
    return PRESETS[site](stage=stage, marker_size=marker_size)
