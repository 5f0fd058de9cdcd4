"""Metadata of real DJI photos (a Phantom 4, camera FC330), values as the files state them.

The header values are kept in ``tests/data/photos/dji_phantom4_fc330.json`` with their source,
commit and licence (``tests/data/photos/README.md``): metadata-extractor's printout of three
photos; the 5 MB JPEGs themselves are not kept. Each photo's fields are written back in the two
forms they are stored in -- DJI's XMP attributes with their printed text (``"+109.69"``) and the
EXIF GPS IFD's degree/minute/second rationals -- and read with :func:`read_metadata`.
"""

from __future__ import annotations

import json
import math
import re
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from uav_struct_env.photos.attitude import enu_from_cam_from_dji
from uav_struct_env.photos.calibration import camera_from_exif
from uav_struct_env.photos.metadata import parse_dji_xmp, read_metadata

DATA = json.loads((Path(__file__).parents[1] / "data" / "photos" / "dji_phantom4_fc330.json").read_text())
PHOTOS = sorted(DATA["photos"])


def _dms(text: str) -> tuple[Fraction, Fraction, Fraction]:
    """``32° 28' 42.96"`` (metadata-extractor's print; a leading minus is its sign for W/S)."""
    d, m, s = re.match(r"-?(\d+)° (\d+)' ([\d.]+)\"", text).groups()
    return Fraction(d), Fraction(m), Fraction(s)


def _degrees(text: str, ref: str) -> float:
    d, m, s = _dms(text)
    value = float(d) + float(m) / 60.0 + float(s) / 3600.0
    return -value if ref in "SW" else value


def _write(path: Path, rec: dict) -> Path:
    """A JPEG of the photo's size with its EXIF (GPS IFD, Make, Model, focal lengths) and DJI XMP."""
    from PIL import ExifTags, Image, TiffImagePlugin

    ex = rec["exif"]
    exif = Image.Exif()
    exif[ExifTags.Base.Make], exif[ExifTags.Base.Model] = ex["Make"], ex["Model"]
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    sub[ExifTags.Base.FocalLength] = TiffImagePlugin.IFDRational(Fraction(ex["Focal Length"].split()[0]))
    sub[ExifTags.Base.FocalLengthIn35mmFilm] = int(ex["Focal Length 35"].split()[0])
    gps = exif.get_ifd(ExifTags.IFD.GPSInfo)
    gps[ExifTags.GPS.GPSLatitudeRef], gps[ExifTags.GPS.GPSLongitudeRef] = (
        ex["GPS Latitude Ref"], ex["GPS Longitude Ref"])
    gps[ExifTags.GPS.GPSLatitude] = tuple(TiffImagePlugin.IFDRational(v) for v in _dms(ex["GPS Latitude"]))
    gps[ExifTags.GPS.GPSLongitude] = tuple(TiffImagePlugin.IFDRational(v) for v in _dms(ex["GPS Longitude"]))
    gps[ExifTags.GPS.GPSAltitudeRef] = b"\x00"  # "Sea level"
    gps[ExifTags.GPS.GPSAltitude] = TiffImagePlugin.IFDRational(Fraction(ex["GPS Altitude"].split()[0]))
    attributes = "".join(f'\n   drone-dji:{k}="{v}"' for k, v in rec["xmp"].items())
    xmp = ('<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-'
           'syntax-ns#"><rdf:Description rdf:about="DJI Meta Data" xmlns:tiff="http://ns.adobe.com/tiff/1.0/"'
           ' xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" tiff:Make="DJI" tiff:Model="FC330"'
           f"{attributes}/></rdf:RDF></x:xmpmeta>")
    w, h = (int(ex[f"Image {k}"].split()[0]) for k in ("Width", "Height"))
    Image.new("RGB", (w, h)).save(path, "JPEG", exif=exif.tobytes(), xmp=xmp.encode())
    return path


def test_the_kept_headers_name_their_source_and_licence():
    assert DATA["source"] == "https://github.com/drewnoakes/metadata-extractor-images"
    assert re.fullmatch(r"[0-9a-f]{40}", DATA["commit"]) and "free to use" in DATA["licence"]
    assert len(PHOTOS) == 3 and all(DATA["photos"][p]["exif"]["Model"] == "FC330" for p in PHOTOS)


@pytest.mark.parametrize("name", PHOTOS)
def test_each_field_reads_as_the_file_states_it(name, tmp_path):
    rec = DATA["photos"][name]
    meta = read_metadata(_write(tmp_path / "DJI.JPG", rec))
    ex = rec["exif"]
    assert (meta.make, meta.model, meta.image_size, meta.orientation) == ("DJI", "FC330", (4000, 3000), 1)
    assert meta.latitude_deg == pytest.approx(_degrees(ex["GPS Latitude"], "N"), abs=1e-12)
    assert meta.longitude_deg == pytest.approx(_degrees(ex["GPS Longitude"], "W"), abs=1e-12)
    assert meta.longitude_deg < -90 and 32 < meta.latitude_deg < 33  # Mississippi, United States
    assert meta.altitude_m == 109.0 and meta.focal_length_mm == 3.6 and meta.focal_length_35mm == 20
    for field, text in rec["xmp"].items():  # every field the reader knows, with its printed value
        if field in meta.dji:
            assert meta.dji[field] == float(text), field
    read = set(meta.dji)
    assert read == {"AbsoluteAltitude", "RelativeAltitude", "GimbalYawDegree", "GimbalPitchDegree",
                    "GimbalRollDegree", "FlightYawDegree", "FlightPitchDegree", "FlightRollDegree"}
    assert meta.absolute_altitude_m == float(rec["xmp"]["AbsoluteAltitude"])  # XMP before EXIF GPS
    # the same fields in the element form tools rewrite them to
    elements = "".join(f"<drone-dji:{k}>{v}</drone-dji:{k}>" for k, v in rec["xmp"].items())
    assert parse_dji_xmp(elements)[0] == meta.dji


@pytest.mark.parametrize("name", PHOTOS)
def test_the_gimbal_angles_point_the_camera_where_dji_says(name):
    # GimbalPitchDegree is the optical axis' elevation (negative: below the horizon) and
    # GimbalYawDegree its azimuth from north towards east
    xmp = DATA["photos"][name]["xmp"]
    yaw, pitch, roll = (float(xmp[f"Gimbal{a}Degree"]) for a in ("Yaw", "Pitch", "Roll"))
    forward = enu_from_cam_from_dji(yaw, pitch, roll)[:, 2]
    assert math.degrees(math.asin(forward[2])) == pytest.approx(pitch, abs=1e-9)
    if pitch > -85.0:
        assert math.degrees(math.atan2(forward[0], forward[1])) == pytest.approx(yaw, abs=1e-9)


def test_a_phantom4_photo_gets_its_intrinsics_from_the_sensor_width(tmp_path):
    meta = read_metadata(_write(tmp_path / "DJI.JPG", DATA["photos"][PHOTOS[0]]))
    with pytest.warns(UserWarning, match="uncalibrated intrinsics"):
        cam = camera_from_exif(meta)
    f = 3.6 / 6.17 * 4000  # FocalLength over the FC330's 1/2.3" sensor width, times the width
    np.testing.assert_allclose(cam.K[[0, 1], [0, 1]], f)
    # FocalLengthIn35mmFilm (20 mm) states the same camera to within the rounding of the 20
    f35 = 20 * math.hypot(4000, 3000) / math.hypot(36, 24)
    assert abs(f35 - f) / f < 0.03
