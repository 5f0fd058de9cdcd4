"""Weights fine-tuned on the real-building corpus's train buildings.

``python -m uav_struct_env.training.corpus_weights --name NAME --out DIR`` fine-tunes the default weight
set (:data:`localization.detect.weights.DEFAULT_WEIGHTS`) on renders of every building of the
corpus's **train** split (``data/ifc_corpus/manifest.json``) that imports, and of random sites,
into one named set: ``OUT/NAME.onnx``, ``OUT/NAME_refiner.onnx`` and ``OUT/NAME_provenance.json``.
The default set was trained on random sites and one IFC building (the duplex); this one sees
Revit, ArchiCAD and Tekla exports too, which is what issue 44's "more diverse training buildings"
asks. Held-out buildings (manifest ``heldout``) are refused: nothing is trained on them.

Per building, ``layouts x views`` half-resolution images (keypoint network, dataset seed
``seed``) and ``refiner_layouts x views`` full-resolution ones (refiner, seed ``seed + 1``), each
layout one of the building's stages drawn at random with site activity, camera and imaging all
``mixed`` (:func:`uav_struct_env.training.finetune.dataset_config`); the random sites add
``random_layouts`` and ``random_refiner_layouts`` layouts, so that the paper's and random sites
are not forgotten. The datasets are rendered into ``WORK/keypoint/<name>/`` and
``WORK/refiner/<name>/`` and kept: a later run with the same settings reuses them (one rendered
with other settings is refused, naming the difference). Then
:func:`uav_struct_env.training.finetune.finetune` trains both networks a fixed number of steps.

``--exclude NAME`` leaves a train building out of the training, so that it can validate the
recipe (a building of the train split that the weights have not seen); the provenance lists
what was trained on and what was excluded.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from localization.detect.weights import DEFAULT_WEIGHTS, MODELS_DIR, file_sha256, weight_set
from uav_struct_env.errors import ConfigError
from uav_struct_env.site.corpus import MANIFEST, REPO, corpus_file
from uav_struct_env.training.finetune import (
    Laps,
    add_setting_options,
    check_settings,
    dataset_config,
    finetune,
    render_dataset,
)

__all__ = ["CorpusConfig", "main", "train_buildings", "train_corpus_weights"]



@dataclass(frozen=True)
class CorpusConfig:
    """Settings of the corpus fine-tune (the model card names the ones of each candidate).

    Attributes:
        layouts: keypoint-network layouts per building (each a stage drawn at random).
        refiner_layouts: refiner layouts per building.
        random_layouts: keypoint-network layouts of random sites (0: none).
        random_refiner_layouts: refiner layouts of random sites (0: none).
        views, keypoint_steps, refiner_steps, keypoint_lr, refiner_lr, seed, threads,
            render_workers: as :class:`~uav_struct_env.training.adapt.AdaptConfig`'s.
    """

    layouts: int = 24
    refiner_layouts: int = 12
    random_layouts: int = 48
    random_refiner_layouts: int = 24
    views: int = 10
    keypoint_steps: int = 1500
    refiner_steps: int = 1000
    keypoint_lr: float = 1e-3
    refiner_lr: float = 5e-4
    seed: int = 5100
    threads: int = 2
    render_workers: int = 2

    def __post_init__(self) -> None:
        check_settings(self, ("seed", "random_layouts", "random_refiner_layouts"))


def train_buildings(exclude: tuple[str, ...] = (), manifest: Path = MANIFEST,
                    files: Path | None = None) -> tuple[list[tuple[str, Path]], dict[str, str]]:
    """The train split's buildings that import: ``([(name, path)], {skipped name: reason})``.

    A building of the train split that has no stage a camera can use (the importer's
    ``IfcImportError``) is skipped with its reason, as is one named in ``exclude``. Each file is
    found by :func:`uav_struct_env.site.corpus.corpus_file` (``files``: a folder tried first).

    Raises:
        ConfigError: no manifest, ``exclude`` names a file that is not in the train split, or a
            train file is missing (fetch the corpus first: ``python benchmarks/fetch_ifc_corpus.py``).
    """
    from uav_struct_env.errors import IfcImportError
    from uav_struct_env.site.ifc import ifc_stages

    if not Path(manifest).is_file():
        raise ConfigError(f"no corpus manifest at {manifest}: the corpus weights are trained from a checkout "
                          "of the repository (data/ifc_corpus/manifest.json)")
    entries = json.loads(Path(manifest).read_text())["files"]
    train = {e["name"]: e for e in entries if e["split"] == "train"}
    unknown = sorted(set(exclude) - set(train))
    if unknown:
        raise ConfigError(f"--exclude {','.join(unknown)}: not a train building of {manifest} "
                          f"(train: {', '.join(sorted(train))})")
    paths = {name: corpus_file(e, files) for name, e in train.items()}
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise ConfigError(f"train buildings missing: {', '.join(missing)}; fetch them with "
                          "python benchmarks/fetch_ifc_corpus.py")
    kept: list[tuple[str, Path]] = []
    skipped: dict[str, str] = {}
    for name, path in paths.items():
        if name in exclude:
            skipped[name] = "excluded (--exclude): a validation building"
            continue
        try:
            ifc_stages(path)
        except IfcImportError as err:
            skipped[name] = f"does not import: {err}"
            continue
        kept.append((name, path))
    return kept, skipped


def _dataset(site: str | Path, out: Path, layouts: int, seed: int, scale: float, config: CorpusConfig,
             progress: bool) -> Path:
    """The dataset in ``out``: rendered unless it is there with these settings (refused if other)."""
    wanted = dataset_config(site, layouts, config.views, seed, scale)
    labels = out / "labels.json"
    if labels.is_file():
        have = json.loads(labels.read_text())["config"]
        want = json.loads(json.dumps(asdict(wanted)))
        diff = sorted(k for k in want.keys() | have.keys() if want.get(k) != have.get(k))
        if diff:
            raise ConfigError(f"{out} was rendered with other settings ({', '.join(diff)}: "
                              f"{[have.get(k) for k in diff]} here, {[want.get(k) for k in diff]} wanted); "
                              "delete it or give another --work")
        return labels
    return render_dataset(wanted, out, config.render_workers, progress)


def _stage_counts(labels: Path) -> dict[str, int]:
    from uav_struct_env.datasets.landmarks import load_labels

    return dict(sorted(Counter(str(r.get("stage")) for r in load_labels(labels)["images"]).items()))


def _render_all(buildings: list[tuple[str, Path]], work: Path, config: CorpusConfig,
                progress: bool) -> tuple[list[Path], list[Path], dict]:
    sites = [(name, path, config.layouts, config.refiner_layouts) for name, path in buildings]
    if config.random_layouts:
        sites.append(("random", "random", config.random_layouts, config.random_refiner_layouts))
    keypoint, refiner, images = [], [], {}
    for name, site, kp_layouts, _ in sites:
        keypoint.append(_dataset(site, work / "keypoint" / name, kp_layouts, config.seed, 0.5, config,
                                 progress))
    for name, site, _, ref_layouts in sites:
        if ref_layouts:
            refiner.append(_dataset(site, work / "refiner" / name, ref_layouts, config.seed + 1, 1.0, config,
                                    progress))
    for labels in keypoint + refiner:
        images[f"{labels.parent.parent.name}/{labels.parent.name}"] = _stage_counts(labels)
    return keypoint, refiner, images


def _targets(out: Path, name: str) -> dict[str, Path]:
    return {"model": out / f"{name}.onnx", "refiner": out / f"{name}_refiner.onnx",
            "provenance": out / f"{name}_provenance.json"}


def train_corpus_weights(name: str, out: str | Path = "runs/corpus_weights/weights",
                         work: str | Path = "runs/corpus_weights",
                         config: CorpusConfig | None = None, exclude: tuple[str, ...] = (),
                         progress: bool = True, overwrite: bool = False,
                         manifest: Path = MANIFEST) -> dict[str, Path]:
    """Fine-tune the default set on the corpus's train buildings; returns the three files written.

    ``manifest``: the corpus manifest whose train split is trained on (:func:`train_buildings`).

    Raises:
        FileExistsError: one of ``out/NAME{.onnx,_refiner.onnx,_provenance.json}`` exists and not
            ``overwrite`` (refused before any work).
        ConfigError: see :func:`train_buildings`; a kept dataset rendered with other settings.
    """
    import torch

    from uav_struct_env.outputs import atomic_write_json
    from uav_struct_env.provenance import software

    config = config or CorpusConfig()
    out, work = Path(out), Path(work)
    targets = _targets(out, name)
    existing = [str(p) for p in targets.values() if p.exists()]
    if existing and not overwrite:
        raise FileExistsError(f"{', '.join(existing)} exist; pass --overwrite to replace them")
    buildings, skipped = train_buildings(exclude, manifest)
    t0 = time.perf_counter()
    laps = Laps()
    keypoint, refiner, images = _render_all(buildings, work, config, progress)
    laps("render")
    base = weight_set(DEFAULT_WEIGHTS)
    with tempfile.TemporaryDirectory(prefix="uav-struct-corpus-") as tmp:
        staged = {k: Path(tmp) / p.name for k, p in targets.items()}
        counts = finetune(config, base, keypoint, refiner, staged, Path(tmp), progress, laps)
        record = {
            "weights": {"name": name, "model": targets["model"].name, "refiner": targets["refiner"].name,
                        "base": DEFAULT_WEIGHTS,
                        "base_sha256": {k: file_sha256(getattr(base, k)) for k in ("model", "refiner")}},
            "trained_on": [{"name": n, "file": str(p.relative_to(REPO) if p.is_relative_to(REPO) else p),
                            "sha256": file_sha256(p)} for n, p in buildings],
            "random_sites": bool(config.random_layouts),
            "not_trained_on": skipped,
            "images_per_dataset_and_stage": images,
            "settings": asdict(config),
            "software": {**software(), "torch": torch.__version__},
            **counts,
            "minutes": {**laps.minutes, "total": round(sum(laps.minutes.values()), 2)},
            "wall_minutes": round((time.perf_counter() - t0) / 60.0, 2),
        }
        atomic_write_json(staged["provenance"], record, indent=2)
        out.mkdir(parents=True, exist_ok=True)
        for key in ("model", "refiner", "provenance"):  # the provenance last: it says the set is whole
            shutil.move(staged[key], targets[key])
    return targets


def _parser() -> argparse.ArgumentParser:
    from uav_struct_env.validate import CommandParser

    p = CommandParser(prog="python -m uav_struct_env.training.corpus_weights",
                      description="Fine-tune the default detector weights on renders of the IFC corpus's "
                      "train buildings and of random sites, into one named weight set.")
    p.add_argument("--name", required=True, help="the set's name: OUT/NAME.onnx, OUT/NAME_refiner.onnx, "
                   "OUT/NAME_provenance.json")
    p.add_argument("--out", default="runs/corpus_weights/weights",
                   help="folder of the set's files (default: %(default)s; a set adopted for the package goes "
                   f"to {MODELS_DIR} with its model-card section)")
    p.add_argument("--work", default="runs/corpus_weights",
                   help="folder of the rendered datasets, kept and reused (default: %(default)s)")
    p.add_argument("--exclude", default="", help="comma-separated train buildings to leave out (validation)")
    p.add_argument("--overwrite", action="store_true", help="replace the set's files")
    add_setting_options(p, CorpusConfig)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    return p


def main(argv: list[str] | None = None) -> int:
    """The command line; returns the exit status."""
    from uav_struct_env.processes import WorkerDied, interrupted_status, stop_on_sigterm
    from uav_struct_env.validate import refuse

    prog = "python -m uav_struct_env.training.corpus_weights"
    args = _parser().parse_args(argv)
    stop_on_sigterm()
    exclude = tuple(n for n in args.exclude.split(",") if n)
    try:
        config = CorpusConfig(**{f.name: getattr(args, f.name) for f in fields(CorpusConfig)})
        targets = train_corpus_weights(args.name, args.out, args.work, config, exclude,
                                       progress=not args.no_progress, overwrite=args.overwrite)
    except (ConfigError, FileExistsError) as err:
        return refuse(prog, err)
    except (WorkerDied, OSError) as err:
        return refuse(prog, f"{err}; no weights written", status=1)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; no weights written (rendered datasets are kept in {args.work})",
              file=sys.stderr)
        return interrupted_status()
    print("wrote " + ", ".join(str(p) for p in targets.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
