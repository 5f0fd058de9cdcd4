"""The learned detector: heatmap decoding on synthetic heatmaps, matching, and a real render."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from localization.detect.learned import (
    DEFAULT_MODEL,
    OPERATING_POINTS,
    LearnedDetector,
    decode,
    match_detections,
    operating_point_for,
    subpixel_parabola,
)
from localization.detect.refiner import DEFAULT_REFINER
from localization.detect.weights import WEIGHT_NAMES, weight_set


def _gauss(h, w, centres, sigma=1.0, peak=1.0):
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.zeros((h, w))
    for cu, cv in centres:
        out = np.maximum(out, peak * np.exp(-((xs - cu) ** 2 + (ys - cv) ** 2) / (2 * sigma**2)))
    return out.astype(np.float32)


def test_parabola_recovers_gaussian_centre(rng):
    for _ in range(20):
        cu, cv = rng.uniform(3, 27), rng.uniform(3, 17)
        heat = _gauss(20, 30, [(cu, cv)])
        r, c = np.unravel_index(np.argmax(heat), heat.shape)
        off = subpixel_parabola(heat, np.array([r]), np.array([c]))[0]
        assert abs(c + off[0] - cu) < 1e-3 and abs(r + off[1] - cv) < 1e-3


def test_decode_heatmap_only_subpixel_in_pixels():
    centres = [(5.3, 4.7), (20.6, 12.2)]  # cells
    heat = _gauss(20, 30, centres)[None]
    uv, scores, kinds = decode(heat, (0,), use_offsets=False, score_threshold=0.5)
    want = (np.array(centres) + 0.5) * 4 - 0.5  # stride 4, pixel-centre convention
    order = np.argsort(uv[:, 0])
    assert np.allclose(uv[order], want, atol=0.01)
    assert np.all(scores > 0.9) and np.all(kinds == 0)


def test_decode_offsets_threshold_types_and_bounds():
    h, w = 20, 30
    heat = np.zeros((3, h, w), np.float32)
    off = np.zeros((2, h, w), np.float32)
    heat[0, 5, 7], off[:, 5, 7] = 0.9, (0.25, -0.4)
    heat[1, 10, 3] = 0.2  # below the threshold
    heat[2, 19, 29], off[:, 19, 29] = 0.8, (0.4, 0.4)  # refined outside a 118 x 78 image
    out = np.concatenate([heat, off])
    uv, scores, kinds = decode(out, (0, 1, 2), image_size=(118, 78), score_threshold=0.3)
    assert kinds.tolist() == [0]
    assert np.allclose(uv[0], ((7.25 + 0.5) * 4 - 0.5, (4.6 + 0.5) * 4 - 0.5))
    uv, _, kinds = decode(out, (2,), score_threshold=0.3)
    assert kinds.tolist() == [2]


def test_decode_nms_keeps_best_of_close_peaks():
    heat = np.zeros((1, 20, 30), np.float32)
    heat[0, 5, 5], heat[0, 5, 7], heat[0, 15, 20] = 0.9, 0.8, 0.7  # 8 px apart, then far
    out = np.concatenate([heat, np.zeros((2, 20, 30), np.float32)])
    uv, scores, _ = decode(out, (0,), nms_px=10.0)
    assert np.allclose(scores, [0.9, 0.7])
    uv, scores, _ = decode(out, (0,), nms_px=4.0)
    assert np.allclose(scores, [0.9, 0.8, 0.7])
    with pytest.raises(ValueError, match="out of range"):
        decode(out, (1,))


def test_decode_votes_recover_a_landmark_merged_into_its_neighbours_peak():
    # Two corners 1.5 cells apart, as a thin opening seen at a grazing angle gives: one heatmap
    # peak (the weaker corner's cell is its neighbour), but the cells around each corner carry
    # offsets pointing at that corner, as the network is trained to.
    h, w = 20, 30
    corners = np.array([[10.2, 8.3], [10.4, 9.8]])  # (u, v) in cells
    heat = np.zeros((1, h, w), np.float32)
    off = np.zeros((2, h, w), np.float32)
    for r, c, score, k in [(8, 10, 0.6, 0), (9, 10, 0.8, 1), (10, 10, 0.7, 1), (7, 10, 0.3, 0)]:
        heat[0, r, c] = score
        off[:, r, c] = corners[k] - (c, r)
    out = np.concatenate([heat, off])
    want = (corners + 0.5) * 4 - 0.5
    uv, scores, _ = decode(out, (0,), score_threshold=0.3, nms_px=4.0)
    assert len(uv) == 1 and np.allclose(uv[0], want[1])  # peaks only: the upper corner is lost
    uv, scores, _ = decode(out, (0,), score_threshold=0.3, nms_px=4.0, vote_threshold=0.5)
    assert np.allclose(uv, want[[1, 0]]) and np.allclose(scores, [0.8, 0.6])
    # A vote below its threshold proposes nothing; votes need the offset channels.
    uv, _, _ = decode(out, (0,), score_threshold=0.3, nms_px=4.0, vote_threshold=0.65)
    assert len(uv) == 1
    with pytest.raises(ValueError, match="vote_threshold needs the offset channels"):
        decode(heat, (0,), use_offsets=False, vote_threshold=0.5)


def test_decode_votes_never_displace_a_peak():
    # A strong non-peak cell (0.7, next to the 0.8 peak) whose offsets point onto a weak but
    # separate peak (0.35): in plain score order it would suppress that peak; peaks go first.
    h, w = 20, 30
    heat = np.zeros((1, h, w), np.float32)
    off = np.zeros((2, h, w), np.float32)
    heat[0, 9, 10], heat[0, 9, 11], heat[0, 9, 13] = 0.8, 0.7, 0.35
    off[:, 9, 11] = (1.9, 0.0)  # points at cell (9, 12.9), 0.4 px from the weak peak
    out = np.concatenate([heat, off])
    peaks_only = decode(out, (0,), score_threshold=0.3, nms_px=4.0)
    with_votes = decode(out, (0,), score_threshold=0.3, nms_px=4.0, vote_threshold=0.5)
    assert np.allclose(peaks_only[1], [0.8, 0.35])
    assert np.allclose(with_votes[0], peaks_only[0]) and np.allclose(with_votes[1], [0.8, 0.35])


def test_match_detections_one_to_one_within_radius():
    gt = np.array([[10.0, 10.0], [50.0, 50.0]])
    uv = np.array([[11.0, 10.0], [10.5, 10.0], [60.0, 50.0]])
    m, d = match_detections(uv, gt, 3.0)
    assert m.tolist() == [-1, 0, -1]
    assert d[1] == pytest.approx(0.5) and np.isnan(d[0])
    m, _ = match_detections(np.zeros((0, 2)), gt)
    assert m.shape == (0,)


def test_bad_arguments():
    with pytest.raises(ValueError, match="landmarks must be"):
        LearnedDetector("aruco")
    with pytest.raises(ValueError, match="score_threshold"):
        LearnedDetector("column_tops", score_threshold=2.0)
    with pytest.raises(FileNotFoundError, match="not found"):
        LearnedDetector("column_tops", model="/nonexistent.onnx")
    with pytest.raises(ValueError, match="refine_threshold"):
        LearnedDetector("column_tops", refine_threshold=1.5)
    with pytest.raises(ValueError, match="operating_point must be one of"):
        LearnedDetector("column_tops", operating_point="fast")
    with pytest.raises(ValueError, match="association must be one of"):
        operating_point_for("hungarian")
    with pytest.raises(FileNotFoundError, match="refiner model not found"):
        LearnedDetector("column_tops", refiner="/nonexistent/refiner.onnx")
    with pytest.raises(ValueError, match=r"vote_threshold must be a number in \(0, 1\], got 0"):
        LearnedDetector("column_tops", vote_threshold=0)
    with pytest.raises(ValueError, match="votes must be True or False, got 'yes'"):
        LearnedDetector("column_tops", votes="yes")


needs_model = pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed model")


@needs_model
def test_operating_points():
    assert operating_point_for("robust") == "recall" and operating_point_for("paper") == "balanced"
    def point(d):
        return d.score_threshold, d.refine_threshold

    recall = LearnedDetector("all", operating_point="recall")
    assert point(recall) == OPERATING_POINTS["recall"]
    assert recall.vote_threshold == recall.score_threshold  # votes: the keypoint threshold
    mixed = LearnedDetector("all", operating_point="recall", refine_threshold=0.6,
                            vote_threshold=0.4)
    assert point(mixed) == (OPERATING_POINTS["recall"][0], 0.6) and mixed.vote_threshold == 0.4
    assert point(LearnedDetector("all")) == OPERATING_POINTS["balanced"]
    assert "vote_threshold=None" in repr(LearnedDetector("all", votes=False))
    study = LearnedDetector.for_localizer("slab_corners", 1280, "robust")
    assert study.scale == 0.5 and point(study) == OPERATING_POINTS["recall"]
    small = LearnedDetector.for_localizer("all", 320, "paper")
    assert small.scale == 1.0 and point(small) == OPERATING_POINTS["balanced"]


@needs_model
def test_bad_image():
    with pytest.raises(ValueError, match="uint8 RGB"):
        LearnedDetector("column_tops").detect(np.zeros((10, 10)), {})


@pytest.fixture(scope="module")
def _shared_column_tops_render():
    """A 1280 x 720 render of the paper site's columns stage and its column-top truth, made once
    for the module (1.4 s of CPU a render)."""
    pytest.importorskip("pybullet")
    from localization.geometry.transforms import look_at
    from uav_struct_env.sim.world import SiteWorld
    from uav_struct_env.site import paper_site

    site = paper_site("columns", marker_size=1.0)
    with SiteWorld(site, image_size=(1280, 720), rng=np.random.default_rng(123)) as world:
        cam_from_world = look_at(site.center + np.array([-6.0, -30.0, 16.0]), site.center)
        res = world.render(cam_from_world, depth=True)
        return res, world.landmark_truth("column_tops", cam_from_world, None, res)


@pytest.fixture
def paper_column_tops_render(_shared_column_tops_render):
    """The shared render and truth, copied: each test gets arrays no other test has touched."""
    return copy.deepcopy(_shared_column_tops_render)


@needs_model
@pytest.mark.parametrize("refiner", [True, False], ids=["refined", "network-only"])
def test_real_render_column_tops(refiner, paper_column_tops_render):
    """On a paper-site render the detector finds the visible column tops within 3 px, with or
    without the full-resolution refiner."""
    res, truth = paper_column_tops_render
    det = LearnedDetector("column_tops", refiner=refiner).detect(
        res.rgb, {"landmarks": {"column_tops": truth}, "image_size": (1280, 720)}
    )
    n_visible = int(np.sum(truth["visible"]))
    n_true = int(np.sum(det.true_ids >= 0))
    assert n_visible >= 8
    assert n_true >= n_visible - 2
    assert len(det) - n_true <= 2
    assert det.scores is not None and np.all(det.scores >= 0.3)


@needs_model
def test_candidates_are_the_network_output_that_the_refiner_then_places(paper_column_tops_render):
    """``candidates`` is ``detect_all`` without refinement; the refiner moves them onto the truth."""
    res, truth = paper_column_tops_render
    raw = LearnedDetector("column_tops", refiner=False, corner_window=0)
    cand = raw.candidates(res.rgb)
    for a, b in zip(cand, raw.detect_all(res.rgb), strict=True):
        np.testing.assert_array_equal(a, b)
    refined, _, _ = LearnedDetector("column_tops").detect_all(res.rgb)
    gt = truth["uv"][truth["visible"]]
    nearest = [np.median([np.min(np.hypot(*(uv - g).T)) for g in gt]) for uv in (cand[0], refined)]
    assert len(gt) >= 8 and nearest[1] < nearest[0] < 3.0


def test_truth_bookkeeping_with_no_visible_landmark():
    """Detections in a view whose landmarks are all hidden (a busy site): every one is false.

    The detector's output is fixed here; what is tested is the scoring of ``true_ids``, which
    indexed an empty array (IndexError in the study) when nothing was visible.
    """
    det = LearnedDetector("slab_corners")
    uv = np.array([[100.0, 50.0], [300.0, 200.0]])
    det.detect_all = lambda image: (uv, np.array([0.9, 0.8]), np.zeros(2, np.int64))
    hidden = {"ids": np.array([3, 4]), "uv": np.array([[100.0, 50.0], [9.0, 9.0]]),
              "visible": np.array([False, False])}
    out = det.detect(np.zeros((72, 128, 3), np.uint8), {"landmarks": {"slab_corners": hidden}})
    assert out.true_ids.tolist() == [-1, -1]
    seen = {**hidden, "visible": np.array([True, False])}
    out = det.detect(np.zeros((72, 128, 3), np.uint8), {"landmarks": {"slab_corners": seen}})
    assert out.true_ids.tolist() == [3, -1]


@pytest.mark.parametrize("name", WEIGHT_NAMES)
def test_every_named_weight_set_ships_and_runs(name):
    named = weight_set(name)
    det = LearnedDetector("all", weights=name)
    assert (det.model_path, det.refiner.model_path) == (named.model, named.refiner)
    assert named.model.name in repr(det) and named.refiner.name in repr(det)
    uv, scores, kinds = det.detect_all(np.full((720, 1280, 3), 128, np.uint8))
    assert uv.shape == (len(scores), 2) and len(kinds) == len(scores)  # a flat image: nothing there
    assert len(scores) == 0


def test_a_named_set_is_its_two_files_and_explicit_files_override_it():
    image = np.random.default_rng(3).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    active = weight_set("landmarks_active_v4")
    by_name = LearnedDetector.for_localizer("all", 1280, "robust", weights="active")
    by_path = LearnedDetector.for_localizer("all", 1280, "robust", model=active.model, refiner=active.refiner)
    for a, b in zip(by_name.detect_all(image), by_path.detect_all(image), strict=True):
        np.testing.assert_array_equal(a, b)
    mixed = LearnedDetector("all", weights="active", refiner=weight_set().refiner)
    assert (mixed.model_path, mixed.refiner.model_path) == (active.model, weight_set().refiner)
    default = LearnedDetector("all")
    assert (default.model_path, default.refiner.model_path) == (DEFAULT_MODEL, DEFAULT_REFINER)
    with pytest.raises(ValueError, match=r"weights must be one of \('landmarks_v1', 'landmarks_active_v4', "
                                         r"'active'\), got 'landmarks_active_v3'"):
        LearnedDetector("all", weights="landmarks_active_v3")
