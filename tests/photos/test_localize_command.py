"""``uav-struct localize`` end to end: rendered views written as DJI JPEGs and localized back.

The building is the paper site written as a georeferenced IFC (UTM 32N, conftest); the env
renders it from the IFC at the slab stage and gives the truth and the ``gnss_ins`` prior, which
goes into each JPEG's EXIF GPS and DJI XMP.
"""

import csv
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.cli import main as cli_main
from uav_struct_env.photos import PhotoError, read_ifc_georeference
from uav_struct_env.photos.command import expand_photos
from uav_struct_env.photos.dji_jpeg import dji_fields_from_pose, write_dji_jpeg
from uav_struct_env.provenance import png_settings
from uav_struct_env.site import load_ifc

STAGE = "Level 1/slab"


@pytest.fixture(scope="module")
def flight(tmp_path_factory, georef_ifc):
    folder = tmp_path_factory.mktemp("flight")
    site = load_ifc(georef_ifc, STAGE)
    env = uav_struct_env.parallel_env(site=site, noise="gnss_ins", image_size=(640, 360))
    try:
        obs, infos = env.reset(seed=5)
    finally:
        env.close()
    g = read_ifc_georeference(georef_ifc)
    photos, truth, priors = [], [], []
    for agent in sorted(obs):
        info = infos[agent]
        path = write_dji_jpeg(folder / f"DJI_{agent}.JPG", obs[agent]["image"],
                              dji_fields_from_pose(info["prior_world_from_cam"], g), focal_length_35mm=24)
        photos.append(str(path))
        truth.append(info["world_from_cam"])
        priors.append(info["prior_world_from_cam"])
    calib = folder / "camera.yaml"
    fs = cv2.FileStorage(str(calib), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", infos["uav_0"]["intrinsics"])
    fs.write("distortion_coefficients", np.asarray(infos["uav_0"]["distortion"]).reshape(1, -1))
    fs.release()
    return {"photos": photos, "truth": truth, "priors": priors, "camera": str(calib), "ifc": str(georef_ifc)}


def test_rendered_photos_localize_back_to_the_truth(flight, tmp_path):
    out = tmp_path / "out"
    status = cli_main(["localize", *flight["photos"], "--ifc", flight["ifc"], "--stage", STAGE,
                       "--camera", flight["camera"], "--out", str(out)])
    assert status == 0
    lines = (out / "poses.csv").read_text().splitlines()
    assert lines[0].startswith(f"# Settings: uav-struct-env {uav_struct_env.__version__}")
    rows = list(csv.DictReader(lines[1:]))
    doc = json.loads((out / "poses.json").read_text())
    assert doc["settings"] == lines[0][len("# Settings: "):] and doc["stage"] == STAGE
    for figure in (out / "flight_summary.png", *sorted((out / "overlays").glob("*.png"))):
        assert png_settings(figure) == doc["settings"], figure.name
    assert [r["photo"] for r in rows] == [p["photo"] for p in doc["photos"]] == [
        f"DJI_uav_{k}.JPG" for k in range(4)]
    localized = 0
    for row, rec, truth, prior in zip(rows, doc["photos"], flight["truth"], flight["priors"], strict=True):
        # the prior read back from the JPEG is the env's prior (2-decimal angles, 1e-9 deg positions)
        np.testing.assert_allclose(rec["prior"]["xyz_m"], prior[:3, 3], atol=5e-3)
        assert rec["n_detections"] == len(rec["identities"]) == len(row["identities"].split())
        assert (out / "overlays" / f"{row['photo'].rsplit('.', 1)[0]}.png").stat().st_size > 10_000
        if row["status"] != "localized":
            assert row["reason"] and rec["reason"] == row["reason"]
            continue
        localized += 1
        est = np.array([float(row[k]) for k in ("x_m", "y_m", "z_m")])
        std = np.array([float(row[k]) for k in ("std_x_m", "std_y_m", "std_z_m")])
        error = np.linalg.norm(est - truth[:3, 3])
        assert error < 5 * np.linalg.norm(std) + 0.02, (row["photo"], error, std)
        assert error < np.linalg.norm(prior[:3, 3] - truth[:3, 3])
        assert rec["status"] == "localized" and rec["n_inliers"] >= 4
    assert localized >= 3
    assert (out / "flight_summary.png").stat().st_size > 10_000


def _refused(capsys, argv, out):
    assert cli_main(["localize", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("uav-struct localize: error: "), err
    assert not out.exists()
    return err[0]


def test_refusals_are_one_line_before_any_work(flight, plain_ifc, tmp_path, capsys):
    base = ["--ifc", flight["ifc"], "--stage", STAGE, "--camera", flight["camera"]]
    text = tmp_path / "notes.jpg"
    text.write_text("not a photo")
    assert "is not an image" in _refused(capsys, [str(text), *base], tmp_path / "a")
    bare = tmp_path / "bare.jpg"
    cv2.imwrite(str(bare), np.zeros((36, 64, 3), np.uint8))
    assert "no prior: the photo lacks a GPS position" in _refused(capsys, [str(bare), *base], tmp_path / "b")
    no_geo = [flight["photos"][0], "--ifc", str(plain_ifc), "--stage", STAGE, "--camera", flight["camera"]]
    assert "states no georeferencing" in _refused(capsys, no_geo, tmp_path / "c")
    far = [flight["photos"][0], *base, "--max-distance", "1"]
    assert "from the building's plan, more than 1 m" in _refused(capsys, far, tmp_path / "d")
    bad = tmp_path / "calib.yaml"
    bad.write_text("camera_matrix: [1, 2")
    cal = [flight["photos"][0], "--ifc", flight["ifc"], "--stage", STAGE, "--camera", str(bad)]
    assert "does not parse" in _refused(capsys, cal, tmp_path / "e")
    det = [flight["photos"][0], *base, "--detector", "learned:v9"]
    assert "--detector must be one of ('guided', 'learned', 'learned:landmarks_v1'" in _refused(capsys, det,
                                                                                      tmp_path / "f")


def test_a_user_georeference_or_prior_replaces_a_missing_one(flight, plain_ifc, tmp_path):
    g = read_ifc_georeference(flight["ifc"])
    georef = f"{g.origin_m[0]},{g.origin_m[1]},{g.origin_m[2]},{np.degrees(g.rotation_rad)},32632"
    out = tmp_path / "out"
    assert cli_main(["localize", flight["photos"][0], "--ifc", str(plain_ifc), "--stage", STAGE, "--camera",
                     flight["camera"], "--georef", georef, "--no-figures", "--out", str(out)]) == 0
    rec = json.loads((out / "poses.json").read_text())["photos"][0]
    np.testing.assert_allclose(rec["prior"]["xyz_m"], flight["priors"][0][:3, 3], atol=5e-3)
    assert not (out / "flight_summary.png").exists()


def test_rtk_fixed_photos_report_the_estimate_against_their_rtk_position(flight, tmp_path, capsys):
    # an RTK-fixed photo: the true position (RtkFlag 50), the prior's attitude; the prior weighted as
    # consumer GNSS so that the estimate comes from the image (docs/photos.md, the accuracy protocol)
    g = read_ifc_georeference(flight["ifc"])
    truth, prior = flight["truth"][0], flight["priors"][0].copy()
    prior[:3, 3] = truth[:3, 3]
    fields = {**dji_fields_from_pose(prior, g), "RtkFlag": 50, "RtkStdLon": 0.02, "RtkStdLat": 0.02,
              "RtkStdHgt": 0.03}
    from PIL import Image

    photo = write_dji_jpeg(tmp_path / "DJI_rtk.JPG", np.asarray(Image.open(flight["photos"][0])), fields)
    out = tmp_path / "out"
    assert cli_main(["localize", str(photo), "--ifc", flight["ifc"], "--stage", STAGE, "--camera",
                     flight["camera"], "--prior-sigmas", "3,5,2,5", "--no-figures", "--out", str(out)]) == 0
    assert "RTK-fixed photos: 1 of 1 localized" in capsys.readouterr().out
    row = next(csv.DictReader((out / "poses.csv").read_text().splitlines()[1:]))
    est = np.array([float(row[k]) for k in ("x_m", "y_m", "z_m")])
    assert float(row["rtk_error_m"]) == pytest.approx(np.linalg.norm(est - truth[:3, 3]), abs=2e-3)
    doc = json.loads((out / "poses.json").read_text())
    assert doc["rtk_accuracy"]["rtk_fixed"] == 1 and doc["rtk_accuracy"]["median_m"] == pytest.approx(
        float(row["rtk_error_m"]), abs=1e-4)
    assert "RTK fixed (RtkStd), user sigmas" in row["prior_source"]


def test_help_lists_every_option_with_its_default(capsys):
    with pytest.raises(SystemExit) as stop:
        cli_main(["localize", "--help"])
    assert stop.value.code == 0
    options = capsys.readouterr().out.split("options:", 1)[1]
    for entry in re.split(r"\n  (?=--)", options)[1:]:
        if re.match(r"--[-\w]+ [A-Z]", entry) and not entry.startswith("--version"):
            assert "default" in " ".join(entry.split()), entry
    assert "--max-distance MAX_DISTANCE" in options and "(default: 500.0)" in " ".join(options.split())


def test_a_folder_stands_for_its_jpegs(flight, tmp_path):
    (tmp_path / "none").mkdir()
    with pytest.raises(PhotoError, match="holds no JPEG photo"):
        expand_photos([str(tmp_path / "none")])
    assert expand_photos([str(Path(flight["photos"][0]).parent)]) == sorted(flight["photos"])


@pytest.mark.parametrize("tag", [6, 3, 8])
def test_a_photo_stored_turned_localizes_its_sensor_camera(flight, tmp_path, tag):
    # the same view stored as a sensor turned on its optical axis would store it, with the EXIF tag
    # that turns it upright; the gimbal angles are the sensor's. For the quarter turns the calibration
    # is the upright images' (640 x 360 for a 360 x 640 photo), for the half turn the stored pixels'.
    from PIL import Image

    from localization.geometry.transforms import rotation_angle_deg
    from uav_struct_env.photos import localize_photos
    from uav_struct_env.photos.calibration import load_calibration
    from uav_struct_env.photos.orientation import turn_camera, turn_image, turn_pose, upright_turns

    turns = upright_turns(tag)
    g = read_ifc_georeference(flight["ifc"])
    sensor_prior = np.linalg.inv(turn_pose(np.linalg.inv(flight["priors"][0]), -turns))
    upright = np.asarray(Image.open(flight["photos"][0]))
    photo = write_dji_jpeg(tmp_path / f"DJI_{tag}.JPG", turn_image(upright, -turns),
                           dji_fields_from_pose(sensor_prior, g), orientation=tag)
    up = load_calibration(flight["camera"], (640, 360))
    K, dist, size = turn_camera(up.K, up.distortion, up.image_size, 2) if turns == 2 else (
        up.K, up.distortion, up.image_size)
    camera = tmp_path / "camera.yaml"  # with its image size: the layout it was made in
    fs = cv2.FileStorage(str(camera), cv2.FILE_STORAGE_WRITE)
    for key, value in (("camera_matrix", K), ("distortion_coefficients", dist.reshape(1, -1)),
                       ("image_width", size[0]), ("image_height", size[1])):
        fs.write(key, value)
    fs.release()
    pose = localize_photos([photo], flight["ifc"], stage=STAGE, camera=camera)[0]
    assert pose.success and pose.orientation == tag, pose.failure_reason
    truth = flight["truth"][0]
    error = np.linalg.norm(pose.position - truth[:3, 3])
    assert error < 5 * np.linalg.norm(pose.std[:3]) + 0.02
    assert error < np.linalg.norm(flight["priors"][0][:3, 3] - truth[:3, 3])
    sensor_truth = np.linalg.inv(turn_pose(np.linalg.inv(truth), -turns))
    assert rotation_angle_deg(pose.world_from_cam[:3, :3], sensor_truth[:3, :3]) < 1.0
    w, h = pose.camera.image_size
    assert (w, h) == ((640, 360) if turns == 2 else (360, 640))
    uv = pose.detections_uv
    assert len(uv) >= 4 and np.all((uv > -0.5) & (uv < np.array([w, h]) - 0.5))


def test_the_guided_detector_matches_the_building_model_in_the_photos(flight, tmp_path):
    # --detector guided: the stack renders the IFC stage's model for its templates (it needs the site)
    from uav_struct_env.photos import localize_photos

    options = {"stage": STAGE, "camera": flight["camera"]}
    guided = localize_photos(flight["photos"], flight["ifc"], detector="guided", **options)
    learned = localize_photos(flight["photos"], flight["ifc"], **options)
    assert sum(p.success for p in guided) >= 3, [p.failure_reason for p in guided]
    for pose, truth, prior in zip(guided, flight["truth"], flight["priors"], strict=True):
        if pose.success:
            error = np.linalg.norm(pose.position - truth[:3, 3])
            assert error < 5 * np.linalg.norm(pose.std[:3]) + 0.02
            assert error < np.linalg.norm(prior[:3, 3] - truth[:3, 3])
    # the template matches replace the learned detector's corners where both found one
    same = [g.detections_uv.shape == n.detections_uv.shape and np.allclose(g.detections_uv, n.detections_uv)
            for g, n in zip(guided, learned, strict=True)]
    assert not all(same)
    out = tmp_path / "out"
    assert cli_main(["localize", flight["photos"][0], "--ifc", flight["ifc"], "--stage", STAGE, "--camera",
                     flight["camera"], "--detector", "guided", "--no-figures", "--out", str(out)]) == 0
    assert "guided detector" in json.loads((out / "poses.json").read_text())["settings"]
