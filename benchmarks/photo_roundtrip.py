r"""A rendered flight through two doors: the env's LocalizationWrapper and DJI-style JPEGs + localize.

The paper site is written as a georeferenced IFC (IfcMapConversion at UTM zone 32N, the x axis
17.19 deg from east); the env renders it from that IFC (stage ``Level 1/slab``, ``gnss_ins``
prior, robust association, landmarks ``all``). Each agent's frame is localized by the wrapper
(the env path) and also written as a JPEG with EXIF GPS and DJI XMP built from the env's prior
(:mod:`uav_struct_env.photos.dji_jpeg`) at each ``--encodings`` entry (``QUALITY`` or
``QUALITY:CHROMA``, chroma ``420`` -- libjpeg's default -- ``422`` as DJI's Phantom 4 writes, or
``444``), then localized by :func:`uav_struct_env.photos.localize_photos` with the same prior
sigmas (the photo path). Both paths run each ``--detectors`` entry (``guided``, the BIM-guided
detector of :mod:`uav_struct_env.stack.guided`; ``learned`` or ``learned:NAME``,
:mod:`localization.detect.weights`); the frames and priors are the same for every detector (the
same seeds). Prints each path's success count and median / P90 translation and rotation errors,
the photo / env ratio per detector (and, for every detector after the first, against the first
one's env path: ``--detectors learned learned:NAME`` compares weights NAME on JPEGs with the
env's default weights on rendered pixels, as the photo refiners of
localization/detect/models/MODEL_CARD.md were judged), the photo path's latency per photo
(``--latency``: JPEG decode + detection + localization,
:attr:`~uav_struct_env.photos.PhotoPose.latency_s`, the detectors alternating photo by photo), the
detections' pixel error on both paths (within 3 px of a visible landmark's true projection,
paired over the landmarks both found: the JPEG's cost at the detector), the translation errors
compared frame by frame (each photo path with its env path, and every detector after the first
with the first on each path: the share of frames closer, Wilcoxon's p, a bootstrap interval of
the ratio of medians -- medians of 40 poses move by 10-20 % between encodings of one flight) and
the georeferencing round trip (project -> WGS84 -> project) over the flight's camera positions.

    python benchmarks/photo_roundtrip.py --episodes 10 --encodings 95 100
    python benchmarks/photo_roundtrip.py --detectors learned learned:active --encodings 95 100 95:422
    python benchmarks/photo_roundtrip.py --detectors guided learned --encodings 95:422 95 100 --latency
    python benchmarks/photo_roundtrip.py --ifc tests/data/ifc/duplex.ifc --stage "Level 2/slab"

``--ifc``: another building (its IFC re-written with the same IfcMapConversion) at ``--stage``.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
from tqdm import tqdm

import uav_struct_env
from localization.detect.learned import match_detections
from localization.geometry.transforms import rotation_angle_deg
from uav_struct_env.photos import localize_photos, plan_photos, read_ifc_georeference, run_plan
from uav_struct_env.photos.command import parse_prior_sigmas
from uav_struct_env.photos.dji_jpeg import dji_fields_from_pose, write_dji_jpeg
from uav_struct_env.site import load_ifc, paper_site
from uav_struct_env.site.ifc_export import write_building
from uav_struct_env.wrappers import LocalizationWrapper

STAGE = "Level 1/slab"
MAP_CONVERSION = {"crs": "EPSG:32632", "eastings": 691000.0, "northings": 5334000.0,
                  "orthogonal_height": 500.0, "x_axis_abscissa": math.cos(0.3),
                  "x_axis_ordinate": math.sin(0.3)}
_CHROMA = {"420": "4:2:0", "422": "4:2:2", "444": "4:4:4"}
#: A detection this close to a visible landmark's true projection is that landmark's, px.
MATCH_PX = 3.0


class _Frame(NamedTuple):
    """One rendered view: its image, the env's prior and truth, and the env path's detections."""

    name: str
    image: np.ndarray
    prior: np.ndarray
    truth: np.ndarray
    landmarks: dict
    env_uv: np.ndarray


def _paired(name: str, a: list[float], b: list[float]) -> None:
    """Print two runs' translation errors (per frame, NaN if failed) compared over the frames both localized.

    The share of frames where ``a`` is the closer, Wilcoxon's signed-rank p, the ratio of the
    medians with its bootstrap interval (2,000 draws of the frames) and the means.
    """
    from scipy.stats import wilcoxon

    x, y = np.asarray(a), np.asarray(b)
    both = np.isfinite(x) & np.isfinite(y)
    x, y = x[both], y[both]
    if len(x) < 5 or not np.any(x != y):
        print(f"    paired {name}: {len(x)} frames both localized, {np.count_nonzero(x != y)} differ")
        return
    draws = np.random.default_rng(0).integers(0, len(x), (2000, len(x)))
    ratio = np.median(x[draws], axis=1) / np.median(y[draws], axis=1)
    low, high = np.percentile(ratio, [2.5, 97.5])
    print(f"    paired {name}, {len(x)} frames: closer in {np.mean(x < y):.0%}, Wilcoxon p "
          f"{wilcoxon(x, y).pvalue:.2g}, median ratio x{np.median(x) / np.median(y):.3f} (bootstrap 95 % "
          f"{low:.3f}-{high:.3f}), mean {x.mean():.3f} against {y.mean():.3f} m")


def _pixel_errors(uv: np.ndarray, truth: dict) -> dict[int, float]:
    """``{landmark id: px}`` of the detections within :data:`MATCH_PX` of a visible true projection."""
    visible = np.asarray(truth["visible"], dtype=bool).reshape(-1)
    ids = np.asarray(truth["ids"]).reshape(-1)[visible]
    match, dist = match_detections(uv, np.asarray(truth["uv"], dtype=np.float64).reshape(-1, 2)[visible],
                                   MATCH_PX)
    return {int(ids[m]): float(d) for m, d in zip(match, dist, strict=True) if m >= 0}


def _pixel_summary(frames: list[_Frame], photo_uv: list[np.ndarray]) -> None:
    """Print the detections' pixel error, env vs photo path, paired over the landmarks both found."""
    env, photo = [], []
    for frame, uv in zip(frames, photo_uv, strict=True):
        a, b = _pixel_errors(frame.env_uv, frame.landmarks), _pixel_errors(uv, frame.landmarks)
        for key in a.keys() & b.keys():
            env.append(a[key])
            photo.append(b[key])
    if env:
        e, p = np.median(env), np.median(photo)
        print(f"    detections within {MATCH_PX:g} px, paired over {len(env)} landmarks: median env "
              f"{e:.3f} px, photo {p:.3f} px (x{p / e:.3f}); P90 env {np.percentile(env, 90):.3f} px, "
              f"photo {np.percentile(photo, 90):.3f} px")


def _summary(name: str, t: list[float], r: list[float], total: int) -> tuple[int, float, float]:
    """Print and return ``(localized, translation median, P90)``; ``t``, ``r`` per frame, NaN if failed."""
    t, r = [v for v in t if math.isfinite(v)], [v for v in r if math.isfinite(v)]
    t_med, t_p90 = np.median(t), np.percentile(t, 90)
    print(f"{name:34s} localized {len(t)}/{total}  translation median {t_med:.3f} m, P90 {t_p90:.3f} m  "
          f"rotation median {np.median(r):.3f} deg, P90 {np.percentile(r, 90):.3f} deg")
    return len(t), float(t_med), float(t_p90)


def _env_path(ifc: Path, stage: str, detector: str, episodes: int,
              seed: int) -> tuple[list, list, list, dict]:
    """Render the flight and localize it in the wrapper: errors, the frames and what the JPEGs need."""
    env = LocalizationWrapper(
        uav_struct_env.parallel_env(site=load_ifc(ifc, stage), noise="gnss_ins", render_mode="rgb_array"),
        landmarks="all", detector=detector)
    t, r, frames = [], [], []
    try:
        for episode in tqdm(range(episodes), desc=f"render + env path ({detector})"):
            obs, infos = env.reset(seed=seed + episode)
            for agent in sorted(obs):
                loc = infos[agent]["localization"]
                t.append(loc["translation_error_m"] if loc["success"] else math.nan)
                r.append(loc["rotation_error_deg"] if loc["success"] else math.nan)
                info = infos[agent]
                frames.append(_Frame(f"{episode:03d}_{agent}", obs[agent]["image"],
                                     info["prior_world_from_cam"], info["world_from_cam"],
                                     info["landmarks"]["all"], env.last_frames[agent].detections.uv))
    finally:
        env.close()
    return t, r, frames, infos["uav_0"]


def _jpeg_path(folder: Path, name: str, encoding: str) -> Path:
    quality, _, chroma = encoding.partition(":")
    return folder / f"DJI_{name}_q{quality}_{chroma or '420'}.JPG"


def _latency(photos: list[Path], ifc: Path, stage: str, camera: Path, detectors: tuple[str, ...]) -> None:
    """Print each detector's time per photo (:attr:`PhotoPose.latency_s`), the detectors alternating.

    Each photo is localized by every detector in turn, the order reversed on every other photo;
    the first photo warms each up and is not counted.
    """
    plan = plan_photos(photos, ifc, stage=stage, camera=camera, prior_sigmas=parse_prior_sigmas("3,3,2,5"))
    times: dict[str, list[float]] = {d: [] for d in detectors}
    for i, job in enumerate(tqdm(plan.jobs, desc="latency, detectors alternating")):
        for detector in detectors if i % 2 else detectors[::-1]:
            seconds = run_plan(replace(plan, jobs=[job]), detector)[0].latency_s
            if i:
                times[detector].append(seconds * 1000.0)
    h, w = _load_size(photos[0])
    for detector, ms in times.items():
        print(f"latency {detector:10s} per {w} x {h} photo (JPEG decode + detection + localization): median "
              f"{np.median(ms):.1f} ms, P90 {np.percentile(ms, 90):.1f} ms; / {detectors[0]} median x"
              f"{np.median(ms) / np.median(times[detectors[0]]):.3f} (over {len(ms)} photos)")


def _load_size(path: Path) -> tuple[int, int]:
    from PIL import Image

    with Image.open(path) as im:
        return im.height, im.width


def _photo_path(folder: Path, ifc: Path, frames: list[_Frame], camera: Path, detector: str, encoding: str,
                stage: str) -> tuple[list, list, list]:
    """The photo path at ``encoding``: translation and rotation errors, each photo's detections."""
    g = read_ifc_georeference(ifc)
    quality, _, chroma = encoding.partition(":")
    photos = []
    for name, image, prior, *_ in frames:
        path = _jpeg_path(folder, name, encoding)
        if not path.exists():
            write_dji_jpeg(path, image, dji_fields_from_pose(prior, g), quality=int(quality),
                           chroma=_CHROMA[chroma or "420"])
        photos.append(path)
    poses = localize_photos(photos, ifc, stage=stage, camera=camera, detector=detector,
                            prior_sigmas=parse_prior_sigmas("3,3,2,5"))
    pairs = [(p, f.truth) for p, f in zip(poses, frames, strict=True)]
    return ([float(np.linalg.norm(p.position - T[:3, 3])) if p.success else math.nan for p, T in pairs],
            [rotation_angle_deg(p.world_from_cam[:3, :3], T[:3, :3]) if p.success else math.nan
             for p, T in pairs],
            [p.detections_uv for p in poses])


def main(episodes: int = 10, encodings: tuple[str, ...] = ("95",), detectors: tuple[str, ...] = ("learned",),
         seed: int = 0, source: str | None = None, stage: str = STAGE, latency: bool = False) -> dict:
    out: dict = {}
    errors: dict[tuple[str, str], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        site = paper_site("slab") if source is None else load_ifc(source)
        ifc = write_building(site.name, site.storeys, site.elements, folder / "georef.ifc",
                             map_conversion=MAP_CONVERSION)
        first, base = None, None
        for detector in detectors:
            env_t, env_r, frames, info = _env_path(ifc, stage, detector, episodes, seed)
            if first is None:
                first, camera = frames, _calibration(folder, info)
            elif any(not np.array_equal(a.image, b.image) for a, b in zip(first, frames, strict=True)):
                raise RuntimeError("the env rendered other frames for another detector")
            total = len(frames)
            out[(detector, "env")] = env = _summary(f"env   {detector}", env_t, env_r, total)
            errors[(detector, "env")] = env_t
            base = base or (detector, env)
            for encoding in encodings:
                t, r, uv = _photo_path(folder, ifc, frames, camera, detector, encoding, stage)
                out[(detector, encoding)] = ph = _summary(f"photo {detector} q{encoding}", t, r, total)
                errors[(detector, encoding)] = t
                print(f"    photo / env translation median x{ph[1] / env[1]:.3f}, P90 x{ph[2] / env[2]:.3f}")
                _paired(f"photo {detector} q{encoding} against its env path", t, env_t)
                if base[0] != detector:
                    print(f"    photo / env of {base[0]}: translation median x{ph[1] / base[1][1]:.3f}, "
                          f"P90 x{ph[2] / base[1][2]:.3f}")
                _pixel_summary(frames, uv)
        for detector in detectors[1:]:
            for path in ("env", *encodings):
                _paired(f"{path}: {detector} against {detectors[0]}", errors[(detector, path)],
                        errors[(detectors[0], path)])
        if latency:
            _latency([_jpeg_path(folder, f.name, encodings[0]) for f in first], ifc, stage, camera, detectors)
        g = read_ifc_georeference(ifc)
        centres = np.array([f.truth[:3, 3] for f in first])
    round_trip = float(np.abs(g.project_from_wgs84(g.wgs84_from_project(centres)) - centres).max())
    print(f"georeferencing round trip over {len(centres)} camera positions: max {round_trip * 1000:.2e} mm")
    out["round_trip_m"] = round_trip
    return out


def _calibration(folder: Path, info: dict) -> Path:
    import cv2

    path = folder / "camera.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", info["intrinsics"])
    fs.write("distortion_coefficients", np.asarray(info["distortion"]).reshape(1, -1))
    fs.release()
    return path


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=10, help="env resets (4 photos each)")
    parser.add_argument("--encodings", nargs="+", default=["95"],
                        help="JPEG QUALITY or QUALITY:CHROMA (chroma 420, 422 or 444)")
    parser.add_argument("--detectors", nargs="+", default=["learned"],
                        help="guided, learned or learned:NAME (a weight set), each run through both paths")
    parser.add_argument("--seed", type=int, default=0, help="first episode's seed")
    parser.add_argument("--ifc", default=None, help="another building's IFC (none: the paper site)")
    parser.add_argument("--stage", default=STAGE, help="the stage localized against")
    parser.add_argument("--latency", action="store_true",
                        help="then time the detectors on the first encoding's photos, alternating per photo")
    args = parser.parse_args()
    main(args.episodes, tuple(args.encodings), tuple(args.detectors), args.seed, args.ifc, args.stage,
         args.latency)
