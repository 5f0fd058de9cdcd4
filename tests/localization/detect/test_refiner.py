"""The learned detector's patch refiner: patch convention, errors, and the committed model on a
real render (candidates displaced by several pixels come back to the landmark)."""

from __future__ import annotations

import numpy as np
import pytest

from localization.detect.refiner import DEFAULT_REFINER, HALF, PATCH, PatchRefiner, extract_patches


def test_patch_is_centred_on_the_nearest_pixel():
    img = np.arange(40 * 50 * 3, dtype=np.int64).reshape(40, 50, 3)
    patches, anchors = extract_patches(img, [[20.4, 18.6], [25.5, 20.0]], 5)
    assert anchors.tolist() == [[20, 19], [26, 20]]  # round half to even: 25.5 -> 26
    assert np.array_equal(patches[0], img[17:22, 18:23])
    assert np.array_equal(patches[0, 2, 2], img[19, 20])  # centre cell = anchor pixel (v, u)


def test_patch_border_replicates():
    img = np.arange(10 * 12, dtype=np.uint8).reshape(10, 12, 1)
    patches, anchors = extract_patches(img, [[0.2, 9.4]], 5)
    assert anchors.tolist() == [[0, 9]]
    p = patches[0, :, :, 0]
    assert np.array_equal(p[2, 2:], img[9, 0:3, 0])  # centre row, right half inside
    assert np.array_equal(p[:, 0], p[:, 2])  # columns left of the image repeat column 0
    assert np.array_equal(p[4], p[2])  # rows below the image repeat the last row


def test_patch_errors():
    with pytest.raises(ValueError, match="odd"):
        extract_patches(np.zeros((10, 10, 3), np.uint8), [[5, 5]], 4)
    with pytest.raises(ValueError, match=r"\(H, W, C\)"):
        extract_patches(np.zeros((10, 10), np.uint8), [[5, 5]])
    with pytest.raises(FileNotFoundError, match="refiner model not found"):
        PatchRefiner("/nonexistent/refiner.onnx")


needs_model = pytest.mark.skipif(not DEFAULT_REFINER.is_file(), reason="no committed refiner")


@needs_model
def test_refiner_arguments():
    with pytest.raises(ValueError, match="iterations"):
        PatchRefiner(iterations=0)
    r = PatchRefiner()
    with pytest.raises(ValueError, match="types has 1 entries for 2"):
        r.refine(np.zeros((64, 64, 3), np.uint8), np.zeros((2, 2)), [0])
    uv, scores = r.refine(np.zeros((64, 64, 3), np.uint8), np.zeros((0, 2)), [])
    assert uv.shape == (0, 2) and scores.shape == (0,)
    assert PATCH == 2 * HALF + 1


@needs_model
def test_refiner_pulls_displaced_candidates_back_on_a_render():
    """Slab corners of a paper-site render, displaced by 5 px in eight directions, are refined
    to within 2 px of the truth (median < 1 px) and keep a high score; points on bare ground
    far from every landmark score low."""
    pytest.importorskip("pybullet")
    from localization.geometry.transforms import look_at
    from uav_struct_env.sim.world import SiteWorld
    from uav_struct_env.site import paper_site

    site = paper_site("slab", marker_size=None)
    with SiteWorld(site, image_size=(1280, 720), rng=np.random.default_rng(7)) as world:
        centre = site.center
        cam_from_world = look_at(centre + np.array([-8.0, -28.0, 17.0]), centre)
        res = world.render(cam_from_world, depth=True)
        truth = world.landmark_truth("slab_corners", cam_from_world, None, res)
    gt = np.asarray(truth["uv"])[np.asarray(truth["visible"], bool)]
    assert len(gt) >= 3
    angles = np.arange(8) * np.pi / 4
    shifts = 5.0 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    start = (gt[:, None, :] + shifts[None]).reshape(-1, 2)
    uv, scores = PatchRefiner().refine(res.rgb, start, np.ones(len(start), int))
    err = np.hypot(*(uv - np.repeat(gt, 8, axis=0)).T)
    assert np.median(err) < 1.0 and np.max(err) < 2.0
    assert np.median(scores) > 0.9
    ground = np.array([[60.0, 680.0], [1220.0, 690.0], [640.0, 700.0]])
    _, s_ground = PatchRefiner().refine(res.rgb, ground, np.ones(3, int))
    assert np.all(s_ground < 0.5)


def test_onnx_net_errors_name_the_bad_value(tmp_path):
    from localization.detect.onnx_net import OnnxNet

    with pytest.raises(FileNotFoundError, match="ONNX model not found: .*missing.onnx"):
        OnnxNet(tmp_path / "missing.onnx")
    with pytest.raises(ValueError, match="threads must be an int >= 1, got 0"):
        OnnxNet(DEFAULT_REFINER, threads=0)
