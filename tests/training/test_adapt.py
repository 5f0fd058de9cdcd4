"""``uav-struct adapt`` on a tiny budget: weights loaded from ONNX, the set's files and provenance,
and the study picking the set up."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from localization.detect.learned import LearnedDetector  # noqa: E402
from localization.detect.weights import (  # noqa: E402
    ADAPTED_DIR_ENV,
    ADAPTED_PROVENANCE,
    adapted_folder,
    adapted_weights,
    file_sha256,
    weight_set,
)
from uav_struct_env.outputs import OutputExistsError  # noqa: E402
from uav_struct_env.training import adapt as adapt_module  # noqa: E402
from uav_struct_env.training.adapt import AdaptConfig, adapt  # noqa: E402
from uav_struct_env.training.init_weights import FrozenBatchNorm2d, load_onnx_weights  # noqa: E402
from uav_struct_env.training.train_detector import KeypointNet  # noqa: E402
from uav_struct_env.training.train_loop import fit  # noqa: E402
from uav_struct_env.training.train_refiner import PatchNet  # noqa: E402

DUPLEX = Path(__file__).parents[1] / "data" / "ifc" / "duplex.ifc"
TINY = AdaptConfig(layouts=1, refiner_layouts=1, views=1, keypoint_steps=2, refiner_steps=2, threads=1,
                   render_workers=1)


def test_committed_networks_load_from_their_onnx_files():
    base = weight_set()
    x = torch.rand(1, 3, 48, 80) * 255
    net = load_onnx_weights(KeypointNet(16), base.model, x)
    assert net.training and all(not m.training for m in net.modules() if isinstance(m, FrozenBatchNorm2d))
    assert sum(isinstance(m, FrozenBatchNorm2d) for m in net.modules()) == 10
    before = [p.detach().clone() for p in net.parameters()]
    net.train()  # the batch norms stay in eval mode: a training-mode pass gives the graph's output
    with torch.no_grad():
        out = net(x)
    assert all(torch.equal(a, b) for a, b in zip(before, net.parameters(), strict=True))
    from localization.detect.onnx_net import OnnxNet

    assert float(np.abs(out.numpy() - OnnxNet(base.model)(x.numpy())).max()) < 1e-3
    load_onnx_weights(PatchNet(16), base.refiner, torch.rand(2, 3, 33, 33) * 255)
    with pytest.raises(ValueError, match=r"layer 0 \(Conv\) has weights \(16, 3, 3, 3\).*\(8, 3, 3, 3\)"):
        load_onnx_weights(KeypointNet(8), base.model, x)
    with pytest.raises(ValueError, match="has 13 Conv/Gemm layers, the PatchNet expected 9"):
        load_onnx_weights(PatchNet(16), base.model, torch.rand(2, 3, 33, 33) * 255)


def test_fit_refuses_a_loader_without_a_batch(tmp_path):
    net = torch.nn.Linear(2, 1)
    with pytest.raises(ValueError, match="no batch"):
        fit(net, [], lambda b: None, tmp_path, minutes=1.0, max_steps=5, lr=1e-3, warmup_steps=1,
            validate=None, eval_every=10, log=lambda r: None)


@pytest.mark.slow  # a fine-tune of both networks and a study: a long library run
def test_adapt_writes_the_set_and_the_study_runs_it(tmp_path, monkeypatch):
    from uav_struct_env.study.study import _parser, study_config

    monkeypatch.setenv(ADAPTED_DIR_ENV, str(tmp_path / "cache"))
    ifc = tmp_path / "moved_copy.ifc"
    shutil.copyfile(DUPLEX, ifc)
    sha = file_sha256(ifc)
    assert adapted_weights(ifc) is None
    folder = adapt(ifc, config=TINY, progress=False)
    assert folder == adapted_folder(sha) == tmp_path / "cache" / sha
    found = adapted_weights(DUPLEX)  # found by content: the original file has the same hash
    assert found is not None and found.model.parent == folder
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        [ADAPTED_PROVENANCE, f"adapted_{sha[:12]}.onnx", f"adapted_{sha[:12]}_refiner.onnx"])
    record = json.loads((folder / ADAPTED_PROVENANCE).read_text())
    assert record["building"]["sha256"] == sha and record["weights"]["base"] == "landmarks_v1"
    assert record["steps"] == {"keypoint_network": 2, "refiner": 2}
    assert record["images"] == {"keypoint_network": 1, "refiner": 1}
    assert record["settings"]["keypoint_steps"] == 2 and record["minutes"]["total"] > 0
    assert set(record["software"]) >= {"version", "git_commit", "torch"}
    # Fine-tuned, not copied: the weights moved, and the detector runs them.
    assert found.model.read_bytes() != weight_set().model.read_bytes()
    assert found.refiner.read_bytes() != weight_set().refiner.read_bytes()
    uv, scores, _ = LearnedDetector("all", model=found.model, refiner=found.refiner).detect_all(
        np.zeros((720, 1280, 3), np.uint8))
    assert uv.shape[1] == 2 and len(scores) == len(uv)
    # The study's default learned detector runs them on that building; a named set still wins.
    config = study_config(_parser().parse_args(["--site", str(ifc)]))
    assert (config.detector_model, config.refiner_model) == (str(found.model), str(found.refiner))
    named = study_config(_parser().parse_args(["--site", str(ifc), "--detector", "learned:landmarks_v1"]))
    assert Path(named.detector_model) == weight_set().model
    assert study_config(_parser().parse_args([])).detector_model is None  # the paper site
    with pytest.raises(OutputExistsError):  # refused before any rendering
        adapt(ifc, config=TINY, progress=False)


def test_an_interrupted_adaptation_leaves_no_set(tmp_path, monkeypatch):
    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(adapt_module, "_render", stop)
    with pytest.raises(KeyboardInterrupt):
        adapt(DUPLEX, tmp_path, config=TINY, progress=False)
    assert adapted_weights(DUPLEX, tmp_path) is None
    assert list(adapted_folder(file_sha256(DUPLEX), tmp_path).iterdir()) == []


def test_floor_stages_are_the_stages_the_study_evaluates():
    from uav_struct_env.site import ifc_stages
    from uav_struct_env.study.protocol import StudyConfig
    from uav_struct_env.training.adapt import floor_stages

    every = ifc_stages(DUPLEX)
    study = StudyConfig(site=str(DUPLEX), detector="projection")
    assert floor_stages(DUPLEX) == tuple(s for s in study._stages.values() if s is not None)
    assert floor_stages(DUPLEX, every[0]) == (every[0],) and len(every) > 1


def test_adapt_command_refuses_bad_input(tmp_path, capsys):
    from uav_struct_env.cli import main

    assert main(["adapt", str(tmp_path / "missing.ifc")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("uav-struct adapt: error: ifc") and "does not exist" in err
    assert main(["adapt", str(DUPLEX), "--keypoint-steps", "0"]) == 2
    assert "AdaptConfig.keypoint_steps" in capsys.readouterr().err
    assert main(["adapt", str(DUPLEX), "--stage", "Attic/slab"]) == 2
    assert "Attic/slab" in capsys.readouterr().err
    assert main(["adapt", str(DUPLEX), "--stage", "Roof/slab", "--all-stages"]) == 2
    assert "--stage 'Roof/slab' and --all-stages: choose one" in capsys.readouterr().err
