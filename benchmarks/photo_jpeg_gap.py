"""Where JPEG compression costs the learned detector its placement (issue 42, item 6).

Renders full-resolution labelled views (:mod:`uav_struct_env.datasets`, scale 1.0, ideal
imaging) of the paper site written as an IFC, or reads a labelled dataset (``--data``), and
encodes each image losslessly and as JPEGs (``--encodings``: ``q95``, ``q100``, a chroma suffix
``_444`` / ``_422`` for 4:4:4 / 4:2:2 instead of Pillow's 4:2:0, ``gray`` for the luma of the
lossless image in all three channels). For each encoding and landmark type it prints the recall
at 3 px and the median / mean pixel error of

* ``cand``: the keypoint network's candidates (half resolution, before the refiner);
* ``final``: the refined detections (the detector as the localizer runs it, ``recall``
  operating point);
* ``ref@jpg``: the lossless image's candidates refined on the JPEG (the refiner's own share);
* ``cand@jpg``: the JPEG's candidates refined on the lossless image (the candidates' share);

errors over the ground-truth landmarks found within 3 px in both the lossless image and the
encoding (paired), so the columns compare the same corners.

    python benchmarks/photo_jpeg_gap.py --layouts 4 --views 10
    python benchmarks/photo_jpeg_gap.py --data /tmp/val --weights active --encodings q95 q95_422
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from localization.detect.learned import LANDMARK_TYPES, LearnedDetector, match_detections
from uav_struct_env.training.jpeg_augment import encode_jpeg

MATCH_PX = 3.0
#: The chroma layout per suffix (Pillow's default, 4:2:0, has none).
_CHROMA = {"444": "4:4:4", "422": "4:2:2", "420": "4:2:0"}


def encode(rgb: np.ndarray, name: str) -> np.ndarray:
    """The image after the encoding ``name`` (``png``, ``gray``, ``q<quality>[_<chroma>]``)."""
    if name == "png":
        return rgb
    if name == "gray":
        return np.repeat(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[..., None], 3, axis=2)
    quality, _, chroma = name[1:].partition("_")
    return encode_jpeg(rgb, int(quality), _CHROMA[chroma or "420"])


def _errors(uv: np.ndarray, kinds: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """(K,) error of each ground-truth keypoint's matched detection of its type, NaN if none."""
    out = np.full(len(kps), np.nan)
    for t in range(len(LANDMARK_TYPES)):
        rows = np.flatnonzero(kps[:, 2] == t)
        if len(rows):
            m, d = match_detections(uv[kinds == t], kps[rows, :2], MATCH_PX)
            out[rows[m[m >= 0]]] = d[m >= 0]
    return out


def _measure(det: LearnedDetector, raw: np.ndarray, img: np.ndarray, kps: np.ndarray) -> dict:
    """Per-keypoint errors of the four stages (module docstring) on one image pair."""
    cand_raw, _, k_raw = det.candidates(raw)
    cand, _, kinds = det.candidates(img)
    out = {"cand": _errors(cand, kinds, kps)}
    for name, (image, uv, k) in {"final": (img, cand, kinds), "ref@jpg": (img, cand_raw, k_raw),
                                 "cand@jpg": (raw, cand, kinds)}.items():
        refined, _, k2 = det._refine(image, uv.copy(), k)
        out[name] = _errors(refined, k2, kps)
    return out


def _dataset(args: argparse.Namespace, folder: Path) -> Path:
    if args.data:
        return Path(args.data)
    from uav_struct_env.datasets.landmarks import DatasetConfig, generate
    from uav_struct_env.site import paper_site
    from uav_struct_env.site.ifc_export import write_building

    site = paper_site("slab")
    ifc = write_building(site.name, site.storeys, site.elements, folder / "paper.ifc")
    config = DatasetConfig(n_layouts=args.layouts, views_per_layout=args.views, seed=args.seed, scale=1.0,
                           site=str(ifc))
    return generate(config, folder / "data").parent


def main(args: argparse.Namespace) -> dict:
    from uav_struct_env.datasets.landmarks import load_labels

    det = LearnedDetector.for_localizer("all", 1280, "robust", weights=args.weights,
                                        refiner=args.refiner or True)
    stages = ("cand", "final", "ref@jpg", "cand@jpg")
    errs: dict = {(e, s): [] for e in args.encodings for s in (*stages, "png")}
    types: list = []
    with tempfile.TemporaryDirectory() as tmp:
        labels = load_labels(_dataset(args, Path(tmp)))
        root = Path(labels["root"])
        for rec in tqdm(labels["images"], desc="images"):
            raw = cv2.cvtColor(cv2.imread(str(root / rec["file"])), cv2.COLOR_BGR2RGB)
            kps = np.array([k[:3] for k in rec["keypoints"]], np.float64).reshape(-1, 3)
            base = _measure(det, raw, raw, kps)
            types.append(kps[:, 2])
            for e in args.encodings:
                got = _measure(det, raw, encode(raw, e), kps)
                for s in stages:
                    errs[(e, s)].append(got[s])
                errs[(e, "png")].append(base["final"])
    types = np.concatenate(types)
    return _report(args.encodings, stages, {k: np.concatenate(v) for k, v in errs.items()}, types)


def _report(encodings: list[str], stages: tuple, errs: dict, types: np.ndarray) -> dict:
    out = {}
    for t, tname in [*enumerate(LANDMARK_TYPES), (None, "all")]:
        rows = np.ones(len(types), bool) if t is None else types == t
        print(f"\n{tname} ({int(rows.sum())} visible landmarks): recall at 3 px; median / mean px error, "
              "paired with the lossless image's final detections")
        for e in encodings:
            png = errs[(e, "png")][rows]
            line = [f"{e:9s} png    {np.isfinite(png).mean():6.1%}"]
            for s in stages:
                err = errs[(e, s)][rows]
                both = np.isfinite(err) & np.isfinite(png)
                med, mean = (np.median(err[both]), err[both].mean()) if both.any() else (math.nan,) * 2
                out[(tname, e, s)] = (float(np.isfinite(err).mean()), float(med), float(mean))
                line.append(f"{s:8s} {np.isfinite(err).mean():6.1%} {med:.3f}/{mean:.3f}")
            both = np.isfinite(png)
            line.append(f"png final {np.median(png[both]):.3f}/{png[both].mean():.3f}")
            print("  ".join(line))
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--layouts", type=int, default=4, help="rendered layouts (each a stage of the IFC)")
    parser.add_argument("--views", type=int, default=10, help="views per layout")
    parser.add_argument("--seed", type=int, default=0, help="the rendered dataset's seed")
    parser.add_argument("--data", default=None, help="a labelled full-resolution dataset instead")
    parser.add_argument("--weights", default=None, help="the detector's weight set (none: the default)")
    parser.add_argument("--refiner", default=None, help="another refiner ONNX file (none: the set's)")
    parser.add_argument("--encodings", nargs="+",
                        default=["q95", "q95_422", "q95_444", "q100", "q100_444", "gray"],
                        help="png, gray or q<QUALITY>[_<CHROMA>] with CHROMA 444, 422 or 420")
    main(parser.parse_args())
