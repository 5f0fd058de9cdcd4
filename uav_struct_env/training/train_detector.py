"""Train the learned landmark detector (PyTorch, CPU) and export it to ONNX.

Only this module imports torch (the ``train`` extra). The exported model runs without it, in
:class:`localization.detect.learned.LearnedDetector` (ONNX Runtime).

The network is a small fully-convolutional CenterNet-style keypoint net: an encoder to stride 16,
a two-step top-down path back to stride 4, and a head with one heatmap per landmark type
(:data:`uav_struct_env.datasets.LANDMARK_TYPES`, sigmoid included in the graph) and two
sub-cell offset channels. Input: ``(1, 3, H, W)`` float RGB in 0..255 (normalized inside the
graph), ``H`` and ``W`` multiples of 16. Output: ``(1, 5, H/4, W/4)``.

Cell ``j`` of the output covers input pixels ``4j .. 4j + 3``; a keypoint at input pixel ``u``
has cell coordinate ``c = (u + 0.5) / 4 - 0.5``. Targets: a Gaussian (``sigma`` cells) splat
around ``c`` per type with 1 at the nearest cell (penalty-reduced focal loss, as CenterNet), and
the offsets ``c - j`` (L1) in the 3 x 3 cells around it.

Example (the committed model, see ``localization/detect/models/MODEL_CARD.md``)::

    python -m uav_struct_env.datasets /tmp/lmdata/train --layouts 200 --views 15 --seed 0
    python -m uav_struct_env.datasets /tmp/lmdata/val --layouts 10 --views 10 --seed 1
    python -m uav_struct_env.training.train_detector --data /tmp/lmdata/train --val /tmp/lmdata/val \
        --out runs/detector --minutes 45
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from localization.detect.onnx_net import OnnxNet
from uav_struct_env.datasets.landmarks import LANDMARK_TYPES, load_labels
from uav_struct_env.errors import UsageError
from uav_struct_env.outputs import atomic_path, atomic_write_json, prepare_output_dir
from uav_struct_env.training.init_weights import load_onnx_weights
from uav_struct_env.training.train_loop import (
    add_training_arguments,
    check_training_arguments,
    fit,
    make_loader,
)
from uav_struct_env.validate import INPUT_ERRORS, CommandParser, refuse

__all__ = ["KeypointNet", "conv_bn_relu", "export_checked", "export_onnx", "main", "train"]

STRIDE = 4
N_TYPES = len(LANDMARK_TYPES)


def conv_bn_relu(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    """3 x 3 convolution (padding 1, no bias), batch norm, ReLU."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout),
                         nn.ReLU(inplace=True))


class KeypointNet(nn.Module):
    """The keypoint network (see the module docstring). ``width`` scales every layer."""

    def __init__(self, width: int = 16) -> None:
        super().__init__()
        c1, c2, c3, c4 = width, int(1.5 * width), 3 * width, 4 * width
        self.s4 = nn.Sequential(conv_bn_relu(3, c1, 2), conv_bn_relu(c1, c2, 2), conv_bn_relu(c2, c2))
        self.s8 = nn.Sequential(conv_bn_relu(c2, c3, 2), conv_bn_relu(c3, c3))
        self.s16 = nn.Sequential(conv_bn_relu(c3, c4, 2), conv_bn_relu(c4, c4), conv_bn_relu(c4, c4))
        self.lat16 = nn.Conv2d(c4, c3, 1)
        self.fuse8 = conv_bn_relu(c3, c3)
        self.lat8 = nn.Conv2d(c3, c2, 1)
        self.fuse4 = conv_bn_relu(c2, c2)
        self.head = nn.Conv2d(c2, N_TYPES + 2, 1)
        nn.init.constant_(self.head.bias[:N_TYPES], -4.0)  # start near "no keypoint"
        nn.init.zeros_(self.head.bias[N_TYPES:])

    def logits(self, x: torch.Tensor) -> torch.Tensor:
        """Raw outputs: heatmap logits and offsets, ``(B, 5, H/4, W/4)``."""
        x = x * (1.0 / 127.5) - 1.0
        f4 = self.s4(x)
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        f8 = self.fuse8(f8 + F.interpolate(self.lat16(f16), scale_factor=2.0, mode="nearest"))
        f4 = self.fuse4(f4 + F.interpolate(self.lat8(f8), scale_factor=2.0, mode="nearest"))
        return self.head(f4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Heatmaps (sigmoid) and offsets, as the exported graph returns them."""
        out = self.logits(x)
        return torch.cat([torch.sigmoid(out[:, :N_TYPES]), out[:, N_TYPES:]], dim=1)


# ------------------------------------------------------------------------------------ data
def _targets(kps: np.ndarray, h: int, w: int, sigma: float):
    """Heatmap (T, h, w), offsets (2, h, w) and offset mask (h, w) at stride 4."""
    heat = np.zeros((N_TYPES, h, w), np.float32)
    off = np.zeros((2, h, w), np.float32)
    mask = np.zeros((h, w), np.float32)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for u, v, t in kps:
        cu, cv_ = (u + 0.5) / STRIDE - 0.5, (v + 0.5) / STRIDE - 0.5
        ju, jv = int(round(cu)), int(round(cv_))
        if not (0 <= ju < w and 0 <= jv < h):
            continue
        g = np.exp(-((xs - cu) ** 2 + (ys - cv_) ** 2) / (2 * sigma**2))
        g[jv, ju] = 1.0
        heat[int(t)] = np.maximum(heat[int(t)], g)
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                a, b = jv + dv, ju + du
                if 0 <= a < h and 0 <= b < w:
                    off[0, a, b], off[1, a, b] = cu - b, cv_ - a
                    mask[a, b] = 1.0 if (du, dv) == (0, 0) else max(mask[a, b], 0.5)
    return heat, off, mask


class LandmarkCrops(torch.utils.data.Dataset):
    """Random augmented crops of a landmark dataset, with stride-4 targets.

    Decoded images are kept in memory (per loader process) up to ``cache_mb`` megabytes: PNG
    decoding is a large part of a loader's time, and with camera imaging (noisy images compress
    poorly) a single loader process cannot keep up with the network on 2 cores.
    """

    def __init__(self, labels: dict, crop: tuple[int, int], seed: int, sigma: float = 1.0,
                 augment: bool = True, epoch_size: int | None = None, cache_mb: float = 4096.0) -> None:
        self.root = Path(labels["root"])
        self.records = labels["images"]
        self.crop, self.sigma, self.augment = crop, sigma, augment
        self.seed = seed
        self.epoch_size = epoch_size or len(self.records)
        self.calls = 0
        self.cache_bytes = int(cache_mb * 2**20)
        self._cache: dict[int, np.ndarray] = {}
        self._cached_bytes = 0

    def image(self, k: int) -> np.ndarray:
        """RGB image of record ``k`` (decoded once while the cache has room)."""
        img = self._cache.get(k)
        if img is None:
            img = cv2.cvtColor(cv2.imread(str(self.root / self.records[k]["file"])), cv2.COLOR_BGR2RGB)
            if self._cached_bytes + img.nbytes <= self.cache_bytes:
                self._cache[k] = img
                self._cached_bytes += img.nbytes
        return img

    def __len__(self) -> int:
        return self.epoch_size

    def __getitem__(self, index: int):
        rng = np.random.default_rng([self.seed, index, self.calls])
        self.calls += 1
        rec = self.records[index % len(self.records)]
        img = self.image(index % len(self.records))
        kps = np.array([k[:3] for k in rec["keypoints"]], np.float64).reshape(-1, 3)
        cw, ch = self.crop
        if self.augment:
            s = float(np.exp(rng.uniform(np.log(0.8), np.log(1.25))))
            # Centre the crop on a random keypoint most of the time (landmarks are sparse).
            if len(kps) and rng.random() < 0.8:
                cx, cy = kps[rng.integers(len(kps)), :2] * s + rng.uniform(-0.4, 0.4, 2) * (cw, ch)
            else:
                cx, cy = rng.uniform(0, img.shape[1] * s), rng.uniform(0, img.shape[0] * s)
            flip = rng.random() < 0.5
        else:
            s, flip = 1.0, False
            cx, cy = img.shape[1] / 2, img.shape[0] / 2
        # Affine map (pixel centres at integers): x' = s x + t.
        tx, ty = cw / 2 - cx, ch / 2 - cy
        A = np.array([[s, 0, tx], [0, s, ty]])
        if flip:
            A = np.array([[-1, 0, cw - 1], [0, 1, 0]]) @ np.vstack([A, [0, 0, 1]])
        crop = cv2.warpAffine(img, A, (cw, ch), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REFLECT101)
        uv = kps[:, :2] @ A[:, :2].T + A[:, 2]
        keep = (uv[:, 0] > -0.5) & (uv[:, 0] < cw - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < ch - 0.5)
        kps = np.column_stack([uv, kps[:, 2]])[keep]
        if self.augment:
            crop = self.photometric(crop, rng)
        heat, off, mask = _targets(kps, ch // STRIDE, cw // STRIDE, self.sigma)
        x = torch.from_numpy(np.ascontiguousarray(crop.transpose(2, 0, 1))).float()
        return x, torch.from_numpy(heat), torch.from_numpy(off), torch.from_numpy(mask)

    @staticmethod
    def photometric(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        x = img.astype(np.float32)
        x = x * rng.uniform(0.7, 1.3) + rng.uniform(-25, 25)  # contrast, brightness
        x = x * rng.uniform(0.9, 1.1, 3)  # colour balance
        if rng.random() < 0.5:
            gamma = rng.uniform(0.7, 1.4)
            x = 255.0 * (np.clip(x, 0, 255) / 255.0) ** gamma
        if rng.random() < 0.3:
            x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.3, 0.9))
        x = x + rng.normal(0, rng.uniform(0, 6), x.shape)
        return np.clip(x, 0, 255).astype(np.uint8)


# ------------------------------------------------------------------------------------ loss
def focal_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced pixel-wise focal loss (alpha 2, beta 4), per keypoint."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1.0).float()
    pos_loss = -torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = -torch.log(1 - p) * p**2 * (1 - target) ** 4 * (1 - pos)
    n = pos.sum().clamp(min=1.0)
    return (pos_loss.sum() + neg_loss.sum()) / n


def loss_fn(out, heat, off, mask):
    """Focal loss on the heatmaps plus L1 on the offsets (weight 1)."""
    hm = focal_loss(out[:, :N_TYPES], heat)
    m = mask.unsqueeze(1)
    l1 = (torch.abs(out[:, N_TYPES:] - off) * m).sum() / m.sum().clamp(min=1.0)
    return hm + l1, hm.detach(), l1.detach()


# ------------------------------------------------------------------------------------ export
def export_checked(model: nn.Module, example: torch.Tensor, path: str | Path, input_name: str,
                   output_name: str, dynamic_axes: dict) -> Path:
    """Export ``model`` to ONNX at ``path`` and check it in ONNX Runtime (as inference runs it).

    Eval mode (batch norm folded); ONNX Runtime must reproduce torch on ``example`` within 1e-3
    (else RuntimeError).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model = model.eval()
    with warnings.catch_warnings():  # the TorchScript exporter's deprecation notice
        warnings.simplefilter("ignore", DeprecationWarning)
        with atomic_path(path) as tmp:
            torch.onnx.export(model, example, str(tmp), opset_version=13, dynamo=False,
                              input_names=[input_name], output_names=[output_name],
                              do_constant_folding=True, dynamic_axes=dynamic_axes)
    got = OnnxNet(path)(example.numpy())
    with torch.no_grad():
        want = model(example).numpy()
    err = float(np.abs(got - want).max())
    if err > 1e-3:
        raise RuntimeError(f"ONNX Runtime output differs from torch by {err:.2e} (> 1e-3)")
    return path


def export_onnx(model: KeypointNet, path: str | Path, size: tuple[int, int] = (640, 368)) -> Path:
    """Export the keypoint net, traced at ``size = (W, H)`` with H and W as dynamic axes."""
    x = torch.rand(1, 3, size[1], size[0]) * 255
    return export_checked(model, x, path, "image", "heatmaps_offsets",
                          {"image": {2: "height", 3: "width"},
                           "heatmaps_offsets": {2: "h4", 3: "w4"}})


# ------------------------------------------------------------------------------------ training
def _evaluate(model: KeypointNet, labels: dict) -> dict:
    """P/R at 1.5 px (3 px full resolution) on a validation set, with the numpy decoder."""
    from localization.detect.learned import decode, match_detections

    model.eval()
    root = Path(labels["root"])
    tp = fp = fn = 0
    errs = []
    for rec in labels["images"]:
        img = cv2.cvtColor(cv2.imread(str(root / rec["file"])), cv2.COLOR_BGR2RGB)
        h, w = img.shape[:2]
        ph, pw = -(-h // 16) * 16, -(-w // 16) * 16
        pad = cv2.copyMakeBorder(img, 0, ph - h, 0, pw - w, cv2.BORDER_REPLICATE)
        with torch.no_grad():
            out = model(torch.from_numpy(pad.transpose(2, 0, 1)[None].copy()).float())[0].numpy()
        kps = np.array([k[:3] for k in rec["keypoints"]], np.float64).reshape(-1, 3)
        for t in range(N_TYPES):
            uv, _, _ = decode(out, types=(t,), image_size=(w, h))
            gt = kps[kps[:, 2] == t, :2]
            m, d = match_detections(uv, gt, 1.5)
            tp += int((m >= 0).sum())
            fp += int((m < 0).sum())
            fn += len(gt) - int((m >= 0).sum())
            errs += d[m >= 0].tolist()
    model.train()
    p = tp / max(tp + fp, 1)
    r = tp / max(tp + fn, 1)
    return {"precision": p, "recall": r, "f1": 2 * p * r / max(p + r, 1e-9),
            "median_err_px": float(np.median(errs)) if errs else float("nan")}


def pool_labels(paths: list[str | Path]) -> dict:
    """Several datasets as one: every image's ``file`` made absolute (``root`` is ``/``)."""
    if not paths:
        raise ValueError("pool_labels needs at least one dataset")
    sets = [load_labels(p) for p in paths]
    images = [{**rec, "file": str((Path(s["root"]) / rec["file"]).resolve())}
              for s in sets for rec in s["images"]]
    return {**sets[0], "root": "/", "images": images}


def train(data: str | list[str], out: str, val: str | None = None, minutes: float = 45.0,
          max_steps: int | None = None, batch: int = 16, crop: tuple[int, int] = (256, 192),
          lr: float = 3e-3, width: int = 16, seed: int = 0, threads: int = 2,
          eval_every: int = 500, workers: int = 1, init: str | Path | None = None,
          warmup_steps: int = 200, log=print) -> dict:
    """Train from scratch (or from ``init``); writes ``out/{last,best}.pt``, ``log.jsonl``, ``model.onnx``.

    ``data`` is one dataset or several (their images pooled: for example random sites and an IFC
    building).

    Stops after ``minutes`` of wall time or ``max_steps`` steps (the cosine learning-rate
    schedule runs over the time budget). ``init``: an exported keypoint network (ONNX, same
    ``width``) to fine-tune (:func:`~uav_struct_env.training.init_weights.load_onnx_weights`:
    its batch norms stay frozen). Returns a summary dict.
    """
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    cv2.setNumThreads(1)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    labels = pool_labels([data] if isinstance(data, (str, Path)) else data)
    val_labels = load_labels(val) if val else None
    loader = make_loader(LandmarkCrops(labels, crop, seed, epoch_size=10**7), batch, workers, seed)
    # Channels-last (NHWC) convolutions: faster on a CPU (docs/benchmarks.md; the refiner trainer
    # does the same).
    model = KeypointNet(width)
    if init is not None:
        load_onnx_weights(model, init, torch.rand(1, 3, 64, 64) * 255)
    model = model.to(memory_format=torch.channels_last)

    def step_loss(batch):
        x, heat, off, mask = batch
        x = x.contiguous(memory_format=torch.channels_last)
        loss, hm, l1 = loss_fn(model.logits(x), heat, off, mask)
        return loss, {"heat": hm, "offset": l1}

    summary = fit(model, loader, step_loss, out_dir, minutes=minutes, max_steps=max_steps, lr=lr,
                  warmup_steps=warmup_steps, eval_every=eval_every, log=log,
                  validate=None if val_labels is None else lambda: _evaluate(model, val_labels))
    onnx_path = export_onnx(model, out_dir / "model.onnx")
    summary.update(params=sum(p.numel() for p in model.parameters()),
                   train_images=len(labels["images"]), onnx=str(onnx_path), seed=seed,
                   batch=batch, crop=list(crop), width=width,
                   init=None if init is None else str(Path(init).resolve()))
    atomic_write_json(out_dir / "summary.json", summary, indent=2)
    return summary


def main(argv: list[str] | None = None) -> dict:
    """Command line: ``python -m uav_struct_env.training.train_detector --data DIR --out DIR``."""
    ap = CommandParser(prog="python -m uav_struct_env.training.train_detector",
                                 description="Train the learned landmark detector.")
    ap.add_argument("--data", required=True, nargs="+",
                    help="training dataset(s) (labels.json or its folder; several are pooled)")
    ap.add_argument("--val", default=None, help="validation dataset (checkpoint selection)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--crop", type=int, nargs=2, default=(256, 192), metavar=("W", "H"))
    add_training_arguments(ap, minutes=45.0, batch=16, lr=3e-3)
    a = ap.parse_args(argv)
    try:  # every input before any work or any file
        check_training_arguments(a)
        if a.crop[0] % 16 or a.crop[1] % 16 or min(a.crop) < 16:
            raise UsageError(f"--crop must be positive multiples of 16, got {a.crop}")
    except INPUT_ERRORS as err:
        raise SystemExit(refuse(ap.prog, err)) from None
    prepare_output_dir(a.out, overwrite=a.overwrite)
    summary = train(a.data, a.out, a.val, a.minutes, a.max_steps, a.batch, tuple(a.crop), a.lr,
                    a.width, a.seed, a.threads, a.eval_every, a.workers, a.init)
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
