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
(detection + localization, :attr:`~uav_struct_env.photos.PhotoPose.latency_s`) and the
georeferencing round trip (project -> WGS84 -> project) over the flight's camera positions.

    python benchmarks/photo_roundtrip.py --episodes 10 --encodings 95 100
    python benchmarks/photo_roundtrip.py --detectors learned learned:active --encodings 95 100 95:422
    python benchmarks/photo_roundtrip.py --detectors guided learned --encodings 95:422 95 100 --seed 10
    python benchmarks/photo_roundtrip.py --ifc tests/data/ifc/duplex.ifc --stage "Level 2/slab"

``--ifc``: another building (its IFC re-written with the same IfcMapConversion) at ``--stage``.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

import uav_struct_env
from localization.geometry.transforms import rotation_angle_deg
from uav_struct_env.photos import localize_photos, read_ifc_georeference
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


def _summary(name: str, t: list[float], r: list[float], total: int) -> tuple[int, float, float]:
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
                if loc["success"]:
                    t.append(loc["translation_error_m"])
                    r.append(loc["rotation_error_deg"])
                info = infos[agent]
                frames.append((f"{episode:03d}_{agent}", obs[agent]["image"], info["prior_world_from_cam"],
                               info["world_from_cam"]))
    finally:
        env.close()
    return t, r, frames, infos["uav_0"]


def _photo_path(folder: Path, ifc: Path, frames: list, camera: Path, detector: str, encoding: str,
                stage: str) -> tuple[list, list]:
    g = read_ifc_georeference(ifc)
    quality, _, chroma = encoding.partition(":")
    photos = []
    for name, image, prior, _ in frames:
        path = folder / f"DJI_{name}_q{quality}_{chroma or '420'}.JPG"
        if not path.exists():
            write_dji_jpeg(path, image, dji_fields_from_pose(prior, g), quality=int(quality),
                           chroma=_CHROMA[chroma or "420"])
        photos.append(path)
    poses = localize_photos(photos, ifc, stage=stage, camera=camera, detector=detector,
                            prior_sigmas=parse_prior_sigmas("3,3,2,5"))
    found = [(p, T) for p, (*_, T) in zip(poses, frames, strict=True) if p.success]
    latency = np.array([p.latency_s for p in poses]) * 1000.0
    h, w = frames[0][1].shape[:2]
    print(f"    photo latency (detection + localization) median {np.median(latency):.1f} ms, "
          f"P90 {np.percentile(latency, 90):.1f} ms per {w} x {h} photo")
    return ([float(np.linalg.norm(p.position - T[:3, 3])) for p, T in found],
            [rotation_angle_deg(p.world_from_cam[:3, :3], T[:3, :3]) for p, T in found])


def main(episodes: int = 10, encodings: tuple[str, ...] = ("95",), detectors: tuple[str, ...] = ("learned",),
         seed: int = 0, source: str | None = None, stage: str = STAGE) -> dict:
    out: dict = {}
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
            elif any(not np.array_equal(a[1], b[1]) for a, b in zip(first, frames, strict=True)):
                raise RuntimeError("the env rendered other frames for another detector")
            total = len(frames)
            out[(detector, "env")] = env = _summary(f"env   {detector}", env_t, env_r, total)
            base = base or (detector, env)
            for encoding in encodings:
                t, r = _photo_path(folder, ifc, frames, camera, detector, encoding, stage)
                out[(detector, encoding)] = ph = _summary(f"photo {detector} q{encoding}", t, r, total)
                print(f"    photo / env translation median x{ph[1] / env[1]:.3f}, P90 x{ph[2] / env[2]:.3f}")
                if base[0] != detector:
                    print(f"    photo / env of {base[0]}: translation median x{ph[1] / base[1][1]:.3f}, "
                          f"P90 x{ph[2] / base[1][2]:.3f}")
        g = read_ifc_georeference(ifc)
        centres = np.array([T[:3, 3] for *_, T in first])
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
    args = parser.parse_args()
    main(args.episodes, tuple(args.encodings), tuple(args.detectors), args.seed, args.ifc, args.stage)
