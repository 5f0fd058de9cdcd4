"""Stage 1, detection with a learned network: the real-time structural-landmark detector.

:class:`LearnedDetector` runs a small fully-convolutional keypoint network (trained on simulator
renders by :mod:`uav_struct_env.training.train_detector`; named weight sets in
:mod:`localization.detect.weights`, their figures in ``localization/detect/models/MODEL_CARD.md``)
with ONNX Runtime (:mod:`localization.detect.onnx_net`) -- no PyTorch at
inference -- and decodes its output into anonymous sub-pixel detections with scores, following
the :class:`Detector` protocol of :mod:`localization.detect`, so the localizer takes it in place
of the projection detector.

Pipeline for an ``(H, W, 3)`` uint8 RGB image:

1. downscale by ``scale`` (default 0.5: 1280 x 720 -> 640 x 360) with ``cv2.INTER_AREA`` and pad
   (edge-replicate, bottom/right) to multiples of 16;
2. the network returns, at stride 4, one heatmap per landmark type (:data:`LANDMARK_TYPES`,
   sigmoid scores) and two sub-cell offset channels;
3. :func:`decode`: local maxima of each requested heatmap (3 x 3 max filter) above
   ``score_threshold``, refined to sub-pixel with the regressed offsets (or, for a heatmap-only
   output, a per-axis parabola through the log-scores); with ``votes`` (the default) also every
   other cell scoring at least ``vote_threshold``, placed where its offsets point -- two corners
   of a thin opening one cell apart merge into one peak, but the cells nearer the weaker corner
   still point at it; then non-maximum suppression by distance (``nms_px``) per type, peaks
   first;
4. pixel coordinates mapped back to the full image (``u + 0.5 = (u' + 0.5) / scale``);
5. by default every candidate is refined at full resolution by the patch refiner
   (:class:`localization.detect.refiner.PatchRefiner`: a second small network on a 33 x 33 patch around
   it, iterated), which also re-scores it: candidates scoring below ``refine_threshold`` are
   dropped and the rest suppressed again by distance per type. Without the refiner
   (``refiner=False``), slab and opening corners can instead be refined on the grey image with
   ``cv2.cornerSubPix`` (``corner_window``; a shift above ``corner_max_shift`` px is discarded).

**Ground truth is used for scoring only.** When the context carries the ground truth of the
requested landmark set (as the environment and the study provide), :meth:`LearnedDetector.detect`
fills ``Detections.true_ids`` by matching detections one-to-one to the *visible* ground-truth
projections within ``match_px`` (3 px) -- a detection farther than that from every visible
landmark is a false positive (-1). This is bookkeeping for detection rate / association scores;
``uv`` and ``scores`` never depend on the context, and the localizer never reads ``true_ids``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from localization.checks import check_number
from localization.detect.interface import Detections, check_rgb_image
from localization.detect.onnx_net import OnnxNet
from localization.detect.refiner import PatchRefiner
from localization.detect.weights import WEIGHT_SETS, weight_set
from localization.geometry.transforms import as_points

__all__ = [
    "DEFAULT_MODEL",
    "FIT_PIXEL_SIGMAS_PX",
    "FIT_PIXEL_SIGMA_PX",
    "LANDMARK_TYPES",
    "LearnedDetector",
    "OPERATING_POINTS",
    "TRAINED_WIDTH",
    "decode",
    "fit_pixel_sigma",
    "match_detections",
    "nms",
    "operating_point_for",
    "subpixel_parabola",
    "truth_ids",
]


#: Heatmap channel order of the network.
LANDMARK_TYPES = ("column_tops", "slab_corners", "opening_corners")


#: The default weights' keypoint network (:data:`localization.detect.weights.DEFAULT_WEIGHTS`).
DEFAULT_MODEL = weight_set().model


STRIDE = 4


_PAD = 16


#: Width (px) of the images the keypoint network was trained on: the paper's camera at half size.
TRAINED_WIDTH = 640


#: The detector's pixel noise (per axis) at 1280 px wide images, as the localizer's fit tests
#: should assume it (:class:`localization.Localizer`'s ``fit_sigma_px``), for weights and imaging
#: :data:`FIT_PIXEL_SIGMAS_PX` does not list (custom or adapted weights). Calibrated on train data
#: only (issue 44's held-out buildings never): the sigma at which 95 % of the successful poses
#: whose pairs are all right pass the chi-square 95 % fit test, over the default weights' studies
#: of the train buildings (revit_large_building, archicad11_institute, archicad20_fzk_haus) and
#: the paper site busy through the Mavic 2 Pro camera: 0.72 px (119 poses); the ideal-imaging
#: paper and random sites alone give 0.42-0.49 px, all of them 0.63 px (380 poses). The true
#: detections' RMS error (those within 3 px) is 0.56 px pooled over the same studies.
FIT_PIXEL_SIGMA_PX = 0.7


#: :data:`FIT_PIXEL_SIGMA_PX` per weight set and imaging (the study's ``ideal`` render or
#: ``camera``: sensor noise, blur and JPEG), each the same statistic over that pair's train
#: studies (issue 44, 2026-11-27; never a held-out building): ``landmarks_v1`` ideal over the
#: paper site, random sites 0-2 and the train buildings revit_large_building,
#: archicad11_institute, archicad20_fzk_haus, jesse_house and revit_samplehouse4 (464 poses);
#: ``landmarks_v1`` camera over the paper site busy through the Mavic 2 Pro (32);
#: ``landmarks_active_v4`` over the site-conditions table's six ideal (457) and three camera
#: (206) rows (``benchmarks/site_conditions_study.py --detector learned:active``).
FIT_PIXEL_SIGMAS_PX = {
    ("landmarks_v1", "ideal"): 0.54,
    ("landmarks_v1", "camera"): 0.84,
    ("landmarks_active_v4", "ideal"): 0.57,
    ("landmarks_active_v4", "camera"): 0.62,
}


def fit_pixel_sigma(
    image_width: int,
    imaging: str = "ideal",
    model: str | Path | None = None,
    refiner: str | Path | None = None,
) -> float:
    """The fit sigma of the weights ``model`` + ``refiner`` (None: the default set's) under ``imaging``.

    :data:`FIT_PIXEL_SIGMAS_PX` for a shipped weight set's two files, else
    :data:`FIT_PIXEL_SIGMA_PX`; scaled with the image width from 1280 px.
    """
    width = check_number("image_width", image_width, 0, lo_open=True)
    default = weight_set()
    files = (Path(model or default.model).resolve(), Path(refiner or default.refiner).resolve())
    names = [n for n, s in WEIGHT_SETS.items() if (s.model.resolve(), s.refiner.resolve()) == files]
    sigma = FIT_PIXEL_SIGMAS_PX.get((names[0], imaging), FIT_PIXEL_SIGMA_PX) if names else FIT_PIXEL_SIGMA_PX
    return sigma * width / 1280.0


#: Operating points ``(keypoint-network score threshold, refiner score threshold)``, chosen on
#: validation data never used for the reported figures (the model card says which).
#: ``"balanced"`` maximizes the detector's own F1 at 3 px. ``"recall"`` keeps weaker candidates
#: for a localizer that rejects false positives itself (``robust`` association): it maximized the
#: association F1 and the successful poses of validation studies. For the ``paper`` association,
#: which assigns every detection, use ``"balanced"``. Votes use the keypoint threshold, which
#: did better than higher vote thresholds.
OPERATING_POINTS = {"balanced": (0.3, 0.5), "recall": (0.15, 0.05)}


def operating_point_for(association: str) -> str:
    """The :data:`OPERATING_POINTS` key to detect for a localizer with this association mode.

    ``"robust"`` (rejects false positives itself) -> ``"recall"``; ``"paper"`` (assigns every
    detection) -> ``"balanced"``.
    """
    points = {"robust": "recall", "paper": "balanced"}
    if association not in points:
        raise ValueError(f"association must be one of {sorted(points)}, got {association!r}")
    return points[association]


def subpixel_parabola(heat: NDArray, rows: NDArray, cols: NDArray) -> NDArray[np.float64]:
    """Sub-cell offsets ``(N, 2)`` (du, dv in cells, within +-0.5) of peaks of ``heat``.

    Fits a parabola through the log-scores of each peak and its two neighbours per axis (exact
    for a sampled Gaussian); peaks on the border get 0 along that axis.
    """
    h, w = heat.shape
    logh = np.log(np.maximum(heat.astype(np.float64), 1e-12))
    out = np.zeros((len(rows), 2))
    for k, (r, c) in enumerate(zip(rows, cols, strict=True)):
        for axis in (0, 1):  # axis 0 varies the column (u), axis 1 the row (v)
            if axis == 0:
                if not 0 < c < w - 1:
                    continue
                left, mid, right = logh[r, c - 1], logh[r, c], logh[r, c + 1]
            else:
                if not 0 < r < h - 1:
                    continue
                left, mid, right = logh[r - 1, c], logh[r, c], logh[r + 1, c]
            den = left - 2 * mid + right
            if den < -1e-12:
                out[k, axis] = np.clip(0.5 * (left - right) / den, -0.5, 0.5)
    return out


def decode(
    output: ArrayLike,
    types: Sequence[int] = (0, 1, 2),
    image_size: tuple[int, int] | None = None,
    score_threshold: float = 0.3,
    nms_px: float = 4.0,
    max_per_type: int = 64,
    use_offsets: bool = True,
    vote_threshold: float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """Detections from one network output.

    Args:
        output: ``(C, h, w)`` array: ``C - 2`` sigmoid heatmaps then 2 offset channels (du, dv,
            in cells), or ``C`` heatmaps only with ``use_offsets=False``.
        types: heatmap channels to decode.
        image_size: ``(W, H)`` of the network input before padding; detections outside it are
            dropped (None: keep all).
        score_threshold: minimum heatmap score of a peak.
        nms_px: detections of one type closer than this (input pixels) keep only the best.
        max_per_type: at most this many detections per type, best first.
        use_offsets: refine with the offset channels; False uses :func:`subpixel_parabola`.
        vote_threshold: also propose, from every cell scoring at least this much that is not a
            3 x 3 peak, the position its offsets point at (offsets are trained on the 3 x 3 cells
            around each keypoint). Two landmarks of a type one cell apart (a thin stair opening
            seen at a grazing angle) give one merged peak; the cells nearer the weaker one still
            point at it. None: peaks only. Needs the offset channels.

    Returns:
        ``uv (N, 2)`` in network-input pixels, ``scores (N,)``, ``types (N,)``; sorted by score.
    """
    out = np.asarray(output, dtype=np.float32)
    if out.ndim == 4 and out.shape[0] == 1:
        out = out[0]
    if out.ndim != 3:
        raise ValueError(f"output must have shape (C, h, w), got {out.shape}")
    n_heat = out.shape[0] - 2 if use_offsets else out.shape[0]
    if vote_threshold is not None and not use_offsets:
        raise ValueError("vote_threshold needs the offset channels (use_offsets=True)")
    kernel = np.ones((3, 3), np.uint8)
    all_uv, all_s, all_t = [], [], []
    for t in types:
        if not 0 <= int(t) < n_heat:
            raise ValueError(f"type channel {t} out of range [0, {n_heat})")
        heat = out[int(t)]
        peaks = (heat >= cv2.dilate(heat, kernel)) & (heat >= score_threshold)
        groups = [peaks]
        if vote_threshold is not None:
            groups.append((heat >= vote_threshold) & ~peaks)
        # Peaks first, each group best first, into the suppression: votes only add candidates,
        # never displace a peak.
        rows_list, cols_list = [], []
        for mask in groups:
            r, c = np.nonzero(mask)
            best = np.argsort(-heat[r, c], kind="stable")[: 4 * max_per_type]
            rows_list.append(r[best])
            cols_list.append(c[best])
        rows, cols = np.concatenate(rows_list), np.concatenate(cols_list)
        scores = heat[rows, cols].astype(np.float64)
        if use_offsets:
            off = np.stack([out[n_heat, rows, cols], out[n_heat + 1, rows, cols]], axis=1)
        else:
            off = subpixel_parabola(heat, rows, cols)
        cells = np.stack([cols, rows], axis=1) + off.astype(np.float64)
        uv = (cells + 0.5) * STRIDE - 0.5
        if image_size is not None:
            w, h = image_size
            inside = ((uv[:, 0] >= -0.5) & (uv[:, 0] < w - 0.5)
                      & (uv[:, 1] >= -0.5) & (uv[:, 1] < h - 0.5))
            uv, scores = uv[inside], scores[inside]
        keep = nms(uv, nms_px, max_per_type)
        all_uv.append(uv[keep])
        all_s.append(scores[keep])
        all_t.append(np.full(len(keep), int(t), dtype=np.int64))
    uv = np.concatenate(all_uv).reshape(-1, 2) if all_uv else np.zeros((0, 2))
    scores = np.concatenate(all_s) if all_s else np.zeros(0)
    kinds = np.concatenate(all_t) if all_t else np.zeros(0, np.int64)
    order = np.argsort(-scores, kind="stable")
    return uv[order], scores[order], kinds[order]


def nms(uv: NDArray[np.float64], radius: float, max_keep: int | None = None) -> list[int]:
    """Greedy non-maximum suppression of points ``uv (N, 2)`` sorted best first.

    Returns the indices kept: a point closer than ``radius`` to a kept one is dropped; at most
    ``max_keep`` are kept.
    """
    keep: list[int] = []
    for i in range(len(uv)):
        if max_keep is not None and len(keep) >= max_keep:
            break
        if keep and np.min(np.hypot(*(uv[keep] - uv[i]).T)) < radius:
            continue
        keep.append(i)
    return keep


def match_detections(
    uv: ArrayLike, truth_uv: ArrayLike, max_px: float = 3.0
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """One-to-one matching of detections to ground-truth points within ``max_px``.

    Returns:
        ``match (N,)``: index into ``truth_uv`` or -1, and ``dist (N,)``: the pixel distance to
        the matched point (NaN when unmatched). Minimizes the total distance (Hungarian).
    """
    uv = as_points("uv", uv, 2)
    gt = as_points("truth_uv", truth_uv, 2)
    match = np.full(len(uv), -1, dtype=np.int64)
    dist = np.full(len(uv), np.nan)
    if len(uv) == 0 or len(gt) == 0:
        return match, dist
    d = np.hypot(uv[:, None, 0] - gt[None, :, 0], uv[:, None, 1] - gt[None, :, 1])
    cost = np.where(d <= max_px, d, 1e6)
    rows, cols = linear_sum_assignment(cost)
    ok = d[rows, cols] <= max_px
    match[rows[ok]] = cols[ok]
    dist[rows[ok]] = d[rows[ok], cols[ok]]
    return match, dist


def truth_ids(uv: NDArray[np.float64], truth: Mapping[str, Any] | None,
              match_px: float) -> NDArray[np.int64] | None:
    """The visible true landmark within ``match_px`` of each detection (one-to-one), else -1.

    None without truth. ``truth``: one landmark set's truth (``ids``, ``uv``, ``visible``), as the
    env delivers it. Scoring bookkeeping only (:class:`~localization.detect.Detections`'
    ``true_ids``): the detectors never read it.
    """
    if truth is None:
        return None
    visible = np.asarray(truth["visible"], dtype=bool).reshape(-1)
    ids = np.asarray(truth["ids"]).astype(np.int64).reshape(-1)
    gt_uv = np.asarray(truth["uv"], dtype=np.float64).reshape(-1, 2)
    match, _ = match_detections(uv, gt_uv[visible], match_px)
    out = np.full(len(match), -1, dtype=np.int64)  # also when nothing is visible
    out[match >= 0] = ids[visible][match[match >= 0]]
    return out


class LearnedDetector:
    """The learned structural-landmark detector (see the module docstring).

    Args:
        landmarks: which types to return: a name of :data:`LANDMARK_TYPES`, ``"all"`` (the three
            together), or a sequence of names. It is also the set looked up in
            ``context["landmarks"]`` for the ground-truth bookkeeping (``true_ids``).
        model: path of the keypoint network's ONNX model (default: that of ``weights``).
        score_threshold: minimum heatmap score of a candidate (None: from ``operating_point``).
        nms_px: detections of one type closer than this (full-resolution px) keep only the best.
        scale: downscale factor applied before the network (the model is trained at 0.5).
        match_px: radius of the ground-truth matching used only to fill ``true_ids``.
        max_per_type: cap on the detections per type.
        corner_window: half-size (px) of the ``cv2.cornerSubPix`` window for slab and opening
            corners at full resolution; 0 disables the refinement.
        corner_max_shift: largest accepted refinement shift, px.
        refiner: full-resolution patch refinement of every candidate
            (:class:`localization.detect.refiner.PatchRefiner`): True for the refiner of ``weights``,
            a path for another ONNX refiner, False for none (then ``corner_window`` applies).
        refine_iterations: refinement passes.
        refine_threshold: candidates whose refiner score is below this are dropped (None: from
            ``operating_point``).
        operating_point: a key of :data:`OPERATING_POINTS`: the default thresholds.
        votes: also take candidates from the heatmap cells that are not peaks (see
            :func:`decode`); False: peaks only.
        vote_threshold: minimum heatmap score of such a cell (None: ``score_threshold``).
        threads: ONNX Runtime threads of each network (:class:`localization.detect.onnx_net.OnnxNet`;
            1: the latency figures are per core).
        weights: the named weight set whose files ``model=None`` and ``refiner=True`` take
            (:mod:`localization.detect.weights`): ``"landmarks_v1"`` (None: this default, trained
            on bare sites), ``"landmarks_active_v4"`` or its alias ``"active"`` (active sites
            through a real camera). The operating points suit both.

    Raises:
        ValueError: for an unknown landmark type or weight-set name, or bad numbers;
            FileNotFoundError for a missing model file.
    """

    def __init__(
        self,
        landmarks: str | Sequence[str] = "column_tops",
        model: str | Path | None = None,
        score_threshold: float | None = None,
        nms_px: float = 8.0,
        scale: float = 0.5,
        match_px: float = 3.0,
        max_per_type: int = 64,
        corner_window: int = 3,
        corner_max_shift: float = 3.0,
        refiner: bool | str | Path = True,
        refine_iterations: int = 2,
        refine_threshold: float | None = None,
        operating_point: str = "balanced",
        votes: bool = True,
        vote_threshold: float | None = None,
        threads: int = 1,
        weights: str | None = None,
    ) -> None:
        named = weight_set(weights)
        if operating_point not in OPERATING_POINTS:
            raise ValueError(
                f"operating_point must be one of {sorted(OPERATING_POINTS)}, got {operating_point!r}"
            )
        point = OPERATING_POINTS[operating_point]
        score_threshold = point[0] if score_threshold is None else score_threshold
        refine_threshold = point[1] if refine_threshold is None else refine_threshold
        if isinstance(landmarks, str):
            names = LANDMARK_TYPES if landmarks == "all" else (landmarks,)
        else:
            names = tuple(landmarks)
        unknown = [n for n in names if n not in LANDMARK_TYPES]
        if unknown or not names:
            raise ValueError(
                f"landmarks must be one of {LANDMARK_TYPES}, 'all' or a sequence of them, "
                f"got {landmarks!r}"
            )
        for name, value, lo, hi in (("score_threshold", score_threshold, 0.0, 1.0),
                                    ("scale", scale, 1e-3, 1.0)):
            check_number(name, value, lo, hi, lo_open=True, type_error=ValueError)
        for name, value in (("nms_px", nms_px), ("match_px", match_px)):
            check_number(name, value, 0.0, lo_open=True, type_error=ValueError)
        path = Path(named.model if model is None else model)
        if not path.is_file():
            raise FileNotFoundError(f"learned detector model not found: {path}")
        self.landmarks = landmarks if isinstance(landmarks, str) else tuple(landmarks)
        self.types = tuple(LANDMARK_TYPES.index(n) for n in names)
        self.model_path = path
        self.score_threshold = float(score_threshold)
        self.nms_px = float(nms_px)
        self.scale = float(scale)
        self.match_px = float(match_px)
        self.max_per_type = int(max_per_type)
        self.corner_window = check_number(
            "corner_window", corner_window, 0, integer=True, type_error=ValueError
        )
        self.corner_max_shift = float(corner_max_shift)
        check_number("refine_threshold", refine_threshold, 0.0, 1.0, hi_open=True, type_error=ValueError)
        if not isinstance(votes, bool):
            raise ValueError(f"votes must be True or False, got {votes!r}")
        if vote_threshold is None:
            vote_threshold = score_threshold
        check_number("vote_threshold", vote_threshold, 0.0, 1.0, lo_open=True, type_error=ValueError)
        self.refine_threshold = float(refine_threshold)
        self.votes = votes
        self.vote_threshold = float(vote_threshold)
        self._net = OnnxNet(path, threads)
        if refiner is False:
            self.refiner = None
        else:
            self.refiner = PatchRefiner(named.refiner if refiner is True else refiner, refine_iterations,
                                        threads=threads)

    @classmethod
    def for_localizer(cls, landmarks: str | Sequence[str], image_width: int, association: str,
                      model: str | Path | None = None,
                      refiner: bool | str | Path = True,
                      weights: str | None = None) -> LearnedDetector:
        """The detector for images ``image_width`` px wide and a localizer of ``association``.

        Downscales to the training width (:data:`TRAINED_WIDTH`, never up) and takes the
        operating point of :func:`operating_point_for`; the study and the LocalizationWrapper
        build theirs this way. ``weights`` names a committed set, ``model`` and ``refiner`` select
        other files (for example networks retrained with
        :mod:`uav_struct_env.training.train_detector` and
        :mod:`uav_struct_env.training.train_refiner`), as in the constructor; the operating point's
        thresholds were chosen for the committed weights.
        """
        return cls(landmarks, model=model, refiner=refiner, weights=weights,
                   scale=min(1.0, TRAINED_WIDTH / image_width),
                   operating_point=operating_point_for(association))

    # --------------------------------------------------------------------------------- core
    def infer(self, image: ArrayLike) -> tuple[NDArray[np.float32], tuple[float, float]]:
        """Network output ``(C, h, w)`` for an RGB image, and the (sx, sy) it was scaled by."""
        img = check_rgb_image(image)
        h, w = img.shape[:2]
        sw, sh = max(1, round(w * self.scale)), max(1, round(h * self.scale))
        small = (img if (sw, sh) == (w, h)
                 else cv2.resize(img, (sw, sh), interpolation=cv2.INTER_AREA))
        ph, pw = -(-sh // _PAD) * _PAD, -(-sw // _PAD) * _PAD
        if (ph, pw) != (sh, sw):
            small = cv2.copyMakeBorder(small, 0, ph - sh, 0, pw - sw, cv2.BORDER_REPLICATE)
        out = self._net(small.transpose(2, 0, 1)[None])[0]
        return out, (sw / w, sh / h)

    def detect_all(
        self, image: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """All detections of this detector's landmark types, best first.

        Returns:
            ``uv (N, 2)`` full-resolution pixels, ``scores (N,)``, ``types (N,)`` (indices of
            :data:`LANDMARK_TYPES`).
        """
        full, scores, kinds = self.candidates(image)
        if self.refiner is not None:
            return self._refine(np.asarray(image), full, kinds)
        corners = kinds != LANDMARK_TYPES.index("column_tops")
        if self.corner_window and np.any(corners):
            full[corners] = self._refine_corners(np.asarray(image), full[corners])
        return full, scores, kinds

    def candidates(
        self, image: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
        """The keypoint network's candidates before any refinement, as :meth:`detect_all` returns.

        Full-resolution ``uv (N, 2)``, heatmap ``scores (N,)`` and ``types (N,)``; what the
        refiner (or ``cv2.cornerSubPix``) then places and re-scores.
        """
        out, (sx, sy) = self.infer(image)
        h, w = np.asarray(image).shape[:2]
        size = (max(1, round(w * self.scale)), max(1, round(h * self.scale)))
        uv, scores, kinds = decode(
            out, self.types, size, self.score_threshold, self.nms_px * min(sx, sy),
            self.max_per_type, vote_threshold=self.vote_threshold if self.votes else None,
        )
        full = np.empty_like(uv)
        full[:, 0] = (uv[:, 0] + 0.5) / sx - 0.5
        full[:, 1] = (uv[:, 1] + 0.5) / sy - 0.5
        return full, scores, kinds

    def _refine(self, image: NDArray[np.uint8], uv: NDArray, kinds: NDArray) -> tuple:
        """Patch refinement: refined positions, the refiner's scores, a second NMS per type."""
        uv, scores = self.refiner.refine(image, uv, kinds)
        ok = scores >= self.refine_threshold
        uv, scores, kinds = uv[ok], scores[ok], kinds[ok]
        order = np.argsort(-scores, kind="stable")
        uv, scores, kinds = uv[order], scores[order], kinds[order]
        keep = np.zeros(len(uv), bool)
        for t in np.unique(kinds):
            idx = np.flatnonzero(kinds == t)
            keep[idx[nms(uv[idx], self.nms_px, self.max_per_type)]] = True
        return uv[keep], scores[keep], kinds[keep]

    def _refine_corners(self, image: NDArray[np.uint8], uv: NDArray[np.float64]) -> NDArray:
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        h, w = gray.shape
        win = self.corner_window
        inside = ((uv[:, 0] >= win + 1) & (uv[:, 0] < w - win - 2)
                  & (uv[:, 1] >= win + 1) & (uv[:, 1] < h - win - 2))
        out = uv.copy()
        if not np.any(inside):
            return out
        pts = uv[inside].astype(np.float32).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)
        ref = cv2.cornerSubPix(gray, pts, (win, win), (-1, -1), crit).reshape(-1, 2)
        ok = np.hypot(*(ref - uv[inside]).T) <= self.corner_max_shift
        sel = np.flatnonzero(inside)[ok]
        out[sel] = ref[ok]
        return out

    def detect(self, image: Any, context: Mapping[str, Any] | None = None) -> Detections:
        """Detections of this detector's landmark types in ``image`` ((H, W, 3) uint8 RGB).

        ``true_ids`` is filled only when ``context["landmarks"][self.landmarks]`` holds ground
        truth (``ids``, ``uv``, ``visible``): scoring bookkeeping, see the module docstring.
        """
        uv, scores, _ = self.detect_all(image)
        truth = None
        if isinstance(context, Mapping) and isinstance(self.landmarks, str):
            truth = context.get("landmarks", {}).get(self.landmarks)
        return Detections(uv=uv, scores=scores, true_ids=truth_ids(uv, truth, self.match_px))

    def __repr__(self) -> str:
        return (f"LearnedDetector(landmarks={self.landmarks!r}, model={self.model_path.name!r}, "
                f"score_threshold={self.score_threshold}, refiner={self.refiner!r}, "
                f"refine_threshold={self.refine_threshold}, "
                f"vote_threshold={self.vote_threshold if self.votes else None})")
