"""The corpus fine-tune: which buildings it trains on (never a held-out one), its kept datasets,
its refusals, and (slow) a tiny run writing a named set the detector runs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.training import corpus_weights
from uav_struct_env.training.corpus_weights import CorpusConfig, train_buildings

DUPLEX = Path(__file__).parents[1] / "data" / "ifc" / "duplex.ifc"
MANIFEST = Path(corpus_weights.__file__).parents[2] / "data" / "ifc_corpus" / "manifest.json"


def _manifest(tmp_path: Path, entries: list[dict]) -> Path:
    (tmp_path / "files").mkdir(exist_ok=True)
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps({"files": entries}))
    return path


def test_the_committed_manifest_trains_on_no_held_out_building():
    entries = json.loads(MANIFEST.read_text())["files"]
    heldout = {e["name"] for e in entries if e["split"] == "heldout"}
    assert heldout == {"revit_tall_building", "archicad9_niedriha", "tekla_carwash", "renga_house",
                       "revit_webifc_example", "sketchup_pcert_house"}
    with pytest.raises(ConfigError, match=r"--exclude renga_house: not a train building .*\(train: .*duplex"):
        train_buildings(("renga_house",))


def test_train_buildings_keeps_what_imports_and_says_why_it_skips(tmp_path):
    shutil.copyfile(DUPLEX, tmp_path / "a.ifc")
    (tmp_path / "b.ifc").write_text("ISO-10303-21;\nnot a building\n")
    shutil.copyfile(DUPLEX, tmp_path / "c.ifc")
    manifest = _manifest(tmp_path, [
        {"name": "a", "split": "train", "local_path": str(tmp_path / "a.ifc")},
        {"name": "b", "split": "train", "local_path": str(tmp_path / "b.ifc")},
        {"name": "c", "split": "train", "local_path": str(tmp_path / "c.ifc")},
        {"name": "h", "split": "heldout", "local_path": str(tmp_path / "a.ifc")},
    ])
    kept, skipped = train_buildings(("c",), manifest=manifest)
    assert kept == [("a", tmp_path / "a.ifc")]
    assert set(skipped) == {"b", "c"}
    assert skipped["b"].startswith("does not import: ") and "b.ifc" in skipped["b"]
    assert skipped["c"] == "excluded (--exclude): a validation building"
    with pytest.raises(ConfigError, match=r"--exclude h: not a train building"):
        train_buildings(("h",), manifest=manifest)
    with pytest.raises(ConfigError, match=r"no corpus manifest at .*nowhere\.json: the corpus weights are "):
        train_buildings(manifest=tmp_path / "nowhere.json")
    gone = {"name": "gone", "split": "train", "local_path": "data/ifc_corpus/files/gone.ifc"}
    missing = _manifest(tmp_path, [gone])
    with pytest.raises(ConfigError, match=r"train buildings missing: .*files/gone\.ifc; fetch them with"):
        train_buildings(manifest=missing)


def test_a_kept_dataset_rendered_with_other_settings_is_refused(tmp_path):
    config = CorpusConfig(views=1, render_workers=1)
    out = tmp_path / "keypoint" / "random"
    labels = corpus_weights._dataset("random", out, 1, 7, 0.5, config, progress=False)
    assert labels == out / "labels.json"
    before = labels.read_bytes()
    assert corpus_weights._dataset("random", out, 1, 7, 0.5, config, False) == labels  # reused, not rendered
    assert labels.read_bytes() == before
    with pytest.raises(ConfigError, match=r"rendered with other settings \(seed: \[7\] here, \[8\] wanted\)"):
        corpus_weights._dataset("random", out, 1, 8, 0.5, config, False)


@pytest.mark.parametrize(("field", "value"), [("keypoint_steps", 0), ("views", 1.5), ("refiner_lr", 2.0)])
def test_corpus_config_refuses_bad_settings(field, value):
    with pytest.raises(ConfigError, match=f"CorpusConfig.{field}"):
        CorpusConfig(**{field: value})


def test_command_refuses_before_any_work(tmp_path, capsys):
    (tmp_path / "x.onnx").write_bytes(b"kept")
    assert corpus_weights.main(["--name", "x", "--out", str(tmp_path), "--work", str(tmp_path / "w")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("python -m uav_struct_env.training.corpus_weights: error: ") and "x.onnx" in err
    assert "--overwrite" in err and (tmp_path / "x.onnx").read_bytes() == b"kept"
    assert corpus_weights.main(["--name", "y", "--out", str(tmp_path), "--exclude", "tekla_carwash"]) == 2
    assert "--exclude tekla_carwash: not a train building" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()


@pytest.mark.slow  # renders and fine-tunes both networks: a long library run
def test_a_tiny_corpus_run_writes_a_set_the_detector_runs(tmp_path):
    pytest.importorskip("torch")
    from localization.detect.learned import LearnedDetector
    from localization.detect.weights import weight_set

    manifest = _manifest(tmp_path, [{"name": "duplex", "split": "train", "local_path": str(DUPLEX)}])
    tiny = CorpusConfig(layouts=1, refiner_layouts=1, random_layouts=1, random_refiner_layouts=0, views=1,
                        keypoint_steps=2, refiner_steps=2, threads=1, render_workers=1)
    files = corpus_weights.train_corpus_weights("tiny", tmp_path / "out", tmp_path / "work", tiny,
                                                progress=False, manifest=manifest)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        "tiny.onnx", "tiny_provenance.json", "tiny_refiner.onnx"]
    record = json.loads(files["provenance"].read_text())
    assert [b["name"] for b in record["trained_on"]] == ["duplex"] and record["random_sites"]
    assert record["trained_on"][0]["sha256"].startswith("b347a2c8aa8fff6db896a4417a9c50c2")
    assert record["steps"] == {"keypoint_network": 2, "refiner": 2}
    assert record["images"] == {"keypoint_network": 2, "refiner": 1}
    assert set(record["images_per_dataset_and_stage"]) == {"keypoint/duplex", "keypoint/random",
                                                           "refiner/duplex"}
    assert files["model"].read_bytes() != weight_set().model.read_bytes()
    uv, scores, _ = LearnedDetector("all", model=files["model"], refiner=files["refiner"]).detect_all(
        np.zeros((720, 1280, 3), np.uint8))
    assert uv.shape[1] == 2 and len(scores) == len(uv)
    with pytest.raises(FileExistsError):
        corpus_weights.train_corpus_weights("tiny", tmp_path / "out", tmp_path / "work", tiny, progress=False,
                                            manifest=manifest)
