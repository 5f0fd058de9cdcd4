import numpy as np
import pytest

from uav_struct_env.photos import PhotoError, parse_dji_xmp, read_metadata
from uav_struct_env.photos.dji_jpeg import write_dji_jpeg
from uav_struct_env.photos.metadata import DJI_FIELDS

RGB = np.full((48, 64, 3), 120, np.uint8)

#: One value per DJI field, as a DJI camera could write it.
VALUES = {"GpsLatitude": -33.868820123, "GpsLongitude": 151.209296456, "AbsoluteAltitude": 123.45,
          "RelativeAltitude": 50.1, "GimbalYawDegree": -12.3, "GimbalPitchDegree": -45.6,
          "GimbalRollDegree": 0.7, "FlightYawDegree": -11.2, "FlightPitchDegree": 3.4,
          "FlightRollDegree": -2.2, "RtkFlag": 50, "RtkStdLon": 0.01234, "RtkStdLat": 0.01567,
          "RtkStdHgt": 0.02345, "CalibratedFocalLength": 3725.151611,
          "CalibratedOpticalCenterX": 2640.5, "CalibratedOpticalCenterY": 1978.25}


def test_every_dji_field_has_a_value_here():
    assert set(VALUES) == set(DJI_FIELDS)


@pytest.mark.parametrize("name", DJI_FIELDS)
def test_each_dji_field_round_trips_through_a_jpeg(tmp_path, name):
    path = write_dji_jpeg(tmp_path / "p.jpg", RGB, {name: VALUES[name]})
    meta = read_metadata(path)
    assert set(meta.dji) == {name}
    decimals = {"GpsLatitude": 9, "GpsLongitude": 9, "CalibratedFocalLength": 6, "RtkStdLon": 5,
                "RtkStdLat": 5, "RtkStdHgt": 5}.get(name, 2)
    assert meta.dji[name] == pytest.approx(VALUES[name], abs=0.6 * 10.0**-decimals)


def test_exif_gps_southern_western_hemisphere_and_sea_level(tmp_path):
    fields = {"GpsLatitude": -33.868820123, "GpsLongitude": -70.5, "AbsoluteAltitude": -12.25}
    meta = read_metadata(write_dji_jpeg(tmp_path / "p.jpg", RGB, fields, model="FC6310"))
    assert meta.latitude_deg == pytest.approx(-33.868820123, abs=1e-9)
    assert meta.longitude_deg == pytest.approx(-70.5, abs=1e-9)
    assert meta.altitude_m == pytest.approx(-12.25)
    assert (meta.make, meta.model, meta.image_size, meta.orientation) == ("DJI", "FC6310", (64, 48), 1)


def test_exif_focal_lengths(tmp_path):
    meta = read_metadata(write_dji_jpeg(tmp_path / "p.jpg", RGB, {}, focal_length_mm=10.26,
                                        focal_length_35mm=28))
    assert meta.focal_length_mm == pytest.approx(10.26)
    assert meta.focal_length_35mm == 28.0
    assert meta.latitude_deg is None and meta.gimbal_deg() is None


# A packet in the attribute layout DJI's cameras write (namespaces, signs, unread fields), values our own.
DJI_PACKET = """<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
  <rdf:Description rdf:about="DJI Meta Data" xmlns:tiff="http://ns.adobe.com/tiff/1.0/"
    xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"
   tiff:Make="DJI" tiff:Model="FC3582"
   drone-dji:AbsoluteAltitude="-21.07" drone-dji:RelativeAltitude="+44.80"
   drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="-97.30" drone-dji:GimbalPitchDegree="-35.10"
   drone-dji:FlightRollDegree="+2.10" drone-dji:FlightYawDegree="-96.80" drone-dji:FlightPitchDegree="-4.90"
   drone-dji:CamReverse="0" drone-dji:GimbalReverse="0">
  </rdf:Description></rdf:RDF></x:xmpmeta>"""


def test_parse_attribute_form_as_dji_writes_it():
    fields, tiff = parse_dji_xmp(DJI_PACKET)
    assert fields == {"AbsoluteAltitude": -21.07, "RelativeAltitude": 44.8, "GimbalRollDegree": 0.0,
                      "GimbalYawDegree": -97.3, "GimbalPitchDegree": -35.1, "FlightRollDegree": 2.1,
                      "FlightYawDegree": -96.8, "FlightPitchDegree": -4.9}
    assert tiff == {"Make": "DJI", "Model": "FC3582"}


def test_parse_element_form_and_the_longtitude_spelling():
    packet = ("<drone-dji:GimbalYawDegree>+45.5</drone-dji:GimbalYawDegree>"
              '<rdf:Description drone-dji:GpsLongtitude="8.5"/>')
    fields, _ = parse_dji_xmp(packet.encode())
    assert fields == {"GimbalYawDegree": 45.5, "GpsLongitude": 8.5}


def test_a_field_that_is_not_a_number_is_refused_not_dropped():
    with pytest.raises(PhotoError, match=r"drone-dji:GimbalYawDegree must be a number, got 'north'"):
        parse_dji_xmp('drone-dji:GimbalYawDegree="north"')


def test_not_an_image_is_refused(tmp_path):
    path = tmp_path / "notes.jpg"
    path.write_text("not a photo")
    with pytest.raises(PhotoError, match="is not an image"):
        read_metadata(path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_metadata(tmp_path / "missing.jpg")


@pytest.mark.parametrize("chroma, sampling", [("4:2:0", 2), ("4:2:2", 1), ("4:4:4", 0)])
def test_the_chroma_subsampling_written_is_the_one_asked_for(tmp_path, chroma, sampling):
    from PIL import Image, JpegImagePlugin

    rgb = np.random.default_rng(0).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    path = write_dji_jpeg(tmp_path / "p.jpg", rgb, {"GpsLatitude": 1.0, "GpsLongitude": 2.0}, chroma=chroma)
    with Image.open(path) as im:
        assert JpegImagePlugin.get_sampling(im) == sampling
    with pytest.raises(ValueError, match="chroma must be one of"):
        write_dji_jpeg(tmp_path / "q.jpg", rgb, {}, chroma="4:1:1")
