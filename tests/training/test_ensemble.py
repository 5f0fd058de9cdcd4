"""The ONNX ensemble: one file whose output is the mean of its members', on the committed refiners."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("onnx")

from localization.detect.learned import DEFAULT_MODEL, LearnedDetector
from localization.detect.onnx_net import OnnxNet
from localization.detect.refiner import DEFAULT_REFINER, PATCH
from localization.detect.weights import weight_set
from uav_struct_env.training.ensemble import average_models, main, split_ensemble  # noqa: E402

#: The committed ensemble: landmarks_active_v4's refiner, the mean of v3's refiner and a second one.
V4 = weight_set("landmarks_active_v4").refiner


def _patches(n: int = 40) -> np.ndarray:
    return np.random.default_rng(0).uniform(0, 255, (n, 3, PATCH, PATCH)).astype(np.float32)


def test_ensemble_output_is_the_mean_of_its_members(tmp_path):
    """Three members, one of them an ensemble itself (v4's refiner)."""
    members = (DEFAULT_REFINER, V4, DEFAULT_REFINER)
    path = average_models(members, tmp_path / "ens.onnx")
    x = _patches()
    outputs = [OnnxNet(p)(x).astype(np.float64) for p in members]
    assert np.abs(outputs[0] - outputs[1]).max() > 0.1  # the members differ
    np.testing.assert_allclose(OnnxNet(path)(x), np.mean(outputs, axis=0), atol=1e-5)
    # One patch or many: the batch dimension stays dynamic.
    np.testing.assert_allclose(OnnxNet(path)(x[:1]), np.mean(outputs, axis=0)[:1], atol=1e-5)


def test_committed_v4_refiner_is_the_mean_of_v3_and_a_second_refiner(tmp_path):
    """landmarks_active_v4 = mean(v3, a second refiner): split into its members, which are refiners
    that differ, it averages them and rebuilds byte for byte (so v3's refiner need not ship)."""
    members = split_ensemble(V4, tmp_path / "members")
    assert [(p.parent.name, p.name) for p in members] == [("m0", "landmarks_active_v3_refiner.onnx"),
                                                         ("m1", "refiner.onnx")]
    x = _patches()
    v3, other = (OnnxNet(p)(x).astype(np.float64) for p in members)
    v4 = OnnxNet(V4)(x).astype(np.float64)
    for member in (v3, other):
        assert np.all((member[:, :3] >= 0) & (member[:, :3] <= 1))  # a probability
    assert np.abs(v4 - v3).max() > 0.05
    np.testing.assert_allclose(v4, (v3 + other) / 2, atol=1e-5)
    rebuilt = average_models(members, tmp_path / "v4.onnx")
    assert rebuilt.read_bytes() == V4.read_bytes()


def test_ensemble_runs_as_a_detector_refiner(tmp_path):
    path = average_models([DEFAULT_REFINER, DEFAULT_REFINER], tmp_path / "twice.onnx")
    image = np.random.default_rng(1).integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    uv = np.array([[640.0, 360.0], [100.5, 200.25], [1200.0, 700.0]])
    kinds = np.array([0, 1, 2])
    single = LearnedDetector(model=DEFAULT_MODEL, refiner=DEFAULT_REFINER).refiner.refine(image, uv, kinds)
    twice = LearnedDetector(model=DEFAULT_MODEL, refiner=path).refiner.refine(image, uv, kinds)
    for a, b in zip(single, twice, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-4)


def test_bad_members_are_refused(tmp_path, capsys):
    with pytest.raises(ValueError, match="at least two models, got 1"):
        average_models([DEFAULT_REFINER], tmp_path / "one.onnx")
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        average_models([DEFAULT_REFINER, tmp_path / "nope.onnx"], tmp_path / "e.onnx")
    with pytest.raises(ValueError, match="has another input than .*one interface"):
        average_models([DEFAULT_REFINER, DEFAULT_MODEL], tmp_path / "mixed.onnx")  # a keypoint network
    assert not (tmp_path / "mixed.onnx").exists()
    with pytest.raises(SystemExit):
        main([str(DEFAULT_REFINER), "--out", str(tmp_path / "cli.onnx")])
    assert "at least two models" in capsys.readouterr().err


def test_split_refuses_what_is_not_an_ensemble_and_the_cli_splits(tmp_path, capsys):
    with pytest.raises(ValueError, match="is not an ensemble written by average_models"):
        split_ensemble(DEFAULT_REFINER, tmp_path / "no")
    with pytest.raises(FileNotFoundError, match="nope.onnx"):
        split_ensemble(tmp_path / "nope.onnx", tmp_path / "no")
    with pytest.raises(SystemExit):
        main(["--split", str(V4), str(V4), "--out", str(tmp_path / "two")])
    assert "--split takes one ensemble, got 2 files" in capsys.readouterr().err
    assert main(["--split", str(V4), "--out", str(tmp_path / "cli")]) == 0
    assert (tmp_path / "cli" / "m0" / "landmarks_active_v3_refiner.onnx").is_file()
    assert "wrote 2 members" in capsys.readouterr().out
