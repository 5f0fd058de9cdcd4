"""Smoke test of the refiner training script (tiny settings): mining, patch sampling, export."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from localization.learned import DEFAULT_MODEL  # noqa: E402
from localization.refine import PATCH, POSITIVE_RADIUS, PatchRefiner  # noqa: E402
from uav_struct_env.training.train_refiner import PatchSamples, main, mine, window_size  # noqa: E402

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
    w = window_size(False)
    assert arrays["windows"].shape == (n, w, w, 3)
    truth = arrays["kind"] == 0
    assert truth.sum() > 0
    # A window anchored on a landmark has that landmark within half a pixel of its centre.
    nearest = np.nanmin(np.hypot(*arrays["offsets"][truth].transpose(2, 0, 1)), axis=0)
    assert np.all(nearest <= 0.5 + 1e-6)
    # Without augmentation the patch is the window's centre and the targets are the offsets.
    ds = PatchSamples(arrays, seed=0, augment=False)
    k = int(np.flatnonzero(truth)[0])
    x, present, off = ds[k]
    c = w // 2
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


def test_context_windows_and_inputs(full_res_dataset, tmp_path):
    """Context windows are CONTEXT + 2 MAX_SHIFT px; an input is the window's centre patch and
    its CONTEXT block averaged 3 x 3 (computed here with OpenCV's area resampling)."""
    import cv2

    from localization.refine import CONTEXT

    path = mine(str(full_res_dataset), str(tmp_path / "c.npz"), negatives=4, progress=False,
                context=True)
    arrays = dict(np.load(path))
    w = window_size(True)
    assert w == CONTEXT + 20 and arrays["windows"].shape[1:] == (w, w, 3)
    ds = PatchSamples(arrays, seed=0, augment=False)
    assert ds.context
    k = int(np.flatnonzero(arrays["kind"] == 0)[0])
    x = ds[k][0].numpy()
    assert x.shape == (6, PATCH, PATCH)
    c, half, h = w // 2, PATCH // 2, CONTEXT // 2
    win = arrays["windows"][k]
    assert np.array_equal(x[:3], win[c - half:c + half + 1, c - half:c + half + 1].transpose(2, 0, 1))
    block = win[c - h:c + h + 1, c - h:c + h + 1].astype(np.float32)
    area = cv2.resize(block, (PATCH, PATCH), interpolation=cv2.INTER_AREA).transpose(2, 0, 1)
    assert np.allclose(x[3:], area, atol=1e-4)
    # the augmented input keeps its shape; windows of another size are refused
    assert PatchSamples(arrays, seed=0)[k][0].shape == (6, PATCH, PATCH)
    with pytest.raises(ValueError, match="53 or 119 px square, got"):
        PatchSamples({**arrays, "windows": arrays["windows"][:, :60, :60]}, seed=0)


def test_tiny_context_training_run_exports_a_context_refiner(full_res_dataset, tmp_path):
    out = tmp_path / "run"
    summary = main(["--data", str(full_res_dataset), "--out", str(out), "--max-steps", "2",
                    "--batch", "4", "--workers", "0", "--threads", "1", "--width", "4",
                    "--context"])
    assert summary["context"] is True and summary["steps"] == 2
    refiner = PatchRefiner(out / "refiner.onnx")
    assert refiner.context
    uv, scores = refiner.refine(np.zeros((100, 120, 3), np.uint8), [[3.0, 4.0], [60.0, 50.0]], [1, 2])
    assert uv.shape == (2, 2) and np.all(np.isfinite(uv)) and np.all((scores >= 0) & (scores <= 1))
    # the plain windows mined for another run do not train a context refiner by mistake
    with pytest.raises(ValueError, match="windows mined for a context refiner, but context=False"):
        main(["--data", str(full_res_dataset), "--out", str(tmp_path / "run2"), "--windows",
              str(out / "windows.npz"), "--max-steps", "1", "--batch", "4", "--workers", "0"])


def test_refiner_refuses_a_model_of_another_input(tmp_path):
    from uav_struct_env.training.train_detector import export_checked

    net = torch.nn.Sequential(torch.nn.Conv2d(4, 9, PATCH), torch.nn.Flatten())
    path = export_checked(net, torch.rand(2, 4, PATCH, PATCH), tmp_path / "four.onnx", "patches",
                          "out", {"patches": {0: "n"}, "out": {0: "n"}})
    with pytest.raises(ValueError, match=r"four.onnx: a refiner takes \(N, 3 or 6, 33, 33\) patches, "
                                         r"this model takes \['n', 4, 33, 33\]"):
        PatchRefiner(path)


def test_mine_rejects_half_resolution_data(tmp_path):
    from uav_struct_env.datasets.__main__ import main as make_dataset

    data = tmp_path / "half"
    make_dataset([str(data), "--layouts", "1", "--views", "1", "--seed", "5", "--scale", "0.25"])
    with pytest.raises(ValueError, match="full-resolution renders"):
        mine(str(data), str(tmp_path / "w.npz"))


def test_missing_keypoint_network_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--data", str(tmp_path), "--out", str(tmp_path / "run"),
              "--detector-model", str(tmp_path / "nope.onnx")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--detector-model" in err and "nope.onnx' does not exist; expected an existing ONNX file" in err
    assert not (tmp_path / "run").exists()
