"""Site files: a :class:`~uav_struct_env.site.Site` as JSON, to describe any building by hand.

Example (the paper's building without markers)::

    {"building": {"grid": {"spans_x": [4, 4], "spans_y": [4, 3, 4]},
                  "storey_heights": [3.5, 3.5], "column_section": [0.35, 0.35],
                  "slab_thickness": 0.25, "slab_overhang": 0.3,
                  "openings": [{"name": "stair", "center": [2.0, 5.5], "size": [3.6, 2.6]}]},
     "stage": "columns",
     "markers": [{"id": 0, "side": 1.0, "center": [2.0, -3.3, 0.01]}]}

Every value is validated by the dataclasses themselves, so a file describing impossible geometry
raises the same :class:`~uav_struct_env.errors.SiteGeometryError` as code would, naming the field:
every number finite and within the physical bounds of :mod:`uav_struct_env.site.parametric`
(``MAX_SPAN``, ``MAX_STOREY_HEIGHT``, ...), every field of the right type and length, and sizes
that would take long to build (``MAX_COLUMNS``, ``MAX_OPENINGS``) refused before anything is built.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.markers import ARUCO_DICTIONARY_SIZES, ArucoMarker
from uav_struct_env.site.model import Site
from uav_struct_env.site.parametric import MAX_OPENINGS, Building, ColumnGrid, Opening, building_site

__all__ = ["load_site", "save_site", "site_from_dict", "site_to_dict"]


_SITE_KEYS = ("building", "stage", "markers", "ground_size", "name")
#: Markers have unique ids in one dictionary: never more than the largest dictionary holds.
MAX_MARKERS = max(ARUCO_DICTIONARY_SIZES.values())


def site_to_dict(site: Site) -> dict[str, Any]:
    """A JSON-ready dict of a parametric ``site`` (inverse of :func:`site_from_dict`).

    Raises:
        SiteGeometryError: if the site was not made from a parametric building (an imported IFC
            site is saved as IFC: ``site.to_ifc(path)``).
    """
    if site.building is None:
        raise SiteGeometryError(
            f"site {site.name!r} has no parametric building to save as a site file; "
            "write it as IFC with site.to_ifc(path)"
        )
    data = {
        "building": dataclasses.asdict(site.building),
        "stage": site.stage,
        "markers": [dataclasses.asdict(m) for m in site.markers],
        "ground_size": site.ground_size,
        "name": site.name,
    }
    return json.loads(json.dumps(data))


def _build(cls, data: Any, where: str, **nested):
    if not isinstance(data, dict):
        raise SiteGeometryError(f"{where} must be a JSON object, got {data!r}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise SiteGeometryError(
            f"{where} has unknown keys {unknown}; expected some of {sorted(names)}"
        )
    kwargs = {}
    for key, value in data.items():
        if key in nested:
            kwargs[key] = nested[key](value, f"{where}.{key}")
        elif isinstance(value, list):
            kwargs[key] = tuple(value)
        else:
            kwargs[key] = value
    try:
        return cls(**kwargs)
    except TypeError as err:
        raise SiteGeometryError(f"{where}: {err}") from None


def _list(value: Any, where: str, limit: int) -> list:
    if not isinstance(value, list):
        raise SiteGeometryError(f"{where} must be a JSON list, got {value!r}"[:300])
    if len(value) > limit:
        raise SiteGeometryError(f"{where} has {len(value)} entries, more than the {limit} supported")
    return value


def site_from_dict(data: dict[str, Any]) -> Site:
    """Build a :class:`Site` from a dict as written by :func:`site_to_dict`.

    Raises:
        SiteGeometryError: on unknown keys, missing keys or impossible geometry.
    """

    def grid(v, where):
        return _build(ColumnGrid, v, where)

    def openings(v, where):
        return tuple(_build(Opening, o, f"{where}[{i}]") for i, o in enumerate(_list(v, where, MAX_OPENINGS)))

    def markers(v, where):
        items = _list(v, where, MAX_MARKERS)
        return tuple(_build(ArucoMarker, m, f"{where}[{i}]") for i, m in enumerate(items))

    def building(v, where):
        return _build(Building, v, where, grid=grid, openings=openings)

    if not isinstance(data, dict):
        raise SiteGeometryError(f"site must be a JSON object, got {data!r}")
    unknown = sorted(set(data) - set(_SITE_KEYS))
    if unknown:
        raise SiteGeometryError(f"site has unknown keys {unknown}; expected some of {sorted(_SITE_KEYS)}")
    if "building" not in data:
        raise SiteGeometryError("site needs a 'building' entry")
    kwargs = {k: v for k, v in data.items() if k not in ("building", "markers")}
    return building_site(
        building(data["building"], "site.building"), markers=markers(data.get("markers", []), "site.markers"),
        **kwargs,
    )


def load_site(path: str | Path) -> Site:
    """Read a site file (JSON)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"site file {str(path)!r} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise SiteGeometryError(f"site file {str(path)!r} is not valid JSON: {err}") from None
    except RecursionError:
        raise SiteGeometryError(f"site file {str(path)!r} is nested too deeply to be a site") from None
    return site_from_dict(data)


def save_site(site: Site, path: str | Path) -> None:
    """Write ``site`` as a site file (JSON)."""
    Path(path).write_text(json.dumps(site_to_dict(site), indent=2) + "\n")
