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


def test_tiny_training_run_exports_a_working_model(tiny_landmark_dataset, tmp_path):
    data = tiny_landmark_dataset  # one random site, two views, quarter scale (tests/conftest.py)
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


def test_several_datasets_are_pooled_with_their_own_folders(tiny_landmark_dataset, tmp_path):
    from uav_struct_env.datasets import load_labels
    from uav_struct_env.datasets.__main__ import main as make_dataset

    # a: the tiny dataset (two views); b: another seed's single view, in a folder of its own
    make_dataset([str(tmp_path / "b"), "--layouts", "1", "--views", "1", "--seed", "4", "--scale", "0.25"])
    pooled = pool_labels([tiny_landmark_dataset, str(tmp_path / "b" / "labels.json")])
    a, b = load_labels(tiny_landmark_dataset), load_labels(tmp_path / "b")
    assert len(pooled["images"]) == len(a["images"]) + len(b["images"]) == 3
    sources = [(a, a["images"][0]), (a, a["images"][1]), (b, b["images"][0])]
    for rec, (src, orig) in zip(pooled["images"], sources, strict=True):
        assert rec["keypoints"] == orig["keypoints"]
        image = (Path(pooled["root"]) / rec["file"]).read_bytes()
        assert image == (Path(src["root"]) / orig["file"]).read_bytes()
    out = tmp_path / "run"
    summary = main(["--data", str(tiny_landmark_dataset), str(tmp_path / "b"), "--out", str(out),
                    "--max-steps", "1", "--batch", "2", "--crop", "64", "64", "--workers", "0",
                    "--threads", "1", "--width", "8"])
    assert summary["train_images"] == 3
    with pytest.raises(ValueError, match="at least one dataset"):
        pool_labels([])
