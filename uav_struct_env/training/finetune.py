"""Fine-tune a committed weight set on rendered landmark datasets: the keypoint network, then its refiner.

Shared by ``uav-struct adapt`` (:mod:`uav_struct_env.training.adapt`: renders of one building)
and the corpus weights (:mod:`uav_struct_env.training.corpus_weights`: renders of the real-building
corpus's train buildings and of random sites). :func:`render_dataset` renders one labelled dataset
(:func:`dataset_config`: site activity, camera and imaging all ``mixed``); :func:`finetune` then

1. fine-tunes the keypoint network from the base set's ONNX file on the half-resolution datasets
   (:func:`uav_struct_env.training.train_detector.train`, its images pooled; the graph's batch
   norms stay frozen);
2. mines windows from the full-resolution datasets with the *fine-tuned* keypoint network and
   fine-tunes the base set's patch refiner on them
   (:func:`uav_struct_env.training.train_refiner.train`).

Both trainings run a fixed number of steps with one seed, so the weights do not depend on the
machine's load (the wall time does); the last weights are kept (no checkpoint is chosen on a
validation set).
"""

from __future__ import annotations

import argparse
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from localization.checks import check_number
from localization.detect.weights import WeightSet
from uav_struct_env.errors import ConfigError

__all__ = ["REFINER_BATCH", "FinetuneSettings", "Laps", "StepBar", "add_setting_options", "check_settings",
           "dataset_config", "finetune", "render_dataset"]

#: The refiner's batch (the trainer's default), or every mined window if there are fewer.
REFINER_BATCH = 128


class FinetuneSettings(Protocol):
    """What :func:`finetune` reads from a command's settings (``AdaptConfig``, ``CorpusConfig``)."""

    keypoint_steps: int
    refiner_steps: int
    keypoint_lr: float
    refiner_lr: float
    seed: int
    threads: int


def check_settings(config: Any, zero_ok: Sequence[str] = ("seed",)) -> None:
    """Check every field of a settings dataclass (``AdaptConfig``, ``CorpusConfig``).

    Integers must be at least 1 (at least 0 for the fields in ``zero_ok``), floats (learning
    rates) in (0, 1].

    Raises:
        ConfigError: naming the class, the field and the value.
    """
    name = type(config).__name__
    for f in fields(config):
        value = getattr(config, f.name)
        if f.type == "int":
            check_number(f"{name}.{f.name}", value, 0 if f.name in zero_ok else 1, integer=True,
                         error=ConfigError, type_error=ConfigError)
        else:
            check_number(f"{name}.{f.name}", value, 0, 1, lo_open=True, error=ConfigError,
                         type_error=ConfigError)


def add_setting_options(parser: argparse.ArgumentParser, cls: type) -> None:
    """One ``--field-name`` option per field of the settings dataclass ``cls``, its default shown."""
    defaults = cls()
    for f in fields(cls):
        value = getattr(defaults, f.name)
        parser.add_argument("--" + f.name.replace("_", "-"), type=int if f.type == "int" else float,
                            default=value, help=f"(default {value})")


class StepBar:
    """A progress bar over a trainer's steps, fed by its log records (one every 50 steps)."""

    def __init__(self, total: int, desc: str, progress: bool) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, unit="step", disable=not progress)

    def __call__(self, record: dict) -> None:
        """Advance to the record's step (records without one are ignored)."""
        if "step" in record:
            self.bar.update(record["step"] - self.bar.n)
            self.bar.set_postfix(loss=record["loss"])

    def close(self) -> None:
        """Fill the bar (a run may stop short of a log record) and close it."""
        self.bar.update(self.bar.total - self.bar.n)
        self.bar.close()


class Laps:
    """Minutes of wall time per phase, in the order the phases ran."""

    def __init__(self) -> None:
        self.minutes: dict[str, float] = {}
        self._t = time.perf_counter()

    def __call__(self, name: str) -> None:
        """Close the phase ``name``: the minutes since the last lap (or the start)."""
        self.minutes[name] = round((time.perf_counter() - self._t) / 60.0, 2)
        self._t = time.perf_counter()


def dataset_config(site: str | Path, layouts: int, views: int, seed: int, scale: float,
                   stages: tuple[str, ...] | None = None):
    """One fine-tuning dataset's settings (a ``DatasetConfig``): activity, camera, imaging ``mixed``.

    ``site`` is ``"random"`` or a building file (site JSON or IFC); ``stages``: the building's
    stages its layouts draw from (None: all).
    """
    from uav_struct_env.datasets.landmarks import DatasetConfig

    return DatasetConfig(n_layouts=layouts, views_per_layout=views, seed=seed, scale=scale, site=str(site),
                         activity="mixed", camera="mixed", imaging="mixed", stages=stages)


def render_dataset(config, out: Path, workers: int, progress: bool) -> Path:
    """Render the dataset of ``config`` (a ``DatasetConfig``) into ``out``; its labels.json."""
    from uav_struct_env.datasets.landmarks import generate

    return generate(config, out, workers=workers, progress=progress)


def _labels(path: Path) -> list:
    from uav_struct_env.datasets.landmarks import load_labels

    return load_labels(path)["images"]


def finetune(settings: FinetuneSettings, base: WeightSet, keypoint_data: Sequence[Path],
             refiner_data: Sequence[Path], final: Mapping[str, Path], work: Path, progress: bool,
             laps: Laps) -> dict:
    """Fine-tune ``base`` into ``final["model"]`` and ``final["refiner"]``; returns the counts.

    Args:
        settings: steps, learning rates, seed and torch threads.
        base: the weight set fine-tuned.
        keypoint_data: half-resolution datasets (their labels.json files or folders), pooled.
        refiner_data: full-resolution datasets the refiner's windows are mined from.
        final: where the two ONNX files go (``"model"``, ``"refiner"``).
        work: a scratch folder for the trainers' checkpoints and the mined windows.
        progress: show progress bars.
        laps: the phases' minutes are recorded there (``keypoint_network``, ``mine``, ``refiner``).

    Returns:
        ``steps`` and ``images`` per network, ``refiner_windows`` and ``refiner_batch``.
    """
    from uav_struct_env.training import train_detector, train_refiner

    data = [str(p) for p in keypoint_data]
    bar = StepBar(settings.keypoint_steps, "keypoint network", progress)
    kp = train_detector.train(data, str(work / "keypoint"), minutes=1e9,
                              max_steps=settings.keypoint_steps, lr=settings.keypoint_lr, seed=settings.seed,
                              threads=settings.threads, workers=0, init=base.model, warmup_steps=100, log=bar)
    bar.close()
    shutil.move(kp["onnx"], final["model"])
    laps("keypoint_network")
    mined = [str(p) for p in refiner_data]
    windows = train_refiner.mine(mined, str(work / "windows.npz"),
                                 model=str(final["model"]), seed=settings.seed, progress=progress)
    laps("mine")
    bar = StepBar(settings.refiner_steps, "patch refiner", progress)
    with np.load(windows) as arrays:  # a building too small for one batch of windows trains on all it has
        batch = min(REFINER_BATCH, len(arrays["kind"]))
    ref = train_refiner.train(str(windows), str(work / "refiner"), minutes=1e9, batch=batch,
                              max_steps=settings.refiner_steps, lr=settings.refiner_lr, seed=settings.seed,
                              threads=settings.threads, workers=0, detector_model=str(final["model"]),
                              init=base.refiner, warmup_steps=50, log=bar)
    bar.close()
    shutil.move(ref["onnx"], final["refiner"])
    laps("refiner")
    return {"steps": {"keypoint_network": kp["steps"], "refiner": ref["steps"]},
            "images": {"keypoint_network": kp["train_images"],
                       "refiner": sum(len(_labels(Path(p))) for p in refiner_data)},
            "refiner_windows": ref["train_windows"], "refiner_batch": batch}
