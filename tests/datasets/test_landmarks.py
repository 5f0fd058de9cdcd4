"""The landmark dataset generator: format, labels inside the image, seeded determinism."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from uav_struct_env.datasets import LANDMARK_TYPES, DatasetConfig, generate, load_labels
from uav_struct_env.datasets.__main__ import main as cli_main
from uav_struct_env.errors import ConfigError


@pytest.fixture(scope="module")
def tiny_dataset(tiny_landmark_dataset):
    """``--layouts 1 --views 2 --seed 7 --scale 0.25`` (tests/conftest.py; read only)."""
    return tiny_landmark_dataset


def _layout_landmarks(seed: int, layout: int) -> dict[int, np.ndarray]:
    """Landmark id -> world position of a random-site layout (its first draws, as the generator)."""
    from uav_struct_env.site import random_site

    rng = np.random.default_rng([seed, layout])
    stage = str(rng.choice(["slab", "columns"]))
    site = random_site(rng, stage=stage, marker_size=[None, 0.5, 1.0][int(rng.integers(3))])
    return {i: p for name in LANDMARK_TYPES
            for i, p in zip(site.landmarks(name).ids, site.landmarks(name).xyz, strict=True)}


def test_format_and_labels(tiny_dataset):
    data = load_labels(tiny_dataset)
    assert data["types"] == list(LANDMARK_TYPES)
    assert data["image_size"] == [320, 180]
    assert len(data["images"]) == 2
    n = 0
    for rec in data["images"]:
        img = cv2.imread(str(tiny_dataset / rec["file"]))
        assert img.shape == (180, 320, 3)
        kps = np.array(rec["keypoints"], dtype=np.float64).reshape(-1, 4)
        n += len(kps)
        assert np.all((kps[:, 0] >= -0.5) & (kps[:, 0] < 319.5))
        assert np.all((kps[:, 1] >= -0.5) & (kps[:, 1] < 179.5))
        assert set(kps[:, 2].astype(int)) <= {0, 1, 2}
        assert np.asarray(rec["K"]).shape == (3, 3)
        assert np.asarray(rec["cam_from_world"]).shape == (4, 4)
    assert n > 0  # the camera is aimed at the building


def test_labels_match_projection(tiny_dataset):
    """Keypoints are the projections of the site's landmarks with the saved K and pose."""
    from localization.geometry.transforms import project

    data = load_labels(tiny_dataset)
    xyz = _layout_landmarks(7, 0)
    for rec in data["images"]:
        for u, v, _, i in rec["keypoints"]:
            K, T = np.asarray(rec["K"]), np.asarray(rec["cam_from_world"])
            uv, _ = project(K, T, xyz[int(i)][None])
            assert np.allclose(uv[0], (u, v), atol=1e-6)


def test_seeded(tmp_path, tiny_dataset):
    cfg = DatasetConfig(n_layouts=1, views_per_layout=2, seed=7, scale=0.25)
    path = generate(cfg, tmp_path, progress=False)
    a = json.loads(path.read_text())["images"]
    b = load_labels(tiny_dataset)["images"]
    assert [r["keypoints"] for r in a] == [r["keypoints"] for r in b]


def test_bad_config():
    with pytest.raises(ConfigError, match="scale"):
        DatasetConfig(scale=2.0)
    with pytest.raises(ConfigError, match="n_layouts"):
        DatasetConfig(n_layouts=0)


def test_an_ifc_building_dataset_labels_its_own_landmarks(tmp_path):
    """``--site building.ifc``: every layout is that building at one of its stages."""
    pytest.importorskip("ifcopenshell")
    from pathlib import Path

    from localization.geometry.transforms import project
    from uav_struct_env.site import ifc_stages, load_ifc

    duplex = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"
    out = tmp_path / "duplex"
    # seed 2: layout 0 at Roof/slab, layout 1 at Level 2/slab (both stages), 128 px textures (cheap)
    assert cli_main([str(out), "--site", str(duplex), "--layouts", "2", "--views", "1",
                     "--seed", "2", "--scale", "0.25", "--renderer", "tiny"]) == 0
    data = load_labels(out)
    assert data["config"]["site"] == str(duplex)
    assert sorted({rec["stage"] for rec in data["images"]}) == sorted(ifc_stages(duplex))
    n = 0
    for rec in data["images"]:
        assert rec["stage"] in ifc_stages(duplex)
        site = load_ifc(duplex, rec["stage"])
        xyz = {i: p for name in LANDMARK_TYPES
               for i, p in zip(site.landmarks(name).ids, site.landmarks(name).xyz, strict=True)}
        for u, v, _, i in rec["keypoints"]:
            uv, _ = project(np.asarray(rec["K"]), np.asarray(rec["cam_from_world"]), xyz[int(i)][None])
            assert np.allclose(uv[0], (u, v), atol=1e-6)
            n += 1
    assert n > 0


def test_stages_limit_the_layouts_to_those_stages(tmp_path, capsys):
    """``--stages A``: every layout of the building at stage A; a bad stage list is refused in one line."""
    pytest.importorskip("ifcopenshell")
    from pathlib import Path

    from uav_struct_env.site import ifc_stages

    duplex = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"
    first, top = ifc_stages(duplex)[0], ifc_stages(duplex)[-1]
    out = tmp_path / "first"
    # seed 8: without --stages both layouts would be at the top stage (the check can fail); with it,
    # 128 px textures (cheap)
    assert cli_main([str(out), "--site", str(duplex), "--stages", first, "--layouts", "2", "--views", "1",
                     "--seed", "8", "--scale", "0.25", "--renderer", "tiny"]) == 0
    data = load_labels(out)
    assert first != top and {rec["stage"] for rec in data["images"]} == {first}
    assert data["config"]["stages"] == [first] and f"stages {first}" in data["settings"]
    with pytest.raises(ConfigError, match=r"DatasetConfig.stages: \['Level 9/slab'\] not stages of duplex"):
        DatasetConfig(site=str(duplex), stages=("Level 9/slab",))
    with pytest.raises(ConfigError, match="applies to a building file"):
        DatasetConfig(stages=("slab",))
    assert cli_main([str(tmp_path / "no"), "--site", str(duplex), "--stages", "Attic/slab"]) == 2
    assert "not stages of duplex.ifc" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()


def test_a_missing_site_file_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "never"
    assert cli_main([str(out), "--site", str(tmp_path / "missing.ifc")]) == 2
    assert "DatasetConfig.site must be 'random' or an existing site file" in capsys.readouterr().err
    assert not out.exists()


def test_site_activity_hides_labels_and_changes_nothing_else(tmp_path, tiny_dataset):
    """--activity busy: the same views (its own seed), pixels differ, labels only lose landmarks."""
    out = tmp_path / "busy"
    assert cli_main([str(out), "--layouts", "1", "--views", "2", "--seed", "7", "--scale", "0.25",
                     "--activity", "busy"]) == 0
    busy, plain = load_labels(out), load_labels(tiny_dataset)
    assert busy["config"]["activity"] == "busy"
    for b, p in zip(busy["images"], plain["images"], strict=True):
        assert b["cam_from_world"] == p["cam_from_world"]
        kb = {tuple(k) for k in b["keypoints"]}
        kp = {tuple(k) for k in p["keypoints"]}
        assert kb <= kp
        assert not np.array_equal(cv2.imread(str(out / b["file"])), cv2.imread(str(tiny_dataset / p["file"])))
    with pytest.raises(ConfigError, match=r"activity must be one of \('none', 'light', 'busy', 'mixed'\)"):
        DatasetConfig(activity="crowded")


@pytest.mark.slow  # seven busy-site layouts rendered (`make test-slow`)
def test_mixed_activity_cycles_the_presets_over_the_layouts(tmp_path):
    """--activity mixed: layout i is rendered exactly as the (i % 3)-th preset's dataset renders it."""
    common = ["--views", "1", "--seed", "7", "--scale", "0.25"]
    # layout i is drawn from [seed, i] alone: the none set needs only its layout 0
    for level, layouts in (("mixed", "3"), ("none", "1"), ("busy", "3")):
        assert cli_main([str(tmp_path / level), "--layouts", layouts, *common, "--activity", level]) == 0
    mixed = load_labels(tmp_path / "mixed")
    assert mixed["config"]["activity"] == "mixed"
    assert [r["activity"] for r in mixed["images"]] == ["none", "light", "busy"]
    for layout, level in ((0, "none"), (2, "busy")):
        same = load_labels(tmp_path / level)["images"][layout]
        rec = mixed["images"][layout]
        assert rec["keypoints"] == same["keypoints"] and rec["cam_from_world"] == same["cam_from_world"]
        image = (tmp_path / "mixed" / rec["file"]).read_bytes()
        assert image == (tmp_path / level / same["file"]).read_bytes()
    assert "activity" not in load_labels(tmp_path / "busy")["images"][0]


# ---------------------------------------------------------------- --camera


@pytest.fixture(scope="module")
def camera_datasets(tmp_path_factory):
    """The tiny dataset's views through ``--camera mavic2pro`` and ``--camera mixed``; the mixed
    one has two views more (views 0 and 1 are those of a two-view dataset: each view continues the
    layout's draws), the ideal dataset the ``--imaging`` test compares with."""
    out = {}
    for camera, views in (("mavic2pro", "2"), ("mixed", "4")):
        out[camera] = tmp_path_factory.mktemp(camera)
        assert cli_main([str(out[camera]), "--layouts", "1", "--views", views, "--seed", "7",
                         "--scale", "0.25", "--camera", camera]) == 0
    return out


def test_mavic_labels_are_where_the_lens_shows_the_landmarks(camera_datasets):
    """Labels = LensView.project (distortion, rolling shutter) of the landmarks, scaled to the image."""
    from localization.geometry.transforms import project
    from uav_struct_env.sim.lens import MAVIC2PRO, LensView, Motion
    from uav_struct_env.sim.uav import FlightLimits

    data = load_labels(camera_datasets["mavic2pro"])
    assert data["config"]["camera"] == "mavic2pro"
    lens = LensView(MAVIC2PRO, 1280, 720)
    xyz = _layout_landmarks(7, 0)
    limits = FlightLimits()
    off_pinhole = 0.0
    for rec in data["images"]:
        assert rec["camera"] == "mavic2pro"
        np.testing.assert_array_equal(rec["distortion"], MAVIC2PRO.distortion)
        np.testing.assert_allclose(rec["K"], lens.camera.scaled(320, 180).K, atol=1e-12)
        T = np.asarray(rec["cam_from_world"])
        vel, ang = np.asarray(rec["velocity"]), np.asarray(rec["angular_velocity"])
        # Within the flight limits: speed, climb/sink, yaw rate (world z), gimbal rate (camera x).
        assert np.hypot(*vel[:2]) <= limits.max_horizontal_speed
        assert -limits.max_descent_speed <= vel[2] <= limits.max_ascent_speed
        assert abs(ang[2]) <= limits.max_yaw_rate + 1e-12
        assert abs(ang @ T[0, :3]) <= limits.max_gimbal_rate + 1e-12
        assert np.linalg.norm(ang) > 0
        kps = np.asarray(rec["keypoints"], dtype=np.float64).reshape(-1, 4)
        assert len(kps) > 0
        pts = np.array([xyz[int(i)] for i in kps[:, 3]])
        uv, _, in_field = lens.project(T, pts, Motion(vel, ang))
        assert in_field.all()
        np.testing.assert_allclose(kps[:, :2], (uv + 0.5) * 0.25 - 0.5, atol=1e-6)
        pin, _ = project(lens.camera.scaled(320, 180).K, T, pts)
        off_pinhole = max(off_pinhole, float(np.abs(pin - kps[:, :2]).max()))
    assert off_pinhole > 2.0  # the lens and the shutter move labels by pixels: the test can tell


def test_mixed_is_every_other_image_of_the_paper_and_mavic_datasets(tiny_dataset, camera_datasets):
    """Same views (own seed stream); paper views byte-identical to the paper dataset, others to mavic2pro."""
    mixed = load_labels(camera_datasets["mixed"])
    paper = load_labels(tiny_dataset)
    mavic = load_labels(camera_datasets["mavic2pro"])
    raw = json.loads((tiny_dataset / "labels.json").read_text())
    assert "camera" not in raw["config"]  # a paper dataset is written as before cameras existed
    assert all("camera" not in rec for rec in raw["images"])
    assert paper["config"]["camera"] == "paper"  # ... and read with the defaults filled in
    assert [r["camera"] for r in mixed["images"]] == ["paper", "mavic2pro"] * 2
    for rec in mixed["images"][:2]:  # the views the two-view paper and mavic2pro datasets have
        twins = paper if rec["camera"] == "paper" else mavic
        twin = twins["images"][rec["view"]]
        assert rec == twin
        image = Path(mixed["root"], rec["file"]).read_bytes()
        assert image == Path(twins["root"], twin["file"]).read_bytes()
    assert paper["images"][1]["keypoints"] != mavic["images"][1]["keypoints"]
    assert paper["images"][1]["cam_from_world"] == mavic["images"][1]["cam_from_world"]


def test_a_blob_at_each_landmark_lands_on_its_label():
    """deliver_view on a synthetic render: blobs at the landmarks end up within 0.1 px of the labels."""
    from uav_struct_env.datasets.landmarks import _lens_view, deliver_view, random_motion

    lens = _lens_view("mavic2pro", 1280, 720)
    T = np.eye(4)
    gx, gy = np.meshgrid(np.linspace(-0.5, 0.5, 7), np.linspace(-0.25, 0.25, 5))
    X = np.stack([gx.ravel() * 25.0, gy.ravel() * 25.0, np.full(gx.size, 25.0)], axis=1)
    Kr = lens.render_camera.K
    q = X[:, :2] / X[:, 2:] * [Kr[0, 0], Kr[1, 1]] + Kr[:2, 2]
    yy, xx = np.mgrid[0: lens.render_camera.height, 0: lens.render_camera.width]
    img = np.zeros(xx.shape, np.float32)
    for u, v in q:  # Gaussian blobs, sigma 3 render px, at the render camera's projections
        img += 250.0 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / 18.0)
    rgb = np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    depth = np.full(xx.shape, 25.0, np.float32)
    truth = [{"ids": np.arange(len(X)), "xyz": X, "uv": q, "visible": np.ones(len(X), bool)}]
    motion = random_motion(np.random.default_rng(3), T)
    out, kps, K = deliver_view(rgb, depth, truth, T, lens, (640, 360), motion)
    static, *_ = lens.project(T, X)
    kp = np.array(kps)[:, :2]
    moved = (static[np.array(kps)[:, 3].astype(int)] + 0.5) * 0.5 - 0.5
    assert np.abs(kp - moved).max() > 2.0  # the shutter moved the landmarks: the check can fail
    g = out[..., 0].astype(np.float64)
    errors = []
    for u, v in kp:
        r0, c0 = int(round(v)), int(round(u))
        if not (7 <= r0 < 360 - 7 and 7 <= c0 < 640 - 7):
            continue
        patch = np.clip(g[r0 - 6: r0 + 7, c0 - 6: c0 + 7] - 3.0, 0, None)
        pr, pc = np.mgrid[r0 - 6: r0 + 7, c0 - 6: c0 + 7]
        errors.append(np.hypot(np.sum(patch * pc) / patch.sum() - u, np.sum(patch * pr) / patch.sum() - v))
    assert len(errors) >= 25
    assert max(errors) <= 0.1, np.round(errors, 3)  # measured: 0.015 px


def test_a_bad_camera_is_refused_in_one_line(tmp_path, capsys):
    expected = r"camera must be one of \('paper', 'mavic2pro', 'mixed'\), got 'gopro'"
    with pytest.raises(ConfigError, match=expected):
        DatasetConfig(camera="gopro")
    out = tmp_path / "never"
    assert cli_main([str(out), "--camera", "gopro"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "got 'gopro'" in err
    assert err.startswith("python -m uav_struct_env.datasets: error: DatasetConfig.camera must be one of")
    assert not out.exists()


# ---------------------------------------------------------------- --imaging


def test_camera_imaging_degrades_every_other_pair_of_images_and_nothing_else(tmp_path, camera_datasets):
    """--imaging mixed: views 2 and 3 of 4 get the camera imaging (noise, blur, JPEG); labels,
    poses and the other images are those of the ideal dataset; the noise is seeded."""
    args = ["--layouts", "1", "--views", "4", "--seed", "7", "--scale", "0.25", "--camera", "mixed"]
    for name in ("mixed", "again"):
        assert cli_main([str(tmp_path / name), *args, "--imaging", "mixed"]) == 0
    ideal_dir = camera_datasets["mixed"]  # the same arguments without --imaging
    ideal, mixed = load_labels(ideal_dir), load_labels(tmp_path / "mixed")
    assert ideal["config"]["n_layouts"] == 1 and ideal["config"]["views_per_layout"] == 4
    assert (ideal["config"]["seed"], ideal["config"]["scale"]) == (7, 0.25)
    assert "imaging" not in json.loads((ideal_dir / "labels.json").read_text())["config"]
    assert ideal["config"]["imaging"] == "ideal" and mixed["config"]["imaging"] == "mixed"
    assert [r["imaging"] for r in mixed["images"]] == ["ideal", "ideal", "camera", "camera"]
    assert [r["camera"] for r in mixed["images"]] == ["paper", "mavic2pro"] * 2
    for a, b in zip(ideal["images"], mixed["images"], strict=True):
        b_without = {k: v for k, v in b.items() if k != "imaging"}
        assert {k: v for k, v in a.items() if k != "imaging"} == b_without
        img_a = cv2.imread(str(ideal_dir / a["file"])).astype(np.float64)
        img_b = cv2.imread(str(tmp_path / "mixed" / b["file"])).astype(np.float64)
        diff = float(np.abs(img_a - img_b).mean())
        if b["imaging"] == "ideal":
            assert diff == 0.0
        else:  # measured 0.84 / 0.88 DN at this scale: noise and JPEG, averaged 4 x 4 by the downscaling
            assert 0.3 < diff < 3.0, diff
        again = tmp_path / "again" / b["file"]
        assert again.read_bytes() == (tmp_path / "mixed" / b["file"]).read_bytes()
    expected = r"imaging must be one of \('ideal', 'camera', 'mixed'\), got 'jpeg'"
    with pytest.raises(ConfigError, match=expected):
        DatasetConfig(imaging="jpeg")


class _Bodies:
    """Records the boxes ``_add_clutter`` places (their half extents and poses)."""

    def __init__(self) -> None:
        self.boxes: list[tuple[tuple, np.ndarray]] = []

    def add_body(self, half_extents, rgba, pose) -> None:
        self.boxes.append((tuple(half_extents), np.asarray(pose)))


def test_clutter_on_a_stage_without_a_floor_stays_on_the_ground():
    """A building whose stage is columns alone (a steel frame): the ground's clutter, none on a slab.

    The generator stopped on such a stage (``max()`` of no slab tops) and no dataset of the
    corpus's steel frame could be rendered.
    """
    from types import SimpleNamespace

    from uav_struct_env.datasets.landmarks import _add_clutter

    site = SimpleNamespace(footprint_bounds=(0.0, 0.0, 20.0, 12.0), floor=())
    for seed in range(20):
        bodies = _Bodies()
        _add_clutter(bodies, site, np.random.default_rng(seed))
        assert len(bodies.boxes) >= 3
        # every box stands on the ground or on a stack outside the footprint (none up on a floor)
        outside = [not (0 <= pose[0, 3] <= 20 and 0 <= pose[1, 3] <= 12) for _, pose in bodies.boxes]
        assert all(outside), seed
