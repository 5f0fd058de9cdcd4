"""The EXIF orientation tag: the quarter turns of image, pixels, camera and pose agree."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from localization.geometry.distortion import distort_points
from localization.geometry.transforms import look_at, project
from uav_struct_env.photos import PhotoError
from uav_struct_env.photos.calibration import resolve_camera
from uav_struct_env.photos.dji_jpeg import write_dji_jpeg
from uav_struct_env.photos.metadata import read_metadata
from uav_struct_env.photos.orientation import (
    turn_camera,
    turn_image,
    turn_points,
    turn_pose,
    upright_turns,
)

SIZE = (640, 360)
K = np.array([[520.0, 0.0, 300.0], [0.0, 505.0, 190.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.05, 0.004, -0.003, 0.01])


def _pixels(K, dist, cam_from_world, xyz):
    uv, depth = project(K, cam_from_world, xyz)
    assert np.all(depth > 0)
    return distort_points(uv, K, dist)


@pytest.mark.parametrize("turns", [1, 2, 3, -1, 4])
def test_turned_camera_and_pose_see_each_point_at_the_turned_pixel(turns):
    rng = np.random.default_rng(turns + 7)
    cam_from_world = look_at([12.0, -20.0, 15.0], [2.0, 3.0, 4.0])
    xyz = rng.uniform([-6, -4, 0], [10, 10, 9], (40, 3))
    stored = _pixels(K, DIST, cam_from_world, xyz)
    K2, d2, size2 = turn_camera(K, DIST, SIZE, turns)
    upright = _pixels(K2, d2, turn_pose(cam_from_world, turns), xyz)
    np.testing.assert_allclose(upright, turn_points(stored, SIZE, turns), atol=1e-9)
    assert size2 == (SIZE if turns % 2 == 0 else SIZE[::-1])
    back = turn_points(turn_points(stored, SIZE, turns), size2, -turns)
    np.testing.assert_allclose(back, stored, atol=1e-12)


@pytest.mark.parametrize("turns", [1, 2, 3])
def test_turned_image_moves_a_pixel_where_turn_points_says(turns):
    img = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    img[37, 501] = 255
    turned = turn_image(img, turns)
    v, u = np.argwhere(turned[..., 0] == 255)[0]
    np.testing.assert_array_equal(turn_points([[501, 37]], SIZE, turns), [[u, v]])
    assert turned.shape[:2] == ((SIZE[1], SIZE[0]) if turns == 2 else (SIZE[0], SIZE[1]))


def test_tags_map_to_quarter_turns_and_mirrors_are_refused():
    assert [upright_turns(t) for t in (1, 6, 3, 8)] == [0, 1, 2, 3]
    for tag in (2, 4, 5, 7):
        with pytest.raises(PhotoError, match=f"EXIF Orientation {tag} mirrors the image"):
            upright_turns(tag, "DJI_0001.JPG")
    with pytest.raises(PhotoError, match="must be 1-8, got 9"):
        upright_turns(9)


def _calibration(path, K, dist, size):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.asarray(dist).reshape(1, -1))
    fs.write("image_width", size[0])
    fs.write("image_height", size[1])
    fs.release()
    return path


def test_a_calibration_of_the_upright_image_is_turned_to_the_stored_pixels(tmp_path):
    # the photo stores the sensor's 360 x 640 pixels and asks to be shown turned clockwise (6);
    # the calibration was made on upright 640 x 360 images (as OpenCV's imread turns them)
    sensor = np.zeros((SIZE[0], SIZE[1], 3), np.uint8)
    photo = write_dji_jpeg(tmp_path / "DJI_6.JPG", sensor, {"GpsLatitude": 48.1, "GpsLongitude": 11.5},
                           orientation=6)
    meta = read_metadata(photo)
    assert meta.orientation == 6 and meta.image_size == (SIZE[1], SIZE[0])
    cam = resolve_camera(_calibration(tmp_path / "upright.yaml", K, DIST, SIZE), meta)
    K_sensor, d_sensor, size = turn_camera(K, DIST, SIZE, -1)
    np.testing.assert_allclose(cam.K, K_sensor, atol=1e-12)
    np.testing.assert_allclose(cam.distortion, d_sensor, atol=1e-12)
    assert cam.image_size == size == meta.image_size and "turned back" in cam.source
    # a calibration of the stored layout is taken as it is
    stored = resolve_camera(_calibration(tmp_path / "stored.yaml", K_sensor, d_sensor, size), meta)
    np.testing.assert_allclose(stored.K, K_sensor, atol=1e-9)
    # without the tag the same upright calibration is another aspect ratio: refused
    plain = read_metadata(write_dji_jpeg(tmp_path / "DJI_1.JPG", sensor, {}))
    with pytest.raises(PhotoError, match="another aspect ratio"):
        resolve_camera(tmp_path / "upright.yaml", plain)
