"""A rendered flight through two doors: the env's LocalizationWrapper and DJI-style JPEGs + localize.

The paper site is written as a georeferenced IFC (IfcMapConversion at UTM zone 32N, the x axis
17.19 deg from east); the env renders it from that IFC (stage ``Level 1/slab``, ``gnss_ins``
prior, learned detector, robust association, landmarks ``all``). Each agent's frame is localized
by the wrapper (the env path) and also written as a JPEG with EXIF GPS and DJI XMP built from the
env's prior (:mod:`uav_struct_env.photos.dji_jpeg`), then localized by
:func:`uav_struct_env.photos.localize_photos` with the same prior sigmas (the photo path). Prints
both paths' success counts and median / P90 translation and rotation errors, their ratio, and
the georeferencing round trip (project -> WGS84 -> project) over the flight's camera positions.

    python benchmarks/photo_roundtrip.py --episodes 10 --quality 95
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


def _summary(name: str, t: list[float], r: list[float], total: int) -> tuple[float, float]:
    t_med, t_p90 = np.median(t), np.percentile(t, 90)
    print(f"{name:6s} localized {len(t)}/{total}  translation median {t_med:.3f} m, P90 {t_p90:.3f} m  "
          f"rotation median {np.median(r):.3f} deg, P90 {np.percentile(r, 90):.3f} deg")
    return float(t_med), float(t_p90)


def main(episodes: int = 10, quality: int = 95, seed: int = 0, source: str | None = None,
         stage: str = STAGE) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        site = paper_site("slab") if source is None else load_ifc(source)
        ifc = write_building(site.name, site.storeys, site.elements, folder / "georef.ifc",
                             map_conversion=MAP_CONVERSION)
        g = read_ifc_georeference(ifc)
        env = LocalizationWrapper(
            uav_struct_env.parallel_env(site=load_ifc(ifc, stage), noise="gnss_ins", render_mode="rgb_array"),
            landmarks="all", detector="learned")
        env_t, env_r, photos, truth = [], [], [], []
        try:
            for episode in tqdm(range(episodes), desc="render + env path"):
                obs, infos = env.reset(seed=seed + episode)
                for agent in sorted(obs):
                    info = infos[agent]
                    loc = info["localization"]
                    if loc["success"]:
                        env_t.append(loc["translation_error_m"])
                        env_r.append(loc["rotation_error_deg"])
                    path = folder / f"DJI_{episode:03d}_{agent}.JPG"
                    fields = dji_fields_from_pose(info["prior_world_from_cam"], g)
                    write_dji_jpeg(path, obs[agent]["image"], fields, quality=quality)
                    photos.append(path)
                    truth.append(info["world_from_cam"])
            camera = _calibration(folder, infos["uav_0"])
        finally:
            env.close()
        poses = localize_photos(photos, ifc, stage=stage, camera=camera,
                                prior_sigmas=parse_prior_sigmas("3,3,2,5"))
    found = [(p, T) for p, T in zip(poses, truth, strict=True) if p.success]
    ph_t = [float(np.linalg.norm(p.position - T[:3, 3])) for p, T in found]
    ph_r = [rotation_angle_deg(p.world_from_cam[:3, :3], T[:3, :3]) for p, T in found]
    total = len(photos)
    env_med, env_p90 = _summary("env", env_t, env_r, total)
    ph_med, ph_p90 = _summary("photo", ph_t, ph_r, total)
    print(f"photo / env: translation median x{ph_med / env_med:.3f}, P90 x{ph_p90 / env_p90:.3f}")
    centres = np.array([T[:3, 3] for T in truth])
    round_trip = float(np.abs(g.project_from_wgs84(g.wgs84_from_project(centres)) - centres).max())
    print(f"georeferencing round trip over {len(centres)} camera positions: max {round_trip * 1000:.2e} mm")
    return {"env": (len(env_t), env_med, env_p90), "photo": (len(ph_t), ph_med, ph_p90),
            "round_trip_m": round_trip}


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
    parser.add_argument("--quality", type=int, default=95, help="JPEG quality")
    parser.add_argument("--seed", type=int, default=0, help="first episode's seed")
    parser.add_argument("--ifc", default=None, help="another building's IFC (none: the paper site)")
    parser.add_argument("--stage", default=STAGE, help="the stage localized against")
    args = parser.parse_args()
    main(args.episodes, args.quality, args.seed, args.ifc, args.stage)
