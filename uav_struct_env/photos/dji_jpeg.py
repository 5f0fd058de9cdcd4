"""Write DJI-style JPEGs: EXIF GPS and an XMP packet in DJI's layout, from a project-frame pose.

What the validation needs (no real drone photo can ship with the project): a rendered frame
written as a photo that :func:`uav_struct_env.photos.read_metadata` and ``uav-struct localize``
read exactly as they read a DJI camera's. The layout follows DJI's own files: EXIF IFD0
``Make``/``Model``, the Exif IFD's ``FocalLength`` and ``FocalLengthIn35mmFilm``, the GPS IFD
(version 2.2.0.0, degrees/minutes/seconds rationals with hemisphere refs, altitude with ref 0),
and an APP1 XMP packet whose ``rdf:Description rdf:about="DJI Meta Data"`` carries the
``drone-dji:`` fields as attributes with explicit signs (``"+12.30"``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from fractions import Fraction
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from localization.geometry.transforms import check_transform
from uav_struct_env.photos.attitude import dji_angles_from_enu_from_cam
from uav_struct_env.photos.georef import Georeference
from uav_struct_env.photos.metadata import DJI_FIELDS
from uav_struct_env.training.jpeg_augment import CHROMA_SUBSAMPLING

__all__ = ["dji_fields_from_pose", "write_dji_jpeg"]

_XMP_HEAD = """<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>
<x:xmpmeta xmlns:x="adobe:ns:meta/">
 <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
  <rdf:Description rdf:about="DJI Meta Data"
    xmlns:tiff="http://ns.adobe.com/tiff/1.0/"
    xmlns:exif="http://ns.adobe.com/exif/1.0/"
    xmlns:xmp="http://ns.adobe.com/xap/1.0/"
    xmlns:dc="http://purl.org/dc/elements/1.1/"
    xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
   tiff:Make="{make}"
   tiff:Model="{model}"
   dc:format="image/jpg"
"""
_XMP_TAIL = """  </rdf:Description>
 </rdf:RDF>
</x:xmpmeta>
<?xpacket end="w"?>"""
#: Decimals DJI writes per field (angles and altitudes 2; positions 9 where XMP carries them).
_DECIMALS = {"GpsLatitude": 9, "GpsLongitude": 9, "RtkFlag": 0, "CalibratedFocalLength": 6,
             "CalibratedOpticalCenterX": 6, "CalibratedOpticalCenterY": 6, "RtkStdLon": 5,
             "RtkStdLat": 5, "RtkStdHgt": 5}


def dji_fields_from_pose(world_from_cam: ArrayLike, georef: Georeference,
                         takeoff_z: float = 0.0) -> dict[str, float]:
    """The DJI fields a camera at ``world_from_cam`` (project frame) would write.

    ``GpsLatitude``/``GpsLongitude``/``AbsoluteAltitude`` through ``georef``, ``RelativeAltitude``
    above ``takeoff_z``, and the gimbal angles (degrees, NED, Z-Y-X); the flight angles are set
    to the gimbal's yaw with a level body.
    """
    T = check_transform("world_from_cam", world_from_cam)
    lat, lon, alt = georef.wgs84_from_project(T[:3, 3])[0]
    enu_from_project = georef.project_from_enu(lat, lon).T
    yaw, pitch, roll = dji_angles_from_enu_from_cam(enu_from_project @ T[:3, :3])
    return {"GpsLatitude": float(lat), "GpsLongitude": float(lon), "AbsoluteAltitude": float(alt),
            "RelativeAltitude": float(T[2, 3] - takeoff_z), "GimbalYawDegree": yaw,
            "GimbalPitchDegree": pitch, "GimbalRollDegree": roll, "FlightYawDegree": yaw,
            "FlightPitchDegree": 0.0, "FlightRollDegree": 0.0}


def _xmp(fields: Mapping[str, float], make: str, model: str) -> bytes:
    unknown = sorted(set(fields) - set(DJI_FIELDS))
    if unknown:
        raise ValueError(f"DJI fields must be among {DJI_FIELDS}, got {unknown}")
    lines = [_XMP_HEAD.format(make=make, model=model)]
    for name in DJI_FIELDS:
        if name in fields:
            d = _DECIMALS.get(name, 2)
            value = f"{int(round(fields[name]))}" if d == 0 else f"{fields[name]:+.{d}f}"
            lines.append(f'   drone-dji:{name}="{value}"\n')
    lines[-1] = lines[-1].rstrip("\n") + ">\n"
    return ("".join(lines) + _XMP_TAIL).encode("utf-8")


def _dms(value: float) -> tuple[Fraction, Fraction, Fraction]:
    """Degrees as EXIF (degrees, minutes, seconds) rationals; seconds to 1e-6 (3e-5 m)."""
    a = abs(value)
    d = math.floor(a)
    m = math.floor((a - d) * 60.0)
    s = round(((a - d) * 60.0 - m) * 60.0 * 1_000_000)
    return Fraction(d), Fraction(m), Fraction(s, 1_000_000)


def write_dji_jpeg(path: str | Path, rgb: ArrayLike, fields: Mapping[str, float], *, make: str = "DJI",
                   model: str = "L1D-20c", focal_length_mm: float | None = None,
                   focal_length_35mm: float | None = None, quality: int = 95,
                   orientation: int = 1, chroma: str = "4:2:0") -> Path:
    """Write an (H, W, 3) uint8 RGB image as a JPEG with DJI's EXIF and XMP (module docstring).

    Args:
        path: the JPEG to write.
        rgb: the pixels.
        fields: ``drone-dji:`` fields (:data:`~uav_struct_env.photos.metadata.DJI_FIELDS` names);
            ``GpsLatitude``/``GpsLongitude``/``AbsoluteAltitude`` also go into the EXIF GPS IFD.
        make: EXIF and ``tiff:`` Make.
        model: EXIF and ``tiff:`` Model (DJI's camera code, ``L1D-20c`` for the Mavic 2 Pro).
        focal_length_mm: EXIF FocalLength, or None to leave it out.
        focal_length_35mm: EXIF FocalLengthIn35mmFilm, or None to leave it out.
        quality: JPEG quality.
        orientation: EXIF Orientation (274) to state, written when not 1 (DJI writes 1): the
            pixels are stored as given, the tag tells a viewer how to turn them.
        chroma: chroma subsampling, ``"4:2:0"`` (libjpeg's default), ``"4:2:2"`` (what DJI's
            Phantom 4 camera writes, ``tests/data/photos/README.md``) or ``"4:4:4"``.

    Raises:
        ValueError: an image that is not (H, W, 3) uint8, an unknown field name or chroma layout.
    """
    from PIL import ExifTags, Image, TiffImagePlugin

    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise ValueError(f"rgb must be an (H, W, 3) uint8 array, got shape {img.shape}, dtype {img.dtype}")
    xmp = _xmp(fields, make, model)
    exif = Image.Exif()
    exif[ExifTags.Base.Make], exif[ExifTags.Base.Model] = make, model
    if orientation != 1:
        exif[ExifTags.Base.Orientation] = int(orientation)
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    if focal_length_mm:
        focal = Fraction(focal_length_mm).limit_denominator(1000)
        sub[ExifTags.Base.FocalLength] = TiffImagePlugin.IFDRational(focal)
    if focal_length_35mm:
        sub[ExifTags.Base.FocalLengthIn35mmFilm] = int(round(focal_length_35mm))
    if "GpsLatitude" in fields and "GpsLongitude" in fields:
        gps = exif.get_ifd(ExifTags.IFD.GPSInfo)
        lat, lon = fields["GpsLatitude"], fields["GpsLongitude"]
        gps[ExifTags.GPS.GPSVersionID] = b"\x02\x02\x00\x00"
        gps[ExifTags.GPS.GPSLatitudeRef] = "N" if lat >= 0 else "S"
        gps[ExifTags.GPS.GPSLatitude] = tuple(TiffImagePlugin.IFDRational(v) for v in _dms(lat))
        gps[ExifTags.GPS.GPSLongitudeRef] = "E" if lon >= 0 else "W"
        gps[ExifTags.GPS.GPSLongitude] = tuple(TiffImagePlugin.IFDRational(v) for v in _dms(lon))
        if "AbsoluteAltitude" in fields:
            alt = fields["AbsoluteAltitude"]
            gps[ExifTags.GPS.GPSAltitudeRef] = b"\x00" if alt >= 0 else b"\x01"
            millimetres = Fraction(round(abs(alt) * 1000), 1000)
            gps[ExifTags.GPS.GPSAltitude] = TiffImagePlugin.IFDRational(millimetres)
    out = Path(path)
    if chroma not in CHROMA_SUBSAMPLING:
        raise ValueError(f"chroma must be one of {tuple(CHROMA_SUBSAMPLING)}, got {chroma!r}")
    extra = {} if chroma == "4:2:0" else {"subsampling": CHROMA_SUBSAMPLING[chroma]}
    Image.fromarray(img).save(out, "JPEG", quality=int(quality), exif=exif.tobytes(), xmp=xmp, **extra)
    return out
