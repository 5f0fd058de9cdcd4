"""Random localization problems for integrity tests: layouts, cameras, viewpoints, priors, detections.

:func:`draw_case` draws one :class:`FuzzCase` from a ``numpy.random.Generator`` over the axes
the robust localizer is sensitive to:

* layout: a ``regular`` grid (equal spacing along each axis), an ``irregular`` grid (random
  spacings, points jittered and some removed) or ``scattered`` points;
* ``coplanar`` (one level) or 3D (two or three levels, or a random height per point);
* a ``short`` (fx 300-1500 px) or ``long`` (fx 3000-12000 px) focal length, square or
  anisotropic pixels (fy / fx in 0.8-1.25), image 640-4096 px wide;
* a ``centred`` or off-centre principal point (up to 15 % of the image size off);
* a prior whose camera centre is off by up to 3 m per axis and whose roll, pitch and yaw are off
  by up to 2, 2 and 5 degrees (half of the cases exactly at those corners, the paper's protocol);
* correct and sufficient detections: every landmark in the frame (at least ``min_visible``),
  with Gaussian noise of ``pixel_sigma``, in random order, no clutter.

The truth comes with the case (``cam_from_world``, ``true_index``), so a test can judge any
estimate; nothing here is needed to localize.

:func:`corrupt_detections` then adds what a real detector adds to those detections
(:data:`CORRUPTIONS`):

* ``ghost_shift``: a ghost copy of every detection, all shifted by one offset of 5-80 px (a
  detector that fires twice per corner, e.g. on both edges of a slab's thickness);
* ``ghost_each``: a ghost copy of every detection, each shifted by its own 5-80 px;
* ``clutter_500``, ``clutter_2000``: that many uniform points over the image;
* ``detector``: the false detections of the learned detector on real renders, replayed
  (:class:`FalseDetections`): those it made within 80 px of a landmark keep their offset from
  it and are attached to a random detection of the case, the others keep their place in the
  image (as a fraction of its width and height). Recorded on the training buildings, the
  paper site and random sites (:data:`FALSE_DETECTIONS_PATH`);
* ``detector_heldout``: the same, recorded on issue 44's held-out buildings
  (:data:`FALSE_DETECTIONS_HELDOUT_PATH`), once, after the verification was fixed: nothing is
  tuned on them.

Ghosts closer than 5 px lie inside the localizer's inlier gate at 1 px noise and act as noise.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from localization.geometry.transforms import look_at, project
from localization.testing.synthetic import perturb_attitude

__all__ = [
    "CORRUPTIONS",
    "FALSE_DETECTIONS_HELDOUT_PATH",
    "FALSE_DETECTIONS_PATH",
    "FALSE_DETECTION_LIBRARIES",
    "FOCALS",
    "FalseDetections",
    "FuzzCase",
    "LAYOUTS",
    "corrupt_detections",
    "draw_case",
]


LAYOUTS = ("regular", "irregular", "scattered")


FOCALS = ("short", "long")


_FOCAL_RANGE_PX = {"short": (300.0, 1500.0), "long": (3000.0, 12000.0)}


#: The prior's error bounds: camera centre per axis (m); roll, pitch, yaw (deg).
PRIOR_POSITION_M = 3.0


PRIOR_ATTITUDE_DEG = (2.0, 2.0, 5.0)


#: The detector's failure modes :func:`corrupt_detections` adds (module docstring).
CORRUPTIONS = (
    "clean", "ghost_shift", "ghost_each", "clutter_500", "clutter_2000", "detector", "detector_heldout",
)


#: Ghost offsets, px: a ghost is this far from its detection.
GHOST_OFFSET_PX = (5.0, 80.0)


#: The recorded false detections of the learned detector (:class:`FalseDetections`).
FALSE_DETECTIONS_PATH = Path(__file__).with_name("false_detections.json")


#: The learned detector's false detections on the held-out buildings, a library of their own.
FALSE_DETECTIONS_HELDOUT_PATH = Path(__file__).with_name("false_detections_heldout.json")


#: The library each replaying corruption reads (:func:`corrupt_detections`).
FALSE_DETECTION_LIBRARIES = {
    "detector": FALSE_DETECTIONS_PATH,
    "detector_heldout": FALSE_DETECTIONS_HELDOUT_PATH,
}


@dataclass(frozen=True, eq=False)
class FuzzCase:
    """One localization problem with its truth.

    Attributes:
        landmarks_xyz: (M, 3) model landmarks, project frame, metres.
        K: (3, 3) intrinsics.
        image_size: (W, H) px.
        cam_from_world: (4, 4) the true pose.
        prior_cam_from_world: (4, 4) the rough pose given to the localizer.
        detections_uv: (N, 2) the in-frame landmarks' projections plus noise, shuffled.
        true_index: (N,) the model landmark of each detection.
        pixel_sigma: the detections' noise, px.
        labels: what was drawn: layout, coplanar, focal, centred, prior ("box" or "corner").
    """

    landmarks_xyz: NDArray[np.float64]
    K: NDArray[np.float64]
    image_size: tuple[int, int]
    cam_from_world: NDArray[np.float64]
    prior_cam_from_world: NDArray[np.float64]
    detections_uv: NDArray[np.float64]
    true_index: NDArray[np.int64]
    pixel_sigma: float
    labels: dict


def _grid_lines(rng: np.random.Generator, regular: bool) -> NDArray[np.float64]:
    n = int(rng.integers(2, 7))
    steps = np.full(n - 1, rng.uniform(3.0, 9.0)) if regular else rng.uniform(2.0, 10.0, n - 1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _layout(rng: np.random.Generator, layout: str, coplanar: bool) -> NDArray[np.float64]:
    if layout == "scattered":
        m = int(rng.integers(4, 25))
        xy = rng.uniform(0.0, rng.uniform(6.0, 40.0, 2), (m, 2))
    else:
        xs, ys = _grid_lines(rng, layout == "regular"), _grid_lines(rng, layout == "regular")
        xy = np.array([(x, y) for y in ys for x in xs])
        if layout == "irregular":
            xy += rng.normal(0.0, 0.3, xy.shape)
            keep = rng.random(len(xy)) >= 0.15
            xy = xy[keep] if keep.sum() >= 4 else xy
    base = rng.uniform(0.0, 30.0)
    if coplanar:
        z = np.full((len(xy), 1), base)
        X = np.hstack([xy, z])
    elif layout == "scattered" or rng.random() < 0.3:
        X = np.hstack([xy, base + rng.uniform(0.0, 8.0, (len(xy), 1))])
    else:  # a grid repeated on two or three levels, as slab corners below column tops
        levels = base + np.cumsum(np.concatenate([[0.0], rng.uniform(2.5, 5.0, int(rng.integers(1, 3)))]))
        X = np.vstack([np.hstack([xy, np.full((len(xy), 1), z)]) for z in levels])
    return X + np.array([*rng.uniform(-50.0, 50.0, 2), 0.0]) - np.array([*xy.mean(axis=0), 0.0])


def _camera(rng: np.random.Generator, focal: str, centred: bool) -> tuple[NDArray, tuple[int, int]]:
    w = int(rng.integers(640, 4097))
    h = int(round(w * rng.uniform(0.5, 0.8)))
    fx = rng.uniform(*_FOCAL_RANGE_PX[focal])
    fy = fx * (1.0 if rng.random() < 0.5 else rng.uniform(0.8, 1.25))
    if centred:
        cx, cy = w / 2.0, h / 2.0
    else:
        cx, cy = w / 2.0 + rng.uniform(-0.15, 0.15) * w, h / 2.0 + rng.uniform(-0.15, 0.15) * h
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), (w, h)


def _in_frame(uv: NDArray, depth: NDArray, size: tuple[int, int]) -> NDArray[np.bool_]:
    w, h = size
    return (
        (depth > 0)
        & (uv[:, 0] >= -0.5)
        & (uv[:, 0] <= w - 0.5)
        & (uv[:, 1] >= -0.5)
        & (uv[:, 1] <= h - 0.5)
    )


def _prior(rng: np.random.Generator, cam_from_world: NDArray) -> tuple[NDArray, str]:
    att = np.asarray(PRIOR_ATTITUDE_DEG)
    if rng.random() < 0.5:
        kind = "corner"
        dpos = PRIOR_POSITION_M * rng.choice([-1.0, 1.0], 3)
        datt = att * rng.choice([-1.0, 1.0], 3)
    else:
        kind = "box"
        dpos = rng.uniform(-PRIOR_POSITION_M, PRIOR_POSITION_M, 3)
        datt = rng.uniform(-att, att)
    return perturb_attitude(cam_from_world, dpos, np.radians(datt)), kind


def draw_case(
    rng: np.random.Generator,
    *,
    layout: str | None = None,
    coplanar: bool | None = None,
    focal: str | None = None,
    centred: bool | None = None,
    pixel_sigma: float = 1.0,
    min_visible: int = 4,
    max_tries: int = 200,
) -> FuzzCase:
    """One random problem (module docstring); an axis given as an argument is fixed, not drawn.

    The viewpoint is drawn 10-80 m from a point of the layout (horizontally), 5-40 m above it,
    aimed at a point near the layout, until at least ``min_visible`` landmarks are in the frame;
    after ``max_tries`` viewpoints the layout and camera are drawn again.

    Raises:
        ValueError: on an unknown ``layout`` or ``focal``.
    """
    if layout is not None and layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if focal is not None and focal not in FOCALS:
        raise ValueError(f"focal must be one of {FOCALS}, got {focal!r}")
    while True:
        lay = layout or str(rng.choice(LAYOUTS))
        cop = bool(rng.random() < 0.5) if coplanar is None else coplanar
        foc = focal or str(rng.choice(FOCALS))
        cen = bool(rng.random() < 0.5) if centred is None else centred
        X = _layout(rng, lay, cop)
        K, size = _camera(rng, foc, cen)
        for _ in range(max_tries):
            target = X[rng.integers(len(X))] + rng.normal(0.0, 2.0, 3)
            az = rng.uniform(0.0, 2.0 * np.pi)
            d, up = rng.uniform(10.0, 80.0), rng.uniform(5.0, 40.0)
            eye = target + np.array([d * np.cos(az), d * np.sin(az), up])
            T = look_at(eye, target)
            uv, depth = project(K, T, X)
            vis = _in_frame(uv, depth, size)
            if vis.sum() >= min_visible:
                break
        else:
            continue
        idx = rng.permutation(np.flatnonzero(vis))
        det = uv[idx] + rng.normal(0.0, pixel_sigma, (len(idx), 2))
        prior, kind = _prior(rng, T)
        labels = {"layout": lay, "coplanar": cop, "focal": foc, "centred": cen, "prior": kind}
        return FuzzCase(X, K, size, T, prior, det, idx.astype(np.int64), pixel_sigma, labels)


@dataclass(frozen=True, eq=False)
class FalseDetections:
    """False detections of a real detector, per view, as :func:`corrupt_detections` replays them.

    Attributes:
        views: one dict per recorded view: ``near`` (K, 2) offsets, px, of the false detections
            within 80 px of a landmark from that landmark's projection (``[r, NaN]`` when only
            the distance ``r`` is known: the replay draws the direction), ``far`` (F, 2) the
            others' places as fractions of the image width and height, ``source`` where they
            were recorded.
        sources: the studies they were recorded from (site, conditions, detector).
    """

    views: tuple[dict, ...]
    sources: tuple[str, ...]

    @classmethod
    def load(cls, path: str | Path = FALSE_DETECTIONS_PATH) -> FalseDetections:
        """The library written by ``benchmarks/integrity_fuzz.py record``.

        Raises:
            ValueError: if the file holds no view.
        """
        data = json.loads(Path(path).read_text())
        views = tuple(
            {
                "near": np.asarray(v["near"], dtype=float).reshape(-1, 2),
                "far": np.asarray(v["far"], dtype=float).reshape(-1, 2),
                "source": v["source"],
            }
            for v in data["views"]
        )
        if not views:
            raise ValueError(f"{path} holds no recorded view, expected at least one")
        return cls(views, tuple(data["sources"]))


def _ghost_offsets(rng: np.random.Generator, n: int) -> NDArray[np.float64]:
    r = rng.uniform(*GHOST_OFFSET_PX, n)
    a = rng.uniform(0.0, 2.0 * np.pi, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def _replayed(
    case: FuzzCase, view: dict, rng: np.random.Generator
) -> NDArray[np.float64]:
    """One recorded view's false detections placed in ``case``'s image (module docstring)."""
    det = case.detections_uv
    near = view["near"].copy()
    unknown = np.isnan(near[:, 1])
    a = rng.uniform(0.0, 2.0 * np.pi, int(unknown.sum()))
    r = near[unknown, 0]
    near[unknown] = np.column_stack([r * np.cos(a), r * np.sin(a)])
    near = det[rng.integers(len(det), size=len(near))] + near
    far = view["far"] * np.asarray(case.image_size, dtype=float) - 0.5
    return np.vstack([near, far])


def corrupt_detections(
    case: FuzzCase,
    mode: str,
    rng: np.random.Generator,
    false_detections: FalseDetections | None = None,
) -> NDArray[np.float64]:
    """The case's detections with ``mode``'s corruption added (module docstring), in random order.

    Args:
        case: the problem.
        mode: one of :data:`CORRUPTIONS`.
        rng: the corruption's randomness.
        false_detections: the ``detector`` or ``detector_heldout`` mode's library; default the
            mode's file (:data:`FALSE_DETECTION_LIBRARIES`).

    Raises:
        ValueError: on an unknown ``mode``.
    """
    if mode not in CORRUPTIONS:
        raise ValueError(f"mode must be one of {CORRUPTIONS}, got {mode!r}")
    det = case.detections_uv
    w, h = case.image_size
    if mode == "ghost_shift":
        det = np.vstack([det, det + _ghost_offsets(rng, 1)])
    elif mode == "ghost_each":
        det = np.vstack([det, det + _ghost_offsets(rng, len(det))])
    elif mode.startswith("clutter_"):
        n = int(mode.split("_")[1])
        det = np.vstack([det, rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], (n, 2))])
    elif mode in FALSE_DETECTION_LIBRARIES:
        library = false_detections or FalseDetections.load(FALSE_DETECTION_LIBRARIES[mode])
        det = np.vstack([det, _replayed(case, library.views[rng.integers(len(library.views))], rng)])
    return det[rng.permutation(len(det))]
