"""Smoke test of the refiner training script (tiny settings): mining, patch sampling, export."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from localization.detect.learned import DEFAULT_MODEL  # noqa: E402
from localization.detect.refiner import PATCH, POSITIVE_RADIUS, PatchRefiner  # noqa: E402
from uav_struct_env.training.train_refiner import WINDOW, PatchSamples, main, mine  # noqa: E402

pytestmark = pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason="no committed keypoint model")


@pytest.fixture(scope="module")
def full_res_dataset(tmp_path_factory):
    from uav_struct_env.datasets.__main__ import main as make_dataset

    data = tmp_path_factory.mktemp("refdata")
    make_dataset([str(data), "--layouts", "1", "--views", "2", "--seed", "5", "--scale", "1.0"])
    return data


def test_mined_windows_and_patch_targets(full_res_dataset, tmp_path):
    path = mine(str(full_res_dataset), str(tmp_path / "w.npz"), negatives=4, progress=False)
    arrays = dict(np.load(path))
    n = len(arrays["kind"])
    assert arrays["windows"].shape == (n, WINDOW, WINDOW, 3)
    truth = arrays["kind"] == 0
    assert truth.sum() > 0
    # A window anchored on a landmark has that landmark within half a pixel of its centre.
    nearest = np.nanmin(np.hypot(*arrays["offsets"][truth].transpose(2, 0, 1)), axis=0)
    assert np.all(nearest <= 0.5 + 1e-6)
    # Without augmentation the patch is the window's centre and the targets are the offsets.
    ds = PatchSamples(arrays, seed=0, augment=False)
    k = int(np.flatnonzero(truth)[0])
    x, present, off = ds[k]
    c = WINDOW // 2
    half = PATCH // 2
    want = arrays["windows"][k, c - half:c + half + 1, c - half:c + half + 1].transpose(2, 0, 1)
    assert np.array_equal(x.numpy(), want.astype(np.float32))
    t = int(np.nanargmin(np.hypot(*arrays["offsets"][k].T)))
    assert present[t] == 1.0 and np.allclose(off[t].numpy(), arrays["offsets"][k, t])
    # Hard negatives have no landmark within twice the positive radius.
    neg = arrays["offsets"][arrays["kind"] == 2]
    assert np.all(~(np.hypot(*neg.transpose(2, 0, 1)) <= 2 * POSITIVE_RADIUS))


def test_tiny_training_run_exports_a_working_refiner(full_res_dataset, tmp_path):
    out = tmp_path / "run"
    keypoint_net = tmp_path / "kp.onnx"  # the keypoint network to mine and validate behind
    keypoint_net.write_bytes(DEFAULT_MODEL.read_bytes())
    summary = main(["--data", str(full_res_dataset), "--val", str(full_res_dataset), "--out",
                    str(out), "--max-steps", "3", "--batch", "8", "--workers", "0",
                    "--threads", "1", "--eval-every", "2", "--width", "4",
                    "--detector-model", str(keypoint_net)])
    assert summary["steps"] == 3 and summary["train_windows"] > 0
    assert summary["detector_model"] == str(keypoint_net.resolve())
    for name in ("windows.npz", "last.pt", "best.pt", "refiner.onnx", "log.jsonl", "summary.json"):
        assert (out / name).is_file()
    uv, scores = PatchRefiner(out / "refiner.onnx").refine(
        np.zeros((100, 120, 3), np.uint8), [[10.0, 20.0], [60.0, 50.0]], [0, 2])
    assert uv.shape == (2, 2) and np.all(np.isfinite(uv)) and np.all((scores >= 0) & (scores <= 1))


def test_mine_rejects_half_resolution_data(tiny_landmark_dataset, tmp_path):
    data = tiny_landmark_dataset  # a quarter of 1280 x 720 (tests/conftest.py)
    with pytest.raises(ValueError, match="full-resolution renders"):
        mine(str(data), str(tmp_path / "w.npz"))
    assert not (tmp_path / "w.npz").exists()


def test_missing_keypoint_network_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--data", str(tmp_path), "--out", str(tmp_path / "run"),
              "--detector-model", str(tmp_path / "nope.onnx")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--detector-model" in err and "nope.onnx' does not exist; expected an existing ONNX file" in err
    assert not (tmp_path / "run").exists()
