"""An IFC model's georeferencing: WGS84 (a photo's GNSS) <-> map coordinates <-> the project frame.

The project frame is the frame :func:`~uav_struct_env.site.load_ifc` builds a site in: the IFC
world frame in metres. IFC4 relates it to a projected map CRS with IfcMapConversion (IFC2X3
files carry the same fields in the IfcProject's ``ePSet_MapConversion``/``ePSet_ProjectedCRS``):

    E = Eastings + S * fx * (cos(t) * x - sin(t) * y)
    N = Northings + S * fy * (sin(t) * x + cos(t) * y)
    H = OrthogonalHeight + S * fz * z

with ``x, y, z`` in the file's length unit, ``t = atan2(XAxisOrdinate, XAxisAbscissa)`` the angle
of the project's x axis from map east (counter-clockwise), ``S`` = Scale (default 1; for a
millimetre file on a metre map 0.001) and ``fx, fy, fz`` the factors of IfcMapConversionScaled
(else 1). E, N and H are in the map unit: IfcProjectedCRS.MapUnit where stated (one real SketchUp
export states millimetres), else the CRS's own axis unit. :class:`Georeference` holds all of it
in metres, so that ``map_m = origin_m + scale_m * [R(t) @ (x, y), z]`` with project metres.

WGS84 <-> map goes through pyproj (the ``photo`` extra) from EPSG:4326 to the CRS named by
IfcProjectedCRS.Name (``"EPSG:32632"``). Heights are not transformed between vertical datums:
a photo's altitude is taken as a height in the datum of OrthogonalHeight (both are usually
above mean sea level; an ellipsoidal GNSS height differs by the geoid undulation, tens of
metres: use ``--takeoff-z`` with RelativeAltitude then, :mod:`uav_struct_env.photos.prior`).

Files without georeferencing take it from the user: ``E,N,H,rotation_deg,EPSG`` metres and
degrees (:meth:`Georeference.from_string`), or three or more surveyed control points, project
``x, y, z`` <-> ``lat, lon, alt`` (:meth:`Georeference.from_control_points`: a plan rotation and
translation fitted by least squares and a height offset, scale 1; the RMS residual is kept).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from uav_struct_env.photos.errors import PhotoError

__all__ = ["INSTALL_HINT", "Georeference", "read_control_points", "read_ifc_georeference", "utm_crs"]

INSTALL_HINT = "pip install 'uav-struct-env[photo]'"
#: Latitude/longitude step for the local ENU axes (about 1 m), degrees.
_STEP_DEG = 1e-5


def _pyproj() -> Any:
    try:
        import pyproj
    except ImportError as exc:
        raise ImportError(f"georeferencing needs pyproj, which is not installed ({exc}); install the "
                          f"'photo' extra: {INSTALL_HINT}") from exc
    return pyproj


@functools.lru_cache(maxsize=16)
def _crs(name: str) -> tuple[Any, Any, Any, float]:
    """``(crs, to_map, to_wgs84, metres per CRS unit)`` for a CRS name; PhotoError if unusable."""
    pyproj = _pyproj()
    try:
        crs = pyproj.CRS.from_user_input(name)
    except pyproj.exceptions.CRSError:
        raise PhotoError(f"CRS {name!r} is not a coordinate reference system pyproj knows; expected e.g. "
                         "'EPSG:32632'") from None
    if not crs.is_projected:
        raise PhotoError(f"CRS {name!r} ({crs.name}) is not a projected CRS; IfcMapConversion needs one "
                         "(eastings/northings in a length unit)")
    factor = float(crs.axis_info[0].unit_conversion_factor)
    wgs84 = pyproj.CRS.from_epsg(4326)
    to_map = pyproj.Transformer.from_crs(wgs84, crs, always_xy=True)
    to_wgs84 = pyproj.Transformer.from_crs(crs, wgs84, always_xy=True)
    return crs, to_map, to_wgs84, factor


def utm_crs(latitude_deg: float, longitude_deg: float) -> str:
    """The WGS84 UTM zone CRS (``"EPSG:326zz"`` north, ``"EPSG:327zz"`` south) of a position."""
    zone = int(math.floor((longitude_deg + 180.0) / 6.0)) % 60 + 1
    return f"EPSG:{(32600 if latitude_deg >= 0 else 32700) + zone}"


@dataclass(frozen=True)
class Georeference:
    """Project frame (metres) <-> map CRS (module docstring), all lengths in metres.

    Attributes:
        origin_m: (E, N, H) of the project origin in the map, metres.
        rotation_rad: angle of the project x axis from map east, counter-clockwise.
        scale: (3,) map metres per project metre along x, y, z.
        crs: the projected CRS, as pyproj reads it (``"EPSG:32632"``).
        source: where it came from (``"IfcMapConversion"``, ``"--georef"``, ``"control points"``).
        residual_m: RMS residual of the control-point fit, metres (0 otherwise).
    """

    origin_m: tuple[float, float, float]
    rotation_rad: float
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    crs: str = "EPSG:4326"
    source: str = ""
    residual_m: float = 0.0

    def __post_init__(self) -> None:
        values = (*self.origin_m, self.rotation_rad, *self.scale)
        if len(self.origin_m) != 3 or len(self.scale) != 3 or not all(math.isfinite(v) for v in values):
            raise PhotoError(f"georeference needs finite origin (E, N, H) and scale (3,), got "
                             f"origin {self.origin_m}, rotation {self.rotation_rad}, scale {self.scale}")
        if min(self.scale) <= 0:
            raise PhotoError(f"georeference scale must be positive, got {self.scale}")
        _crs(self.crs)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_string(cls, text: str) -> Georeference:
        """``"E,N,H,rotation_deg,EPSG"`` (metres, degrees; EPSG as ``32632`` or ``EPSG:32632``).

        Raises:
            PhotoError: five comma-separated fields were not given, or one does not parse.
        """
        parts = [p.strip() for p in str(text).split(",")]
        if len(parts) != 5:
            raise PhotoError(f"--georef must be E,N,H,rotation_deg,EPSG (5 fields), got {text!r}")
        try:
            e, n, h, rot = (float(p) for p in parts[:4])
        except ValueError:
            raise PhotoError(f"--georef E,N,H,rotation_deg must be numbers, got {text!r}") from None
        code = parts[4] if ":" in parts[4] else f"EPSG:{parts[4]}"
        return cls((e, n, h), math.radians(rot), crs=code, source="--georef")

    @classmethod
    def from_control_points(cls, project_xyz: ArrayLike, lat_lon_alt: ArrayLike,
                            crs: str | None = None) -> Georeference:
        """Fit to >= 3 surveyed points: project ``(x, y, z)`` m <-> ``(lat, lon, alt)`` deg, m.

        A plan rotation and translation (least squares, scale 1) and a height offset (the mean).
        ``crs`` default: the UTM zone of the first point.

        Raises:
            PhotoError: fewer than 3 points, shapes that differ, or points collinear in plan.
        """
        xyz = np.asarray(project_xyz, dtype=np.float64).reshape(-1, 3)
        lla = np.asarray(lat_lon_alt, dtype=np.float64).reshape(-1, 3)
        finite = np.all(np.isfinite(xyz)) and np.all(np.isfinite(lla))
        if len(xyz) < 3 or len(xyz) != len(lla) or not finite:
            raise PhotoError(f"control points: need >= 3 finite project (x, y, z) <-> (lat, lon, alt) pairs, "
                             f"got {len(xyz)} and {len(lla)}")
        crs = crs or utm_crs(lla[0, 0], lla[0, 1])
        _, to_map, _, factor = _crs(crs)
        e, n = to_map.transform(lla[:, 1], lla[:, 0])
        enh = np.column_stack([np.asarray(e) * factor, np.asarray(n) * factor, lla[:, 2]])
        p, q = xyz[:, :2] - xyz[:, :2].mean(0), enh[:, :2] - enh[:, :2].mean(0)
        if np.linalg.svd(p, compute_uv=False)[-1] < 1e-3 * max(1.0, np.abs(p).max()):
            raise PhotoError("control points are collinear in plan; the rotation is undetermined")
        h = p.T @ q
        theta = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
        c, s = math.cos(theta), math.sin(theta)
        t = enh[:, :2].mean(0) - np.array([[c, -s], [s, c]]) @ xyz[:, :2].mean(0)
        height = float(np.mean(enh[:, 2] - xyz[:, 2]))
        out = cls((float(t[0]), float(t[1]), height), theta, crs=crs, source="control points")
        residual = out.map_from_project(xyz) - enh
        return cls(out.origin_m, theta, crs=crs, source="control points",
                   residual_m=float(np.sqrt(np.mean(np.sum(residual**2, axis=1)))))

    # ------------------------------------------------------------------ conversions
    def _rotation(self) -> NDArray[np.float64]:
        c, s = math.cos(self.rotation_rad), math.sin(self.rotation_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def map_from_project(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) map (E, N, H) in metres of project points (N, 3) in metres."""
        p = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        return np.asarray(self.origin_m) + (p * np.asarray(self.scale)) @ self._rotation().T

    def project_from_map(self, enh: ArrayLike) -> NDArray[np.float64]:
        """Inverse of :meth:`map_from_project`."""
        m = np.asarray(enh, dtype=np.float64).reshape(-1, 3) - np.asarray(self.origin_m)
        return (m @ self._rotation()) / np.asarray(self.scale)

    def project_from_wgs84(self, lat_lon_alt: ArrayLike) -> NDArray[np.float64]:
        """(N, 3) project points of WGS84 ``(lat deg, lon deg, alt m)`` rows (N, 3)."""
        lla = np.asarray(lat_lon_alt, dtype=np.float64).reshape(-1, 3)
        _, to_map, _, factor = _crs(self.crs)
        e, n = to_map.transform(lla[:, 1], lla[:, 0])
        enh = np.column_stack([np.asarray(e) * factor, np.asarray(n) * factor, lla[:, 2]])
        if not np.all(np.isfinite(enh)):
            raise PhotoError(f"a WGS84 position {lla.tolist()} lies outside the area of {self.crs}")
        return self.project_from_map(enh)

    def wgs84_from_project(self, xyz: ArrayLike) -> NDArray[np.float64]:
        """Inverse of :meth:`project_from_wgs84`: (N, 3) ``(lat, lon, alt)``."""
        enh = self.map_from_project(xyz)
        _, _, to_wgs84, factor = _crs(self.crs)
        lon, lat = to_wgs84.transform(enh[:, 0] / factor, enh[:, 1] / factor)
        return np.column_stack([np.asarray(lat), np.asarray(lon), enh[:, 2]])

    def project_from_enu(self, latitude_deg: float, longitude_deg: float) -> NDArray[np.float64]:
        """(3, 3) rotation taking local east-north-up axes at a position to project axes.

        Includes the map projection's grid convergence and the project's rotation; measured by
        mapping one step east and one north (its residual non-orthogonality is the projection's
        distortion, removed by an SVD).
        """
        lla = np.array([[latitude_deg, longitude_deg, 0.0],
                        [latitude_deg, longitude_deg + _STEP_DEG, 0.0],
                        [latitude_deg + _STEP_DEG, longitude_deg, 0.0]])
        p = self.project_from_wgs84(lla)
        east, north = p[1, :2] - p[0, :2], p[2, :2] - p[0, :2]
        a = np.column_stack([east / np.linalg.norm(east), north / np.linalg.norm(north)])
        u, _, vt = np.linalg.svd(a)
        r2 = u @ vt
        out = np.eye(3)
        out[:2, :2] = r2
        return out

    def describe(self) -> str:
        """One line for outputs: origin, rotation, scale, CRS and source."""
        e, n, h = self.origin_m
        text = (f"{self.source or 'georeference'} E {e:.3f} N {n:.3f} H {h:.3f} m, x axis "
                f"{math.degrees(self.rotation_rad):.4f} deg from east, scale {self.scale[0]:g}, {self.crs}")
        fitted = self.source == "control points"
        return text + (f", control-point RMS {self.residual_m:.3f} m" if fitted else "")


def _crs_fields(f: Any) -> tuple[str | None, float | None]:
    """(CRS name, map unit in metres or None) of an IFC file."""
    import ifcopenshell.util.geolocation
    import ifcopenshell.util.unit

    info = ifcopenshell.util.geolocation.get_crs(f) or {}
    name = info.get("Name")
    unit = info.get("MapUnit")
    if f.schema == "IFC2X3":  # ePSet_ProjectedCRS.MapUnit is a label ("METRE", "MILLIMETRE")
        label = str(unit or "").upper()
        prefix = {"MILLI": 1e-3, "CENTI": 1e-2, "DECI": 1e-1, "KILO": 1e3}
        mu = next((v for k, v in prefix.items() if label.startswith(k)), 1.0) if label else None
        return name, mu
    return name, (None if unit is None else _named_unit_m(unit))


def _named_unit_m(unit: Any) -> float:
    """Metres per IfcSIUnit / IfcConversionBasedUnit length unit."""
    if unit.is_a("IfcSIUnit"):
        prefixes = {None: 1.0, "MILLI": 1e-3, "CENTI": 1e-2, "DECI": 1e-1, "KILO": 1e3}
        return prefixes.get(unit.Prefix, 1.0)
    factor = unit.ConversionFactor
    value = float(factor.ValueComponent.wrappedValue)
    return value * _named_unit_m(factor.UnitComponent)


def read_ifc_georeference(path: str | Path) -> Georeference | None:
    """The georeferencing an IFC file states (module docstring), or None when it states none.

    Raises:
        PhotoError: a map conversion without a usable projected CRS name.
        ImportError: ifcopenshell or pyproj is not installed.
    """
    from uav_struct_env.site.ifc_export import require_ifcopenshell

    ifcopenshell = require_ifcopenshell()
    import ifcopenshell.util.geolocation  # noqa: F811 (submodules of the module required above)
    import ifcopenshell.util.unit

    f = ifcopenshell.open(str(path))
    params = ifcopenshell.util.geolocation.get_helmert_transformation_parameters(f)
    if params is None:
        return None
    name, map_unit = _crs_fields(f)
    if not name:
        raise PhotoError(f"{str(path)!r} has a map conversion but no IfcProjectedCRS name (expected e.g. "
                         "'EPSG:32632'); give --georef E,N,H,rotation_deg,EPSG instead")
    file_unit = float(ifcopenshell.util.unit.calculate_unit_scale(f))
    mu = map_unit if map_unit is not None else _crs(name)[3]
    s = float(params.scale) * mu / file_unit
    return Georeference(
        origin_m=(float(params.e) * mu, float(params.n) * mu, float(params.h) * mu),
        rotation_rad=math.atan2(float(params.xao), float(params.xaa)),
        scale=(s * float(params.factor_x), s * float(params.factor_y), s * float(params.factor_z)),
        crs=name, source="IfcMapConversion",
    )


def read_control_points(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Control points from a CSV file of ``x,y,z,lat,lon,alt`` rows (``#`` comments, a header allowed).

    Returns:
        (N, 3) project points in metres and (N, 3) WGS84 ``(lat, lon, alt)``.

    Raises:
        PhotoError: a row that is not six numbers, or fewer than 3 rows.
    """
    rows = []
    for k, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line or (not rows and line[0].isalpha()):
            continue
        try:
            values = [float(v) for v in line.split(",")]
        except ValueError:
            values = []
        if len(values) != 6:
            raise PhotoError(f"{str(path)!r} line {k}: expected x,y,z,lat,lon,alt (6 numbers), got {line!r}")
        rows.append(values)
    if len(rows) < 3:
        raise PhotoError(f"{str(path)!r}: needs at least 3 control points, got {len(rows)}")
    arr = np.asarray(rows)
    return arr[:, :3], arr[:, 3:]
