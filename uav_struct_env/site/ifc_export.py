"""IFC export: a building's storeys and elements as an IFC4 file (``Site.to_ifc``, ``write_ifc``).

IFC4 through ``ifcopenshell.api``, in metres: project, site, building, one IfcBuildingStorey per
storey (name, elevation), each element contained in its storey, placed at its bottom. An element
without a mesh is an extruded IfcArbitraryClosedProfileDef of its outline; a slab's openings are
IfcOpeningElement voids extruded through it. An element with its own mesh (an imported one) is an
IfcTriangulatedFaceSet (its openings are already cut). GlobalIds are derived from the site name
and element guid (the same site writes the same ids); the element guid goes into ``Tag``.
Markers are not written (they are not building elements). ``map_conversion`` (optional) writes
IfcMapConversion with its IfcProjectedCRS (IFC4 georeferencing, metres; see
:mod:`uav_struct_env.photos.georef`).

The writer reads the plain data only (elements, storeys), so it sits below the
:class:`~uav_struct_env.site.Site` that calls it; the importer
(:mod:`uav_struct_env.site.ifc`) sits above. ifcopenshell (the optional extra ``ifc``:
``pip install 'uav-struct-env[ifc]'``) is imported inside the functions, so the rest of the
package works without it.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.site.elements import Element, Hole, Slab, Storey

__all__ = ["INSTALL_HINT", "IFC_CLASSES", "require_ifcopenshell", "write_building"]

INSTALL_HINT = "pip install 'uav-struct-env[ifc]'"

#: The IFC class each element kind is written as.
IFC_CLASSES = {"column": "IfcColumn", "slab": "IfcSlab", "beam": "IfcBeam", "wall": "IfcWall"}

_GUID_NAMESPACE = uuid.UUID("6f1b7a52-3c1e-4f0e-9a55-2b8c8a4d7e10")
_API_MODULES = ("aggregate", "context", "feature", "geometry", "root", "spatial", "unit")


def require_ifcopenshell() -> Any:
    """The ifcopenshell module (with geom and util), or an ImportError naming the extra."""
    try:
        import ifcopenshell
        import ifcopenshell.geom
        import ifcopenshell.util.element
        import ifcopenshell.util.placement
        import ifcopenshell.util.unit
    except ImportError as exc:
        raise ImportError(
            f"IFC import/export needs ifcopenshell, which is not installed ({exc}); "
            f"install the 'ifc' extra: {INSTALL_HINT}"
        ) from exc
    return ifcopenshell


def _api(usecase: str, *args: Any, **kwargs: Any) -> Any:
    """Run the ``ifcopenshell.api`` use case ``"<module>.<name>"``."""
    import ifcopenshell.api

    module, name = usecase.split(".")
    return getattr(getattr(ifcopenshell.api, module), name)(*args, **kwargs)


def _global_id(site_name: str, key: str) -> str:
    """The GlobalId of ``key`` in the site ``site_name``: the same site writes the same ids."""
    import ifcopenshell.guid

    return ifcopenshell.guid.compress(uuid.uuid5(_GUID_NAMESPACE, f"{site_name}/{key}").hex)


def _translation(x: float, y: float, z: float) -> NDArray[np.float64]:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _extrusion(f: Any, outline: NDArray[np.float64], z0: float, depth: float) -> Any:
    """An IfcExtrudedAreaSolid of a plan ``outline`` from ``z0`` up by ``depth`` (local frame)."""
    pts = [f.createIfcCartesianPoint((float(x), float(y))) for x, y in outline]
    profile = f.createIfcArbitraryClosedProfileDef("AREA", None, f.createIfcPolyline([*pts, pts[0]]))
    position = f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, float(z0))), None, None)
    up = f.createIfcDirection((0.0, 0.0, 1.0))
    return f.createIfcExtrudedAreaSolid(profile, position, up, float(depth))


def _face_set(f: Any, vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> Any:
    """An IfcTriangulatedFaceSet (IFC4) of a triangle mesh, vertices deduplicated."""
    v, inverse = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    fc = inverse.reshape(-1)[faces]
    fc = fc[(fc[:, 0] != fc[:, 1]) & (fc[:, 1] != fc[:, 2]) & (fc[:, 0] != fc[:, 2])]
    points = f.createIfcCartesianPointList3D([tuple(map(float, p)) for p in v])
    indices = [tuple(int(i) + 1 for i in t) for t in fc]  # 1-based
    return f.createIfcTriangulatedFaceSet(points, None, None, indices, None)


def _project(f: Any, name: str) -> tuple[Any, Any]:
    """Project (metres), site and building of ``f``: the Body context and the IfcBuilding."""
    project = _api("root.create_entity", f, ifc_class="IfcProject", name=name)
    project.GlobalId = _global_id(name, "project")
    metre = _api("unit.add_si_unit", f, unit_type="LENGTHUNIT")
    _api("unit.assign_unit", f, units=[metre])
    model = _api("context.add_context", f, context_type="Model")
    body = _api("context.add_context", f, context_type="Model", context_identifier="Body",
                target_view="MODEL_VIEW", parent=model)
    ifc_site = _api("root.create_entity", f, ifc_class="IfcSite", name=name)
    ifc_site.GlobalId = _global_id(name, "site")
    building = _api("root.create_entity", f, ifc_class="IfcBuilding", name=name)
    building.GlobalId = _global_id(name, "building")
    _api("aggregate.assign_object", f, products=[ifc_site], relating_object=project)
    _api("aggregate.assign_object", f, products=[building], relating_object=ifc_site)
    for product in (ifc_site, building):
        _api("geometry.edit_object_placement", f, product=product, matrix=np.eye(4))
    return body, building


def _storeys(f: Any, name: str, storeys: Sequence[Storey], building: Any) -> list[Any]:
    """One IfcBuildingStorey per storey (name, elevation), aggregated in ``building``."""
    out = []
    for k, st in enumerate(storeys):
        s = _api("root.create_entity", f, ifc_class="IfcBuildingStorey", name=st.name)
        s.GlobalId = _global_id(name, f"storey {k}")
        s.Elevation = float(st.elevation)
        _api("aggregate.assign_object", f, products=[s], relating_object=building)
        _api("geometry.edit_object_placement", f, product=s, matrix=_translation(0.0, 0.0, st.elevation))
        out.append(s)
    return out


def _element(f: Any, name: str, e: Element, body: Any, storeys: list[Any]) -> Any:
    """The IFC product of ``e`` in its storey, placed at its bottom, with its body geometry."""
    product = _api("root.create_entity", f, ifc_class=IFC_CLASSES[e.kind], name=e.name,
                   predefined_type=("FLOOR" if getattr(e, "structural", True) else "NOTDEFINED")
                   if e.kind == "slab" else None)
    product.GlobalId = _global_id(name, e.guid)
    product.Tag = e.guid
    if storeys:
        _api("spatial.assign_container", f, products=[product],
             relating_structure=storeys[min(e.storey, len(storeys) - 1)])
    _api("geometry.edit_object_placement", f, product=product, matrix=_translation(0.0, 0.0, e.z_bottom))
    if e.mesh is not None:
        item = _face_set(f, e.mesh.vertices - [0.0, 0.0, e.z_bottom], e.mesh.faces)
        rep_type = "Tessellation"
    else:
        item = _extrusion(f, e.outline, 0.0, e.z_top - e.z_bottom)
        rep_type = "SweptSolid"
    rep = f.createIfcShapeRepresentation(body, "Body", rep_type, [item])
    _api("geometry.assign_representation", f, product=product, representation=rep)
    return product


def _opening(f: Any, name: str, slab: Slab, hole: Hole, body: Any, product: Any) -> None:
    """An IfcOpeningElement voiding ``product`` (the slab's): ``hole`` extruded through it."""
    op = _api("root.create_entity", f, ifc_class="IfcOpeningElement", name=hole.name)
    op.GlobalId = _global_id(name, f"{slab.guid}/{hole.guid}")
    op.Tag = hole.guid
    _api("geometry.edit_object_placement", f, product=op,
         matrix=_translation(0.0, 0.0, slab.z_bottom - 0.1))
    rep = f.createIfcShapeRepresentation(
        body, "Body", "SweptSolid", [_extrusion(f, hole.outline, 0.0, slab.thickness + 0.2)])
    _api("geometry.assign_representation", f, product=op, representation=rep)
    _api("feature.add_feature", f, feature=op, element=product)


def _map_conversion(f: Any, fields: Mapping[str, Any]) -> None:
    """IfcMapConversion from the model context to an IfcProjectedCRS (map unit: metre)."""
    context = f.by_type("IfcGeometricRepresentationContext", include_subtypes=False)[0]
    metre = f.createIfcSIUnit(None, "LENGTHUNIT", None, "METRE")
    crs = f.createIfcProjectedCRS(str(fields["crs"]), None, "WGS84", None, None, None, metre)
    f.createIfcMapConversion(
        context, crs, float(fields["eastings"]), float(fields["northings"]),
        float(fields["orthogonal_height"]), float(fields.get("x_axis_abscissa", 1.0)),
        float(fields.get("x_axis_ordinate", 0.0)), float(fields.get("scale", 1.0)))


def write_building(
    name: str, storeys: Sequence[Storey], elements: Sequence[Element], path: str | os.PathLike,
    map_conversion: Mapping[str, Any] | None = None,
) -> Path:
    """Write a building (its storeys and every element) as IFC4 in metres; returns the path.

    ``name`` names the project, site and building and seeds the GlobalIds (see the module
    docstring). ``map_conversion``: None, or the georeferencing to write: ``crs`` (a projected
    CRS name, ``"EPSG:32632"``), ``eastings``, ``northings``, ``orthogonal_height`` (metres),
    ``x_axis_abscissa``, ``x_axis_ordinate`` (default 1, 0) and ``scale`` (default 1).

    Raises:
        ImportError: if ifcopenshell is not installed (names the ``ifc`` extra).
    """
    require_ifcopenshell()
    import ifcopenshell.api
    import ifcopenshell.api.project

    for module in _API_MODULES:
        __import__(f"ifcopenshell.api.{module}")
    f = ifcopenshell.api.project.create_file(version="IFC4")
    body, building = _project(f, name)
    containers = _storeys(f, name, storeys, building)
    if map_conversion is not None:
        _map_conversion(f, map_conversion)
    for e in elements:
        product = _element(f, name, e, body, containers)
        if isinstance(e, Slab) and e.mesh is None:
            for hole in e.holes:
                _opening(f, name, e, hole, body, product)
    out = Path(path)
    f.write(str(out))
    return out
