import json

import cv2
import numpy as np
import pytest

from uav_struct_env.photos import PhotoError, camera_from_exif, load_calibration
from uav_struct_env.photos.metadata import PhotoMetadata

K = np.array([[1108.5, 0.0, 639.5], [0.0, 1110.0, 361.0], [0.0, 0.0, 1.0]])
D = np.array([-0.12, 0.03, 0.001, -0.002, 0.005])


def test_opencv_yaml_as_filestorage_writes_it(tmp_path):
    path = tmp_path / "cam.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(1, 5))
    fs.release()
    cam = load_calibration(path, (1280, 720))
    np.testing.assert_allclose(cam.K, K)
    np.testing.assert_allclose(cam.distortion, D)
    assert cam.calibrated and cam.image_size == (1280, 720)


def test_plain_json_four_coefficients_and_scaling_to_the_photo(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"K": K.tolist(), "D": D[:4].tolist(), "image_size": [640, 360]}))
    cam = load_calibration(path, (1280, 720))
    np.testing.assert_allclose(cam.distortion, [*D[:4], 0.0])
    assert cam.K[0, 0] == pytest.approx(2217.0) and cam.K[1, 1] == pytest.approx(2220.0)
    assert cam.K[0, 2] == pytest.approx((639.5 + 0.5) * 2 - 0.5)


def test_opendronemap_cameras_json(tmp_path):
    path = tmp_path / "cameras.json"
    w, h = 4000, 3000
    path.write_text(json.dumps({"v2 dji fc6310 4000 3000 brown 0.85": {
        "projection_type": "brown", "width": w, "height": h, "focal_x": 0.85, "focal_y": 0.86,
        "c_x": 0.01, "c_y": -0.02, "k1": -0.1, "k2": 0.02, "p1": 0.001, "p2": 0.002, "k3": -0.01}}))
    cam = load_calibration(path, (w, h))
    np.testing.assert_allclose(cam.K, [[3400, 0, 2039.5], [0, 3440, 1419.5], [0, 0, 1]])
    np.testing.assert_allclose(cam.distortion, [-0.1, 0.02, 0.001, 0.002, -0.01])


@pytest.mark.parametrize("text, match", [
    ("camera_matrix: [1, 2", "does not parse"),
    ('{"camera_matrix": [[1, 0, 0], [0, 1, 0]]}', "camera matrix"),
    ('{"foo": 1}', "no camera matrix"),
])
def test_files_that_do_not_parse_are_refused(tmp_path, text, match):
    path = tmp_path / ("cam.json" if text.startswith("{") else "cam.yaml")
    path.write_text(text)
    with pytest.raises(PhotoError, match=match):
        load_calibration(path, (1280, 720))


def test_another_aspect_ratio_is_refused(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"K": K.tolist(), "image_size": [1280, 960]}))
    with pytest.raises(PhotoError, match="another aspect ratio"):
        load_calibration(path, (1280, 720))


def test_exif_fallbacks_warn(tmp_path):
    meta = PhotoMetadata(tmp_path / "p.jpg", (5472, 3648), model="FC6310", focal_length_mm=8.8)
    with pytest.warns(UserWarning, match="uncalibrated intrinsics limit the accuracy"):
        cam = camera_from_exif(meta)
    assert cam.K[0, 0] == pytest.approx(8.8 / 13.2 * 5472) and not cam.calibrated
    meta35 = PhotoMetadata(tmp_path / "p.jpg", (4000, 3000), focal_length_35mm=24.0)
    with pytest.warns(UserWarning):
        assert camera_from_exif(meta35).K[0, 0] == pytest.approx(24.0 * 5000 / 43.2666, rel=1e-4)
    with pytest.raises(PhotoError, match="states no focal length"):
        camera_from_exif(PhotoMetadata(tmp_path / "p.jpg", (4000, 3000)))
