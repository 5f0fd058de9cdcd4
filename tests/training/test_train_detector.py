"""Smoke test of the detector training script (tiny settings) and its target encoding."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from localization.detect.learned import LearnedDetector, decode  # noqa: E402
from uav_struct_env.training.train_detector import _targets, main, pool_labels  # noqa: E402


def test_targets_decode_round_trip():
    kps = np.array([[37.3, 21.8, 0], [100.1, 50.6, 1], [12.0, 70.49, 2]])
    heat, off, mask = _targets(kps, 96 // 4, 128 // 4, 1.0)
    assert heat.max() == 1.0 and mask.sum() == 3 + 3 * 8 * 0.5
    uv, _, kinds = decode(np.concatenate([heat, off]), (0, 1, 2), (128, 96))
    order = np.argsort(kinds)
    assert np.allclose(uv[order], kps[:, :2], atol=1e-5)


def test_tiny_training_run_exports_a_working_model(tmp_path):
    from uav_struct_env.datasets.__main__ import main as make_dataset

    data = tmp_path / "data"
    make_dataset([str(data), "--layouts", "1", "--views", "2", "--seed", "3", "--scale", "0.25"])
    out = tmp_path / "run"
    summary = main(["--data", str(data), "--val", str(data), "--out", str(out),
                    "--max-steps", "3", "--batch", "2", "--crop", "64", "64", "--workers", "0",
                    "--threads", "1", "--eval-every", "2", "--width", "8"])
    assert summary["steps"] == 3
    for name in ("last.pt", "best.pt", "model.onnx", "log.jsonl", "summary.json"):
        assert (out / name).is_file()
    det = LearnedDetector("all", model=out / "model.onnx", scale=1.0)
    uv, scores, kinds = det.detect_all(np.zeros((72, 128, 3), np.uint8))
    assert uv.shape[1] == 2 and len(scores) == len(kinds)


def test_several_datasets_are_pooled_with_their_own_folders(tmp_path):
    from uav_struct_env.datasets import load_labels
    from uav_struct_env.datasets.__main__ import main as make_dataset

    for name, seed in (("a", "3"), ("b", "4")):
        make_dataset([str(tmp_path / name), "--layouts", "1", "--views", "1", "--seed", seed,
                      "--scale", "0.25"])
    pooled = pool_labels([tmp_path / "a", str(tmp_path / "b" / "labels.json")])
    a, b = load_labels(tmp_path / "a"), load_labels(tmp_path / "b")
    assert len(pooled["images"]) == len(a["images"]) + len(b["images"]) == 2
    for rec, (src, orig) in zip(pooled["images"], ((a, a["images"][0]), (b, b["images"][0])), strict=True):
        assert rec["keypoints"] == orig["keypoints"]
        image = (Path(pooled["root"]) / rec["file"]).read_bytes()
        assert image == (Path(src["root"]) / orig["file"]).read_bytes()
    out = tmp_path / "run"
    summary = main(["--data", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out),
                    "--max-steps", "1", "--batch", "2", "--crop", "64", "64", "--workers", "0",
                    "--threads", "1", "--width", "8"])
    assert summary["train_images"] == 2
    with pytest.raises(ValueError, match="at least one dataset"):
        pool_labels([])
