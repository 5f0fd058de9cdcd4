"""A drone photo's own metadata: EXIF (Pillow) and DJI's XMP packet (a small parser).

What is read, and where from:

* **EXIF** (Pillow's ``Image.getexif``): image size, ``Make``, ``Model``, ``Orientation``
  (274), ``FocalLength`` (37386, mm), ``FocalLengthIn35mmFilm`` (41989, mm) and the GPS IFD
  (34853): ``GPSLatitude``/``GPSLatitudeRef``, ``GPSLongitude``/``GPSLongitudeRef`` (degrees,
  minutes, seconds as rationals) and ``GPSAltitude``/``GPSAltitudeRef`` (metres; ref 1 = below
  sea level).
* **DJI XMP** (the ``drone-dji:`` namespace, ``http://www.dji.com/drone-dji/1.0/``), written by
  DJI cameras as attributes of ``rdf:Description`` (some tools rewrite them as elements; both are
  read): :data:`DJI_FIELDS`. Gimbal and flight angles are degrees in DJI's convention: the
  north-east-down (NED) frame, intrinsic Z-Y-X (yaw, then pitch, then roll), yaw from true north
  towards east, pitch up positive (``-90`` looks straight down), roll right-wing-down positive.
  :mod:`uav_struct_env.photos.attitude` converts them into the project's camera convention.

A value that is absent is None; a value present but not a number is refused
(:class:`~uav_struct_env.photos.errors.PhotoError`), never read as absent.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uav_struct_env.photos.errors import PhotoError

__all__ = ["DJI_FIELDS", "PhotoMetadata", "parse_dji_xmp", "read_metadata"]

#: The ``drone-dji:`` XMP fields read, as DJI spells them.
DJI_FIELDS = (
    "GpsLatitude", "GpsLongitude", "AbsoluteAltitude", "RelativeAltitude",
    "GimbalYawDegree", "GimbalPitchDegree", "GimbalRollDegree",
    "FlightYawDegree", "FlightPitchDegree", "FlightRollDegree",
    "RtkFlag", "RtkStdLon", "RtkStdLat", "RtkStdHgt",
    "CalibratedFocalLength", "CalibratedOpticalCenterX", "CalibratedOpticalCenterY",
)
#: Some DJI firmware spells the longitude ``GpsLongtitude``; read as ``GpsLongitude``.
_ALIASES = {"GpsLongtitude": "GpsLongitude"}

_EXIF_MAKE, _EXIF_MODEL, _EXIF_ORIENTATION = 271, 272, 274
_EXIF_IFD, _GPS_IFD = 34665, 34853
_FOCAL_LENGTH, _FOCAL_35MM = 37386, 41989
_GPS_LAT_REF, _GPS_LAT, _GPS_LON_REF, _GPS_LON, _GPS_ALT_REF, _GPS_ALT = 1, 2, 3, 4, 5, 6

_ATTRIBUTE = re.compile(r'drone-dji:(\w+)\s*=\s*"([^"]*)"')
_ELEMENT = re.compile(r"<drone-dji:(\w+)>([^<]*)</drone-dji:\1>")
_TIFF = re.compile(r'tiff:(Make|Model)\s*=\s*"([^"]*)"')


@dataclass(frozen=True)
class PhotoMetadata:
    """What a photo says about itself.

    Attributes:
        path: the file.
        image_size: (W, H) of the stored pixels.
        orientation: EXIF orientation tag (1 = as stored; 1-8), 1 when absent.
        make, model: camera maker and model ("" when absent).
        latitude_deg, longitude_deg: WGS84 position (EXIF GPS, else DJI XMP), or None.
        altitude_m: EXIF GPS altitude, metres, or None.
        focal_length_mm: EXIF FocalLength, or None.
        focal_length_35mm: EXIF FocalLengthIn35mmFilm, or None.
        dji: the ``drone-dji:`` fields present, by :data:`DJI_FIELDS` name, as floats.
    """

    path: Path
    image_size: tuple[int, int]
    orientation: int = 1
    make: str = ""
    model: str = ""
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = None
    focal_length_mm: float | None = None
    focal_length_35mm: float | None = None
    dji: dict[str, float] = field(default_factory=dict)

    @property
    def absolute_altitude_m(self) -> float | None:
        """DJI's AbsoluteAltitude when present, else the EXIF GPS altitude, metres."""
        return self.dji.get("AbsoluteAltitude", self.altitude_m)

    def gimbal_deg(self) -> tuple[float, float, float] | None:
        """DJI's gimbal (yaw, pitch, roll), degrees, NED, Z-Y-X; None unless all three are present."""
        names = ("GimbalYawDegree", "GimbalPitchDegree", "GimbalRollDegree")
        if not all(n in self.dji for n in names):
            return None
        return tuple(self.dji[n] for n in names)  # type: ignore[return-value]


def _number(name: str, text: str, where: str) -> float:
    try:
        value = float(text.strip())
    except ValueError:
        raise PhotoError(f"{where}: {name} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise PhotoError(f"{where}: {name} must be finite, got {text!r}")
    return value


def parse_dji_xmp(xmp: str | bytes, where: str = "XMP") -> tuple[dict[str, float], dict[str, str]]:
    """The ``drone-dji:`` fields of an XMP packet, and its ``tiff:`` Make/Model.

    Args:
        xmp: the packet (attribute or element form).
        where: names the source in error messages (the photo's path).

    Returns:
        ``(fields, tiff)``: the :data:`DJI_FIELDS` present as floats (``"+12.30"`` -> 12.3),
        and ``{"Make": ..., "Model": ...}`` where present.

    Raises:
        PhotoError: a DJI field present whose value is not a finite number.
    """
    text = xmp.decode("utf-8", errors="replace") if isinstance(xmp, (bytes, bytearray)) else str(xmp)
    out: dict[str, float] = {}
    for pattern in (_ATTRIBUTE, _ELEMENT):
        for name, value in pattern.findall(text):
            name = _ALIASES.get(name, name)
            if name in DJI_FIELDS and name not in out:
                out[name] = _number(f"drone-dji:{name}", value, where)
    return out, dict(_TIFF.findall(text))


def _ratio(value: Any) -> float:
    return float(value)  # IFDRational or tuple-free number: Pillow gives IFDRational


def _dms(name: str, value: Any, where: str) -> float:
    try:
        d, m, s = (_ratio(v) for v in value)
    except (TypeError, ValueError, ZeroDivisionError):
        raise PhotoError(f"{where}: EXIF {name} must be (degrees, minutes, seconds), got {value!r}") from None
    out = d + m / 60.0 + s / 3600.0
    if not math.isfinite(out):
        raise PhotoError(f"{where}: EXIF {name} must be finite, got {value!r}")
    return out


def _gps(gps: dict, where: str) -> tuple[float | None, float | None, float | None]:
    """(latitude, longitude, altitude) from an EXIF GPS IFD; None where absent."""
    lat = lon = alt = None
    if _GPS_LAT in gps and _GPS_LON in gps:
        lat = _dms("GPSLatitude", gps[_GPS_LAT], where)
        lon = _dms("GPSLongitude", gps[_GPS_LON], where)
        if str(gps.get(_GPS_LAT_REF, "N")).strip().upper().startswith("S"):
            lat = -lat
        if str(gps.get(_GPS_LON_REF, "E")).strip().upper().startswith("W"):
            lon = -lon
    if _GPS_ALT in gps:
        alt = _ratio(gps[_GPS_ALT])
        ref = gps.get(_GPS_ALT_REF, 0)
        ref = ref[0] if isinstance(ref, (bytes, bytearray)) and ref else ref
        if ref == 1:
            alt = -alt
    return lat, lon, alt


def _optional_float(value: Any) -> float | None:
    if value is None:
        return None
    try:
        out = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return out if math.isfinite(out) and out > 0 else None


def read_metadata(path: str | Path) -> PhotoMetadata:
    """Read a photo's size, EXIF and DJI XMP (module docstring); the pixels are not decoded.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        PhotoError: if it is not an image Pillow can open, or a present field does not parse.
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"photo {str(path)!r} does not exist")
    where = str(path)
    try:
        with Image.open(path) as im:
            size = (int(im.width), int(im.height))
            exif = im.getexif()
            xmp = im.info.get("xmp", b"")
    except (UnidentifiedImageError, OSError) as err:
        raise PhotoError(f"{where} is not an image this program can read ({err})") from None
    gps = exif.get_ifd(_GPS_IFD) if _GPS_IFD in exif else {}
    sub = exif.get_ifd(_EXIF_IFD) if _EXIF_IFD in exif else {}
    lat, lon, alt = _gps(dict(gps), where)
    dji, tiff = parse_dji_xmp(xmp, where) if xmp else ({}, {})
    if lat is None and "GpsLatitude" in dji and "GpsLongitude" in dji:
        lat, lon = dji["GpsLatitude"], dji["GpsLongitude"]
    orientation = int(exif.get(_EXIF_ORIENTATION, 1) or 1)
    if not 1 <= orientation <= 8:
        raise PhotoError(f"{where}: EXIF Orientation must be 1-8, got {orientation}")
    return PhotoMetadata(
        path=path, image_size=size, orientation=orientation,
        make=str(exif.get(_EXIF_MAKE, tiff.get("Make", ""))).strip("\x00 "),
        model=str(exif.get(_EXIF_MODEL, tiff.get("Model", ""))).strip("\x00 "),
        latitude_deg=lat, longitude_deg=lon, altitude_m=alt,
        focal_length_mm=_optional_float(sub.get(_FOCAL_LENGTH)),
        focal_length_35mm=_optional_float(sub.get(_FOCAL_35MM)),
        dji=dji,
    )
