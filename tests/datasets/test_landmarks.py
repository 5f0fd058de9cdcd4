"""The landmark dataset generator: format, labels inside the image, seeded determinism."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from uav_struct_env.datasets import LANDMARK_TYPES, DatasetConfig, generate, load_labels
from uav_struct_env.datasets.__main__ import main as cli_main
from uav_struct_env.errors import ConfigError


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("lm")
    cli_main([str(out), "--layouts", "1", "--views", "2", "--seed", "7", "--scale", "0.25"])
    return out


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
    from localization.geometry import project
    from uav_struct_env.site import random_site

    data = load_labels(tiny_dataset)
    rng = np.random.default_rng([7, 0])
    stage = str(rng.choice(["slab", "columns"]))
    site = random_site(rng, stage=stage, marker_size=[None, 0.5, 1.0][int(rng.integers(3))])
    xyz = {i: p for name in LANDMARK_TYPES
           for i, p in zip(site.landmarks(name).ids, site.landmarks(name).xyz, strict=True)}
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

    from localization.geometry import project
    from uav_struct_env.site import ifc_stages, load_ifc

    duplex = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"
    out = tmp_path / "duplex"
    assert cli_main([str(out), "--site", str(duplex), "--layouts", "2", "--views", "2",
                     "--seed", "3", "--scale", "0.25", "--renderer", "tiny"]) == 0
    data = load_labels(out)
    assert data["config"]["site"] == str(duplex)
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
    with pytest.raises(ConfigError, match=r"activity must be one of \('none', 'light', 'busy'\)"):
        DatasetConfig(activity="crowded")
