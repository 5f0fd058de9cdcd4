"""Latency of the BIM-guided detector beside the learned detector's, per landmark type, one core.

Renders ``--viewpoints`` viewpoints x 4 UAVs of a site at 1280 x 720 (the study's environment,
priors and cameras), builds the study's stack for every landmark type the stage has (at least
four landmarks) with ``--detector learned`` and with ``--detector guided``, and times each
detector's ``detect`` on every frame, alternating which goes first (this machine's speed drifts
by about 10 % within minutes, so only figures of the same run compare). One thread: ONNX Runtime
runs one per network and ``cv2.setNumThreads(1)``; the template renderer is single-threaded.
The guided figure is its whole detection: the learned detector, the first localization, the
template matching (and, from a first pose the verification did not confirm, the wide template
pass and its localization; without any first pose, the model aligned with the image at the
prior, the wide passes from its hypotheses and their localizations); its parts are printed too
(the narrow pass as "templates", where a first pose exists; the alignment and its hypotheses'
fitted poses as "alignment from the prior", where none does; these parts are timed without the
frame's sharing). The guided detectors of a frame's sets share the learned detector's run and the
alignment from the prior (``uav_struct_env.stack.frame_memo``): the first set of a frame pays for
them, so the sum over the frame's sets ("guided, every set of the frame") is printed too. Times
are the process's CPU time (``time.process_time``; one thread, so the machine's other load counts
less than in wall time).

    python benchmarks/guided_detector.py                                   # the paper site, both stages
    python benchmarks/guided_detector.py --site tests/data/ifc/duplex.ifc --stages "Roof/slab"

Only train buildings (docs/study.md, the real-building corpus) belong here: a held-out building
is evaluated once, with the method fixed.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
from tqdm import tqdm

import uav_struct_env
from localization import Detections
from localization.geometry.transforms import invert
from uav_struct_env.site import STRUCTURAL_SETS, load_ifc
from uav_struct_env.stack import build_stack
from uav_struct_env.study.protocol import METHODS, StudyConfig
from uav_struct_env.study.run import stack_spec


def _site(site: str, stage: str):
    if site.lower().endswith(".ifc"):
        return {"site": load_ifc(site, stage=stage)}
    return {"stage": stage}


def _timed(fn, *args) -> tuple[float, object]:
    t0 = time.process_time()
    out = fn(*args)
    return time.process_time() - t0, out


def _stacks(config: StudyConfig, site, info: dict) -> dict:
    """Per structural set with >= 4 landmarks: (learned stack, guided stack)."""
    out = {}
    for method in METHODS:
        if not method.structural or method.landmarks not in STRUCTURAL_SETS or method.key in out:
            continue
        model = site.landmarks(method.landmarks)
        if len(model) < 4:
            continue
        pair = []
        for detector in ("learned", "guided"):
            spec = stack_spec(StudyConfig(detector=detector, site=config.site), method)
            pair.append(build_stack(spec, info["intrinsics"], (1280, 720), model_xyz=model.xyz,
                                    model_ids=model.ids, distortion=info["distortion"], site=site))
        out[method.landmarks] = tuple(pair)
    return out


def _starts_unshared(starts, image, prior) -> list:
    """Every start from the prior, computed afresh (not the frame's shared ones)."""
    return [starts.refined(image, a.cam_from_world) for a in starts.aligner.align(image, prior, starts.K)]


def _frame(stacks: dict, image, info: dict, flip: bool, times: dict) -> None:
    prior = invert(info["prior_world_from_cam"])
    frame_total = 0.0
    for name, (learned, guided) in stacks.items():
        context = {"landmarks": {}, "image_size": (1280, 720), "prior_cam_from_world": prior}
        order = [("learned", learned), ("guided", guided)]
        order = order[::-1] if flip else order
        for label, stack in order:
            dt, _ = _timed(stack.detector.detect, image, context)
            times.setdefault((name, label), []).append(dt)
            frame_total += dt if label == "guided" else 0.0
        g = guided.detector  # its parts, once more (not alternated: a breakdown, not a comparison)
        seed = getattr(g.seed, "detector", g.seed)  # the learned detector itself, not the frame's shared run
        dt_seed, (uv, scores, types) = _timed(seed.detect_all, image)
        mine = np.isin(types, g.types)
        dt_pose, (pose, _) = _timed(g.first_pose, Detections(uv[mine], scores[mine]), Detections(uv, scores),
                                    prior)
        dt_find = dt_align = float("nan")
        if pose is not None:  # the narrow pass (an unconfirmed first pose adds a wide one and a localization)
            dt_find = _timed(g.matcher.find, image, pose, g.localizer.K, g.localizer.distortion)[0]
        else:  # no first pose: the model aligned at the prior and each alignment's fitted pose
            dt_align = _timed(_starts_unshared, g.prior_starts, image, prior)[0]
        parts = (("learned, all types", dt_seed), ("first localization", dt_pose), ("templates", dt_find),
                 ("alignment from the prior", dt_align))
        for part, dt in parts:
            times.setdefault((name, "guided: " + part), []).append(dt)
    times.setdefault(("every set", "guided, every set of the frame"), []).append(frame_total)


def main(site: str = "paper", stages: tuple[str, ...] = ("slab", "columns"), viewpoints: int = 3) -> dict:
    """Time both detectors; returns ``{(set, detector or part): [seconds per frame]}``."""
    cv2.setNumThreads(1)
    times: dict = {}
    config = StudyConfig(detector="guided", site=site)
    flip = False
    for stage in stages:
        env = uav_struct_env.parallel_env(image_size=(1280, 720), **_site(site, stage))
        for vp in tqdm(range(viewpoints), desc=f"stage {stage}"):
            obs, infos = env.reset(seed=vp, options={"viewpoint": vp})
            for agent in env.possible_agents:
                stacks = _stacks(config, env.site, infos[agent])
                _frame(stacks, obs[agent]["image"], infos[agent], flip, times)
                flip = not flip
        env.close()
    print("| landmarks | detector | median ms | p90 ms | frames |\n|---|---|---:|---:|---:|")
    for (name, label), values in times.items():
        v = np.asarray(values) * 1000
        v = v[np.isfinite(v)]
        if len(v):
            print(f"| {name} | {label} | {np.median(v):.1f} | {np.percentile(v, 90):.1f} | {len(v)} |")
    for name in {n for n, _ in times} - {"every set"}:
        ratio = np.asarray(times[(name, "guided")]) / np.asarray(times[(name, "learned")])
        print(f"{name}: guided / learned, per frame: median {np.median(ratio):.2f}")
    return times


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--site", default="paper", help="paper or a train building's IFC file")
    p.add_argument("--stages", nargs="+", default=["slab", "columns"], help="stages to render")
    p.add_argument("--viewpoints", type=int, default=3, help="viewpoints per UAV (4 UAVs)")
    return p


if __name__ == "__main__":
    a = _parser().parse_args()
    main(a.site, tuple(a.stages), a.viewpoints)
