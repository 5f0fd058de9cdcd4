"""IFC parse time of every corpus file, and what a change to the importer moves, file by file.

    .venv/bin/python benchmarks/ifc_import_diff.py dump DIR [--files data/ifc_corpus/files] [--names ...]
    .venv/bin/python benchmarks/ifc_import_diff.py compare BEFORE AFTER

``dump`` parses every file of ``data/ifc_corpus/manifest.json`` that is present, each in a fresh
Python process with a fresh, empty parse cache (``UAV_STRUCT_IFC_CACHE``), and times the first
parse (``ifc_stages``: CPU seconds, ``time.process_time``, the "one core" figure, and wall
clock); run it under ``taskset -c 0`` for one core. It then writes ``DIR/<name>.pickle``: the
times, the file's size, the import report (kept, dropped, skipped, repaired rows), every element's
kind, name, storey, heights, outline, openings and mesh size, and every stage's landmarks of every
structural set (label, its occurrence and position). A refusal is recorded with its message.

``compare`` reads two such folders (the importer before and after a change) and prints, per
file: the parse CPU before -> after, whether the report's rows are the same (else the rows that
differ), and the largest displacement of a landmark (matched by stage, set, label and the
label's occurrence), of an element's outline and of an opening's outline (symmetric Hausdorff
distance, metres), and how many meshes changed. A benchmark, not a test: times depend on the
machine and its load.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from ifc_corpus import local_path  # this folder's sibling: where a corpus file lives

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "data" / "ifc_corpus" / "manifest.json"
SETS = ("slab_corners", "opening_corners", "column_tops")


def snapshot(path: str) -> dict:
    """Parse ``path`` in this (fresh) process: times, report, elements and every stage's landmarks."""
    import ifcopenshell  # noqa: F401

    from uav_struct_env.site import ifc_stages, load_ifc

    out: dict = {"mb": Path(path).stat().st_size / 1e6}
    t, cpu = time.perf_counter(), time.process_time()
    try:
        stages = ifc_stages(path)
    except Exception as exc:  # a refusal is a result
        out.update(parse_cpu_s=time.process_time() - cpu, parse_s=time.perf_counter() - t,
                   error=f"{type(exc).__name__}: {exc}")
        return out
    out.update(parse_cpu_s=time.process_time() - cpu, parse_s=time.perf_counter() - t)
    site = load_ifc(path)
    report = site.source["report"]
    out["report"] = {"kept": report.kept, "dropped": report.dropped, "skipped": report.skipped,
                     "repaired": report.repaired}
    out["elements"] = {
        e.guid: {"kind": e.kind, "name": e.name, "storey": e.storey, "z": (e.z_bottom, e.z_top),
                 "outline": np.asarray(e.outline), "mesh": (len(e.mesh.vertices), len(e.mesh.faces)),
                 "mesh_bytes": hashlib.sha256(np.asarray(e.mesh.vertices).tobytes()).hexdigest(),
                 "holes": {h.guid: np.asarray(h.outline) for h in getattr(e, "holes", ())}}
        for e in site.elements}
    out["stages"] = stages
    out["landmarks"] = {}
    for stage in stages:
        at = load_ifc(path, stage)
        for name in SETS:
            lm = at.landmarks(name)
            seen: dict[str, int] = {}
            for label, xyz in zip(lm.labels, lm.xyz, strict=True):  # a label may repeat: count it
                seen[label] = seen.get(label, -1) + 1
                out["landmarks"][(stage, name, label, seen[label])] = np.asarray(xyz, dtype=np.float64)
    return out


def dump(folder: str | Path, files: str | None = None, names: list[str] | None = None) -> None:
    """Snapshot every present corpus file into ``folder`` (one fresh process and cache each)."""
    from uav_struct_env.site.ifc_cache import IFC_CACHE_ENV

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for entry in json.loads(MANIFEST.read_text())["files"]:
        if names and entry["name"] not in names:
            continue
        path = local_path(entry, files)
        if not path.exists():
            print(f"{entry['name']:<22} absent ({path})")
            continue
        with tempfile.TemporaryDirectory(prefix="ifc_diff_cache_") as cache:
            target = folder / f"{entry['name']}.pickle"
            cmd = [sys.executable, str(Path(__file__).resolve()), "one", str(path), str(target)]
            done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True,
                                  env={**os.environ, IFC_CACHE_ENV: cache, "PYTHONPATH": os.pathsep.join(
                                      [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])})
        if done.returncode != 0:
            print(f"{entry['name']:<22} exit {done.returncode}: {done.stderr.strip()[-300:]}")
            continue
        snap = pickle.loads(target.read_bytes())
        tail = (snap["error"] if "error" in snap
                else f"{len(snap['elements'])} elements, {len(snap['landmarks'])} landmarks")
        print(f"{entry['name']:<22} {snap['mb']:5.2f} MB  parse {snap['parse_cpu_s']:6.2f} s CPU "
              f"{snap['parse_s']:6.2f} s wall  {tail[:100]}", flush=True)


def _hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    import shapely

    return float(shapely.Polygon(a).hausdorff_distance(shapely.Polygon(b)))


def _differences(a: dict, b: dict) -> dict:
    """What moved from snapshot ``a`` to ``b`` (both of one file that imports)."""
    out: dict = {}
    for key in ("kept", "dropped", "skipped", "repaired"):
        ra, rb = set(a["report"][key]), set(b["report"][key])
        if ra != rb:
            out[key] = (sorted(ra - rb), sorted(rb - ra))
    ea, eb = a["elements"], b["elements"]
    common = ea.keys() & eb.keys()
    out["elements_only_before"] = sorted(ea.keys() - eb.keys())
    out["elements_only_after"] = sorted(eb.keys() - ea.keys())
    out["outline_max_m"] = max((_hausdorff(ea[g]["outline"], eb[g]["outline"]) for g in common), default=0.0)
    out["outlines_changed"] = sum(not np.array_equal(ea[g]["outline"], eb[g]["outline"]) for g in common)
    holes = [(ea[g]["holes"][h], eb[g]["holes"][h]) for g in common for h in ea[g]["holes"].keys()
             & eb[g]["holes"].keys()]
    out["holes_differ"] = sum(ea[g]["holes"].keys() != eb[g]["holes"].keys() for g in common)
    out["hole_max_m"] = max((_hausdorff(p, q) for p, q in holes), default=0.0)
    out["meshes_changed"] = sum(ea[g]["mesh_bytes"] != eb[g]["mesh_bytes"] for g in common)
    out["z_max_m"] = max((float(np.max(np.abs(np.subtract(ea[g]["z"], eb[g]["z"])))) for g in common),
                         default=0.0)
    la, lb = a["landmarks"], b["landmarks"]
    out["landmarks_only_before"] = sorted(la.keys() - lb.keys())
    out["landmarks_only_after"] = sorted(lb.keys() - la.keys())
    out["landmark_max_m"] = max((float(np.linalg.norm(la[k] - lb[k])) for k in la.keys() & lb.keys()),
                                default=0.0)
    out["landmarks"] = len(la)
    return out


def compare(before: str | Path, after: str | Path) -> dict[str, dict]:
    """Print and return, per file in both folders, the parse times and what moved."""
    rows = {}
    for pa in sorted(Path(before).glob("*.pickle")):
        pb = Path(after) / pa.name
        if not pb.exists():
            continue
        a, b = pickle.loads(pa.read_bytes()), pickle.loads(pb.read_bytes())
        name = pa.stem
        head = (f"{name:<22} {a['mb']:5.2f} MB  parse CPU {a['parse_cpu_s']:6.2f} -> "
                f"{b['parse_cpu_s']:6.2f} s (wall {a['parse_s']:6.2f} -> {b['parse_s']:6.2f} s)")
        if "error" in a or "error" in b:
            same = a.get("error") == b.get("error")
            verdict = "the same" if same else "DIFFERENTLY"
            print(f"{head}  refused {verdict}: {b.get('error', 'imports')[:80]}")
            rows[name] = {"same_refusal": same}
            continue
        d = _differences(a, b)
        rows[name] = d
        rep = [k for k in ("kept", "dropped", "skipped", "repaired") if k in d]
        print(f"{head}  report {'same' if not rep else 'DIFFERS in ' + ', '.join(rep)}; "
              f"landmarks {d['landmarks']} max {1000 * d['landmark_max_m']:.4f} mm; outlines changed "
              f"{d['outlines_changed']} max {1000 * d['outline_max_m']:.4f} mm; holes max "
              f"{1000 * d['hole_max_m']:.4f} mm; meshes changed {d['meshes_changed']}; z max "
              f"{1000 * d['z_max_m']:.4f} mm")
        for k in rep:
            for row in d[k][0]:
                print(f"    {k} before only: {row}")
            for row in d[k][1]:
                print(f"    {k} after only:  {row}")
        for k in ("elements_only_before", "elements_only_after", "landmarks_only_before",
                  "landmarks_only_after"):
            if d[k]:
                print(f"    {k}: {d[k][:6]}{' ...' if len(d[k]) > 6 else ''}")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p_dump = sub.add_parser("dump", help="parse every present corpus file into DIR")
    p_dump.add_argument("folder", help="where the snapshots and parse times go")
    p_dump.add_argument("--files", default=None, help="a folder holding <name>.ifc (none: the manifest's)")
    p_dump.add_argument("--names", nargs="*", default=None, help="only these corpus names")
    p_cmp = sub.add_parser("compare", help="what moved from BEFORE to AFTER")
    p_cmp.add_argument("before", help="a dump's folder")
    p_cmp.add_argument("after", help="another dump's folder")
    p_one = sub.add_parser("one", help="one file's snapshot (a dump's worker)")
    p_one.add_argument("path", help="the IFC file")
    p_one.add_argument("target", help="the snapshot file to write")
    args = parser.parse_args()
    if args.command == "dump":
        dump(args.folder, args.files, args.names)
    elif args.command == "compare":
        compare(args.before, args.after)
    else:
        Path(args.target).write_bytes(pickle.dumps(snapshot(args.path)))
