import numpy as np
import pytest

from localization.detect.interface import Detections, Detector
from localization.detect.projection import ProjectionDetector
from localization.geometry.camera import PAPER_K
from localization.geometry.transforms import look_at
from localization.testing.synthetic import landmark_context


def _context(building, center):
    T = look_at([4, -20, 18], center)
    return landmark_context(PAPER_K, T, {"column_tops": building["column_tops"]})


def test_clean_detections_are_the_visible_projections(building, center):
    ctx = _context(building, center)
    det = ProjectionDetector("column_tops", pixel_sigma=0.0, rng=np.random.default_rng(0)).detect(
        None, ctx
    )
    assert isinstance(det, Detections) and det.uv.dtype == np.float64
    gt = ctx["landmarks"]["column_tops"]
    assert len(det) == gt["visible"].sum()
    for uv, tid in zip(det.uv, det.true_ids, strict=True):
        np.testing.assert_allclose(uv, gt["uv"][gt["ids"] == tid][0])


def test_noise_misses_and_clutter_statistics(building, center):
    ctx = _context(building, center)
    d = ProjectionDetector(
        "column_tops", 2.0, miss_rate=0.25, false_positives=3.0, rng=np.random.default_rng(1)
    )
    n_true, n_fp, resid = [], [], []
    gt = ctx["landmarks"]["column_tops"]
    for _ in range(300):
        det = d.detect(None, ctx)
        n_true.append(np.sum(det.true_ids >= 0))
        n_fp.append(np.sum(det.true_ids < 0))
        for uv, tid in zip(det.uv[det.true_ids >= 0], det.true_ids[det.true_ids >= 0], strict=True):
            resid.append(uv - gt["uv"][gt["ids"] == tid][0])
        clutter = det.uv[det.true_ids < 0]
        assert np.all((clutter >= -0.5) & (clutter <= np.array([1279.5, 719.5])))
    assert np.mean(n_true) == pytest.approx(0.75 * gt["visible"].sum(), rel=0.05)
    assert np.mean(n_fp) == pytest.approx(3.0, rel=0.1)
    assert np.std(np.array(resid)) == pytest.approx(2.0, rel=0.05)


def test_detections_are_shuffled_and_seeded(building, center):
    ctx = _context(building, center)
    a = ProjectionDetector("column_tops", rng=np.random.default_rng(3)).detect(None, ctx)
    b = ProjectionDetector("column_tops", rng=np.random.default_rng(3)).detect(None, ctx)
    np.testing.assert_array_equal(a.uv, b.uv)
    assert not np.array_equal(a.true_ids, np.sort(a.true_ids))


def test_protocol_and_errors(building, center):
    d = ProjectionDetector("column_tops", rng=np.random.default_rng(0))
    assert isinstance(d, Detector)
    with pytest.raises(KeyError, match="no set 'slab'"):
        ProjectionDetector("slab").detect(None, _context(building, center))
    with pytest.raises(ValueError, match="miss_rate"):
        ProjectionDetector(miss_rate=1.5)
    with pytest.raises(TypeError, match="rng"):
        ProjectionDetector(rng=np.random.RandomState(0))
    with pytest.raises(ValueError, match=r"Detections.uv must have shape \(N, 2\)"):
        Detections(uv=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="true_ids"):
        Detections(uv=np.zeros((3, 2)), true_ids=np.zeros(2, dtype=int))
