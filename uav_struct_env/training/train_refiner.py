r"""Train the learned detector's full-resolution patch refiner (PyTorch, CPU); export to ONNX.

The refiner (:class:`localization.detect.refiner.PatchRefiner` at inference, ONNX Runtime) takes a
``PATCH x PATCH`` full-resolution patch around a keypoint candidate of the half-resolution
keypoint network and returns, per landmark type, the probability that a landmark of that type
lies within :data:`~localization.detect.refiner.POSITIVE_RADIUS` px of the patch centre and its offset.

Two steps, both seeded:

1. :func:`mine` reads a **full-resolution** landmark dataset (``python -m uav_struct_env.datasets
   OUT --scale 1.0``) and stores, per image, ``WINDOW x WINDOW`` windows (larger than a patch, so
   that training can shift the patch) around three kinds of anchors: every ground-truth keypoint,
   every candidate of the keypoint network (threshold 0.2, no refinement: the distribution the
   refiner sees at inference, with its false positives) and strong image corners far from every
   landmark (hard negatives). With every window: the offset of the nearest landmark of each type.
2. :func:`train` crops patches from the windows at random shifts (up to :data:`MAX_SHIFT` px
   around ground-truth anchors, fewer around candidates and negatives), flips them horizontally
   and applies photometric augmentation; loss = binary cross-entropy of the three scores + L1 of
   the offset of every type present within the positive radius. Checkpoints are chosen by the F1
   at 3 px of the whole detector (keypoint network + this refiner) on a validation dataset.
   ``--jpeg P,QLO,QHI`` (off by default) also JPEG-compresses that fraction of the windows
   (:mod:`uav_struct_env.training.jpeg_augment`), for photos: the refiner is the stage a camera's
   JPEG costs accuracy (``benchmarks/photo_jpeg_gap.py``, docs/photos.md).

Example (the committed refiner, see ``localization/detect/models/MODEL_CARD.md``)::

    python -m uav_struct_env.datasets /tmp/refdata/train --layouts 150 --views 10 --seed 3 --scale 1.0
    python -m uav_struct_env.datasets /tmp/refdata/val --layouts 6 --views 10 --seed 1 --scale 1.0
    python -m uav_struct_env.training.train_refiner --data /tmp/refdata/train --val /tmp/refdata/val \\
        --out /tmp/refrun/v1 --minutes 15
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from localization.detect.learned import DEFAULT_MODEL, LANDMARK_TYPES, LearnedDetector, match_detections
from localization.detect.refiner import HALF, PATCH, POSITIVE_RADIUS, extract_patches
from uav_struct_env.datasets.landmarks import load_labels
from uav_struct_env.errors import ConfigError, UsageError
from uav_struct_env.outputs import atomic_path, atomic_write_json, prepare_output_dir
from uav_struct_env.training.init_weights import load_onnx_weights
from uav_struct_env.training.jpeg_augment import JpegAugment
from uav_struct_env.training.train_detector import LandmarkCrops, conv_bn_relu, export_checked
from uav_struct_env.training.train_loop import (
    add_training_arguments,
    check_training_arguments,
    fit,
    make_loader,
)
from uav_struct_env.validate import INPUT_ERRORS, CommandParser, check_input_file, refuse

__all__ = ["MAX_SHIFT", "PatchNet", "PatchSamples", "export_refiner", "main", "mine", "train"]

N_TYPES = len(LANDMARK_TYPES)
#: Largest shift (px, per axis) of a training patch from its ground-truth anchor.
MAX_SHIFT = 10
WINDOW = PATCH + 2 * MAX_SHIFT
_ANCHOR_TRUTH, _ANCHOR_CANDIDATE, _ANCHOR_NEGATIVE = 0, 1, 2


class PatchNet(nn.Module):
    """The refiner network: ``(N, 3, PATCH, PATCH)`` RGB 0..255 -> ``(N, 9)``.

    Output: three sigmoid scores (one per landmark type), then ``(du, dv)`` per type in px.
    """

    def __init__(self, width: int = 16) -> None:
        super().__init__()
        c = width
        self.features = nn.Sequential(
            conv_bn_relu(3, c), conv_bn_relu(c, c), nn.MaxPool2d(2),  # 33 -> 16
            conv_bn_relu(c, 2 * c), conv_bn_relu(2 * c, 2 * c), nn.MaxPool2d(2),  # -> 8
            conv_bn_relu(2 * c, 3 * c), conv_bn_relu(3 * c, 3 * c), nn.MaxPool2d(2),  # -> 4
            conv_bn_relu(3 * c, 4 * c),
        )
        side = PATCH // 8
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(4 * c * side * side, 128),
                                  nn.ReLU(inplace=True), nn.Linear(128, 3 * N_TYPES))

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """Raw outputs: score logits (N, 3) and offsets (N, 6)."""
        return self.head(self.features(x * (1.0 / 127.5) - 1.0))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Scores (sigmoid) and offsets, as the exported graph returns them."""
        out = self.logits(x)
        return torch.cat([torch.sigmoid(out[:, :N_TYPES]), out[:, N_TYPES:]], dim=1)


# ------------------------------------------------------------------------------------ mining
def _nearest_offsets(anchors: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """Offsets ``(N, 3, 2)`` from each anchor to the nearest keypoint of each type.

    NaN where no keypoint of that type lies within the window.
    """
    out = np.full((len(anchors), N_TYPES, 2), np.nan, np.float32)
    for t in range(N_TYPES):
        gt = kps[kps[:, 2] == t, :2]
        if len(gt) == 0 or len(anchors) == 0:
            continue
        d = gt[None, :, :] - anchors[:, None, :]
        n = np.argmin(np.hypot(d[..., 0], d[..., 1]), axis=1)
        near = d[np.arange(len(anchors)), n]
        inside = np.all(np.abs(near) <= WINDOW // 2, axis=1)
        out[inside, t] = near[inside]
    return out


def mine(data: str | Sequence[str], out: str, model: str | None = None, negatives: int = 12,
         seed: int = 0, progress: bool = True) -> Path:
    """Windows around ground truth, keypoint-network candidates and hard negatives -> NPZ.

    Args:
        data: one or several full-resolution landmark datasets (``scale`` 1.0).
        out: path of the ``.npz`` written (``windows`` uint8 (N, WINDOW, WINDOW, 3), ``offsets``
            float32 (N, 3, 2), ``kind`` int8 (N,), ``image`` int32 (N,)).
        model: keypoint-network ONNX (default: the committed one).
        negatives: hard negatives per image (strong corners > 2 x the positive radius from
            every landmark).
        seed: seed of the negative sampling.
        progress: show a progress bar.
    """
    from tqdm import tqdm

    images = []
    for path in [data] if isinstance(data, (str, Path)) else data:
        labels = load_labels(path)
        if labels.get("scale") != 1.0:
            raise ValueError(f"{path}: the refiner trains on full-resolution renders (dataset "
                             f"scale 1.0), got scale {labels.get('scale')!r}")
        images += [(Path(labels["root"]) / rec["file"], rec) for rec in labels["images"]]
    det = LearnedDetector("all", model=model, refiner=False, corner_window=0, score_threshold=0.2)
    rng = np.random.default_rng(seed)
    parts: dict[str, list] = {"windows": [], "offsets": [], "kind": [], "image": []}
    for k, (file, rec) in enumerate(tqdm(images, unit="img", disable=not progress)):
        img = cv2.cvtColor(cv2.imread(str(file)), cv2.COLOR_BGR2RGB)
        kps = np.array([kp[:3] for kp in rec["keypoints"]], np.float64).reshape(-1, 3)
        cand, _, _ = det.detect_all(img)
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        corners = cv2.goodFeaturesToTrack(gray, 8 * negatives, 0.02, 6)
        corners = np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2)
        if len(kps):
            d = np.hypot(*(corners[:, None, :] - kps[None, :, :2]).transpose(2, 0, 1))
            corners = corners[d.min(axis=1) > 2 * POSITIVE_RADIUS]
        corners = corners[rng.permutation(len(corners))[:negatives]]
        groups = ((kps[:, :2], _ANCHOR_TRUTH), (cand, _ANCHOR_CANDIDATE),
                  (corners, _ANCHOR_NEGATIVE))
        for pts, kind in groups:
            if len(pts) == 0:
                continue
            windows, anchors = extract_patches(img, pts, WINDOW)
            parts["windows"].append(windows)
            parts["offsets"].append(_nearest_offsets(anchors.astype(np.float64), kps))
            parts["kind"].append(np.full(len(anchors), kind, np.int8))
            parts["image"].append(np.full(len(anchors), k, np.int32))
    arrays = {name: np.concatenate(v) for name, v in parts.items()}
    path = Path(out)
    path = path if path.suffix == ".npz" else path.with_name(path.name + ".npz")  # as np.savez
    with atomic_path(path) as tmp:
        np.savez(tmp, **arrays)
    return path


# ------------------------------------------------------------------------------------ data
class PatchSamples(torch.utils.data.Dataset):
    """Augmented training patches cut from mined windows (see the module docstring).

    ``jpeg``: also JPEG-compress the windows (:class:`~uav_struct_env.training.jpeg_augment.JpegAugment`;
    None, the default: never). With it the photometric augmentation is applied to the window
    before the compression, as a camera does; without it to the patch, as the committed weights
    were trained.
    """

    def __init__(self, arrays: dict, seed: int, augment: bool = True,
                 jpeg: JpegAugment | None = None) -> None:
        self.windows = arrays["windows"]
        self.offsets = arrays["offsets"]
        self.kind = arrays["kind"]
        self.seed, self.augment, self.jpeg = seed, augment, jpeg
        self.calls = 0

    def __len__(self) -> int:
        return len(self.windows)

    def _shift(self, kind: int, rng: np.random.Generator) -> np.ndarray:
        if kind == _ANCHOR_TRUTH:
            # Half near the landmark (the second refinement pass), half anywhere in the radius.
            r = rng.uniform(0, 2.5) if rng.random() < 0.5 else MAX_SHIFT * math.sqrt(rng.random())
            a = rng.uniform(0, 2 * math.pi)
            s = np.round([r * math.cos(a), r * math.sin(a)])
        else:
            lim = 2 if kind == _ANCHOR_CANDIDATE else 4
            s = rng.integers(-lim, lim + 1, 2)
        return np.clip(s, -MAX_SHIFT, MAX_SHIFT).astype(np.int64)

    def __getitem__(self, index: int):
        rng = np.random.default_rng([self.seed, index, self.calls])
        self.calls += 1
        su, sv = self._shift(int(self.kind[index]), rng) if self.augment else (0, 0)
        c = WINDOW // 2
        window = self.windows[index]
        if self.augment and self.jpeg is not None:
            # The camera's imaging first, then its JPEG, on the whole window (the block grid
            # spans the patch's surroundings as in a photo).
            window = self.jpeg(LandmarkCrops.photometric(window, rng), rng)
        patch = window[c + sv - HALF:c + sv + HALF + 1, c + su - HALF:c + su + HALF + 1]
        off = self.offsets[index] - np.array([su, sv], np.float32)
        if self.augment and rng.random() < 0.5:
            patch = patch[:, ::-1]
            off = off * np.array([-1.0, 1.0], np.float32)
        if self.augment and self.jpeg is None:
            patch = LandmarkCrops.photometric(np.ascontiguousarray(patch), rng)
        present = np.isfinite(off[:, 0]) & (np.hypot(off[:, 0], off[:, 1]) <= POSITIVE_RADIUS)
        off = np.where(present[:, None], off, 0.0).astype(np.float32)
        x = torch.from_numpy(np.ascontiguousarray(patch.transpose(2, 0, 1))).float()
        return x, torch.from_numpy(present.astype(np.float32)), torch.from_numpy(off)


def loss_fn(out: torch.Tensor, present: torch.Tensor, off: torch.Tensor):
    """BCE of the scores + L1 (px) of the offsets of the types present."""
    bce = F.binary_cross_entropy_with_logits(out[:, :N_TYPES], present)
    pred = out[:, N_TYPES:].reshape(-1, N_TYPES, 2)
    m = present.unsqueeze(-1)
    l1 = (torch.abs(pred - off) * m).sum() / (2 * m.sum()).clamp(min=1.0)
    return bce + l1, bce.detach(), l1.detach()


def export_refiner(model: PatchNet, path: str | Path) -> Path:
    """Export the refiner with a dynamic batch axis (checked in ONNX Runtime)."""
    x = torch.rand(5, 3, PATCH, PATCH) * 255
    return export_checked(model, x, path, "patches", "scores_offsets",
                          {"patches": {0: "n"}, "scores_offsets": {0: "n"}})


# ------------------------------------------------------------------------------------ training
def evaluate(refiner: str | Path, labels: dict, match_px: float = 3.0,
             detector_model: str | None = None) -> dict:
    """Precision / recall / F1 at ``match_px`` of the whole detector with this refiner."""
    det = LearnedDetector("all", model=detector_model, refiner=refiner)
    root = Path(labels["root"])
    tp = np.zeros(N_TYPES, int)
    fp = np.zeros(N_TYPES, int)
    fn = np.zeros(N_TYPES, int)
    for rec in labels["images"]:
        img = cv2.cvtColor(cv2.imread(str(root / rec["file"])), cv2.COLOR_BGR2RGB)
        uv, _, kinds = det.detect_all(img)
        kps = np.array([k[:3] for k in rec["keypoints"]], np.float64).reshape(-1, 3)
        for t in range(N_TYPES):
            gt = kps[kps[:, 2] == t, :2]
            m, _ = match_detections(uv[kinds == t], gt, match_px)
            tp[t] += int((m >= 0).sum())
            fp[t] += int((m < 0).sum())
            fn[t] += len(gt) - int((m >= 0).sum())
    p = float(tp.sum() / max(tp.sum() + fp.sum(), 1))
    r = float(tp.sum() / max(tp.sum() + fn.sum(), 1))
    per_type = {name: {"precision": round(float(tp[t] / max(tp[t] + fp[t], 1)), 4),
                       "recall": round(float(tp[t] / max(tp[t] + fn[t], 1)), 4)}
                for t, name in enumerate(LANDMARK_TYPES)}
    return {"precision": p, "recall": r, "f1": 2 * p * r / max(p + r, 1e-9), "types": per_type}


def train(windows: str, out: str, val: str | None = None, minutes: float = 15.0,
          max_steps: int | None = None, batch: int = 128, lr: float = 2e-3, width: int = 16,
          seed: int = 0, threads: int = 2, eval_every: int = 500, workers: int = 1,
          detector_model: str | None = None, init: str | Path | None = None,
          warmup_steps: int = 100, jpeg: JpegAugment | None = None, log=print) -> dict:
    """Train from scratch (or from ``init``) on mined windows; returns the summary.

    Writes ``out/{last,best}.pt``, ``out/log.jsonl``, ``out/refiner.onnx`` and
    ``out/summary.json``. Stops after ``minutes`` of wall time or ``max_steps`` steps.
    Validation runs the refiner behind ``detector_model`` (None: the committed keypoint network).
    ``init``: an exported refiner (ONNX, same ``width``) to fine-tune
    (:func:`~uav_struct_env.training.init_weights.load_onnx_weights`: its batch norms stay frozen).
    ``jpeg``: JPEG-compress training windows (:class:`PatchSamples`; None: never).
    """
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    cv2.setNumThreads(1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    ds = PatchSamples(dict(np.load(windows)), seed, jpeg=jpeg)
    val_labels = load_labels(val) if val else None
    # Channels-last (NHWC) convolutions: faster on a CPU, so a wall-time budget trains more steps
    # (docs/benchmarks.md).
    model = PatchNet(width)
    if init is not None:
        load_onnx_weights(model, init, torch.rand(2, 3, PATCH, PATCH) * 255)
    model = model.to(memory_format=torch.channels_last)

    def step_loss(batch):
        x, present, off = batch
        x = x.contiguous(memory_format=torch.channels_last)
        loss, bce, l1 = loss_fn(model.logits(x), present, off)
        return loss, {"bce": bce, "offset_px": l1}

    def validate() -> dict:
        return evaluate(export_refiner(model, out_dir / "candidate.onnx"), val_labels,
                        detector_model=detector_model)

    summary = fit(model, make_loader(ds, batch, workers, seed), step_loss, out_dir,
                  minutes=minutes, max_steps=max_steps, lr=lr, warmup_steps=warmup_steps,
                  validate=None if val_labels is None else validate, eval_every=eval_every,
                  log=log)
    onnx_path = export_refiner(model, out_dir / "refiner.onnx")
    (out_dir / "candidate.onnx").unlink(missing_ok=True)
    summary.update(params=sum(p.numel() for p in model.parameters()), train_windows=len(ds),
                   onnx=str(onnx_path), seed=seed, batch=batch, width=width,
                   detector_model=str(Path(detector_model or DEFAULT_MODEL).resolve()),
                   init=None if init is None else str(Path(init).resolve()))
    if jpeg is not None:
        summary["jpeg"] = asdict(jpeg)
    atomic_write_json(out_dir / "summary.json", summary, indent=2)
    return summary


def parse_jpeg(text: str) -> JpegAugment:
    """``--jpeg P,QLO,QHI`` as a :class:`JpegAugment`.

    Raises:
        UsageError: naming the option, for anything but three numbers a JpegAugment accepts.
    """
    parts = text.split(",")
    try:
        if len(parts) != 3:
            raise ValueError
        return JpegAugment(probability=float(parts[0]), quality=(int(parts[1]), int(parts[2])))
    except (ValueError, ConfigError) as err:
        detail = f" ({err})" if str(err) else ""
        raise UsageError(f"--jpeg must be P,QLO,QHI (a fraction and two JPEG qualities 1-100), got "
                         f"{text!r}{detail}") from None


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m uav_struct_env.training.train_refiner --data DIR --out DIR``."""
    ap = CommandParser(prog="python -m uav_struct_env.training.train_refiner",
                                 description="Train the learned detector's patch refiner.")
    ap.add_argument("--data", required=True, nargs="+",
                    help="full-resolution training dataset(s)")
    ap.add_argument("--val", default=None, help="full-resolution validation dataset")
    ap.add_argument("--out", required=True)
    ap.add_argument("--windows", default=None,
                    help="mined windows .npz (default OUT/windows.npz, mined when missing)")
    ap.add_argument("--detector-model", default=None, metavar="ONNX",
                    help="keypoint network whose candidates are mined and behind which the "
                         "refiner is validated (default: the committed one); give the new "
                         "one when retraining both networks")
    ap.add_argument("--jpeg", default=None, metavar="P,QLO,QHI",
                    help="JPEG-compress this fraction P of the training windows at a quality drawn "
                         "from QLO..QHI and a chroma subsampling drawn from 4:4:4, 4:2:2 and 4:2:0 "
                         "(e.g. 0.75,80,100; default: never)")
    add_training_arguments(ap, minutes=15.0, batch=128, lr=2e-3)
    a = ap.parse_args(argv)
    try:  # every input before any work or any file
        if a.detector_model is not None:
            check_input_file(a.detector_model, option="--detector-model", what="ONNX file")
        check_training_arguments(a)
        jpeg = None if a.jpeg is None else parse_jpeg(a.jpeg)
    except INPUT_ERRORS as err:
        raise SystemExit(refuse(ap.prog, err)) from None
    prepare_output_dir(a.out, overwrite=a.overwrite)
    windows = Path(a.windows or Path(a.out) / "windows.npz")
    if not windows.exists():
        mine(a.data, str(windows), model=a.detector_model, seed=a.seed)
    summary = train(str(windows), a.out, a.val, a.minutes, a.max_steps, a.batch, a.lr, a.width,
                    a.seed, a.threads, a.eval_every, a.workers, a.detector_model, a.init, jpeg=jpeg)
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
