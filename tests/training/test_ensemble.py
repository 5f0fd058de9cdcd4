"""The ONNX ensemble: one file whose output is the mean of its members', on the committed refiners."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("onnx")

from localization.detect.learned import DEFAULT_MODEL, LearnedDetector
from localization.detect.onnx_net import OnnxNet
from localization.detect.refiner import DEFAULT_REFINER, PATCH
from uav_struct_env.training.ensemble import average_models, main  # noqa: E402

MODELS = DEFAULT_REFINER.parent
V2, V3 = MODELS / "landmarks_active_v2_refiner.onnx", MODELS / "landmarks_active_v3_refiner.onnx"
V4 = MODELS / "landmarks_active_v4_refiner.onnx"


def _patches(n: int = 40) -> np.ndarray:
    return np.random.default_rng(0).uniform(0, 255, (n, 3, PATCH, PATCH)).astype(np.float32)


def test_ensemble_output_is_the_mean_of_its_members(tmp_path):
    path = average_models([DEFAULT_REFINER, V2, V3], tmp_path / "ens.onnx")
    x = _patches()
    members = [OnnxNet(p)(x).astype(np.float64) for p in (DEFAULT_REFINER, V2, V3)]
    assert np.abs(members[0] - members[2]).max() > 0.1  # the members differ
    np.testing.assert_allclose(OnnxNet(path)(x), np.mean(members, axis=0), atol=1e-5)
    # One patch or many: the batch dimension stays dynamic.
    np.testing.assert_allclose(OnnxNet(path)(x[:1]), np.mean(members, axis=0)[:1], atol=1e-5)


def test_committed_v4_refiner_contains_v3():
    """landmarks_active_v4 = mean(v3, a second refiner): 2 x v4's output minus v3's is that one."""
    x = _patches()
    v3, v4 = OnnxNet(V3)(x).astype(np.float64), OnnxNet(V4)(x).astype(np.float64)
    other = 2 * v4 - v3
    assert np.all((other[:, :3] > -1e-5) & (other[:, :3] < 1 + 1e-5))  # a probability
    assert np.abs(v4 - v3).max() > 0.05


def test_ensemble_runs_as_a_detector_refiner(tmp_path):
    path = average_models([V3, V3], tmp_path / "twice.onnx")
    image = np.random.default_rng(1).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    uv = np.array([[640.0, 360.0], [100.5, 200.25], [1200.0, 700.0]])
    kinds = np.array([0, 1, 2])
    single = LearnedDetector(model=DEFAULT_MODEL, refiner=V3).refiner.refine(image, uv, kinds)
    twice = LearnedDetector(model=DEFAULT_MODEL, refiner=path).refiner.refine(image, uv, kinds)
    for a, b in zip(single, twice, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)


def test_bad_members_are_refused(tmp_path, capsys):
    with pytest.raises(ValueError, match="at least two models, got 1"):
        average_models([V3], tmp_path / "one.onnx")
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        average_models([V3, tmp_path / "nope.onnx"], tmp_path / "e.onnx")
    with pytest.raises(ValueError, match="has another input than .*one interface"):
        average_models([V3, DEFAULT_MODEL], tmp_path / "mixed.onnx")  # a keypoint network
    assert not (tmp_path / "mixed.onnx").exists()
    with pytest.raises(SystemExit):
        main([str(V3), "--out", str(tmp_path / "cli.onnx")])
    assert "at least two models" in capsys.readouterr().err
