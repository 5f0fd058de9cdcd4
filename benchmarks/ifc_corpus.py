"""The real-IFC corpus (data/ifc_corpus): parse time, stages and landmarks of every file present.

    .venv/bin/python benchmarks/ifc_corpus.py [--split all|train|heldout] [--timeout 600] [--files DIR]

For every building of ``data/ifc_corpus/manifest.json`` whose file is present locally (shipped
under ``data/ifc_corpus/files/``, or fetched there by ``benchmarks/fetch_ifc_corpus.py``; ``--files DIR``
looks for ``DIR/<name>.ifc`` instead), a fresh
Python process imports ifcopenshell and ``uav_struct_env.site`` (not timed), then times
``ifc_stages`` (the parse: tessellation and the import rules; the in-process cache is empty in a
fresh process) and ``load_ifc`` at the default stage (the highest, served from that cache), and
counts the landmarks of each structural set at that stage. One process per file, one file at a
time: a file that crashes, hangs or eats memory cannot take the others with it. A failure is
reported as its exception type and message.

Columns: name, authoring tool, schema, length unit, size (MB), parse (s: ``ifc_stages``, wall
clock), cpu (s: the same parse's CPU time in this process, ``time.process_time``: the "one core"
figure, which a busy machine inflates far less than the wall clock), load
(s: ``load_ifc`` after the parse), cached (s: the parse read back from the disk cache,
:mod:`uav_struct_env.site.ifc_cache`, as the next process to load the file does it: key, read,
unpickle), stages, slab_corners / opening_corners / column_tops at the default stage, split, the
default stage's name, and ``digest``: 12 hex digits of the SHA-256 of the imported building
(:func:`site_digest`: every element's fields, outline, openings and mesh, the storeys, the
stages, the report, and every stage's landmarks), so that two versions of the importer can be
compared file by file: equal digests, the same sites bit for bit. The children parse into a
fresh, empty cache folder (``UAV_STRUCT_IFC_CACHE``), so the parse is a first parse. A
benchmark, not a test: times depend on the machine and on what else runs on it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "data" / "ifc_corpus"
SETS = ("slab_corners", "opening_corners", "column_tops")


def local_path(entry: dict, files: str | Path | None = None) -> Path:
    """Where the manifest entry's file lives here (:func:`uav_struct_env.site.corpus.corpus_file`)."""
    from uav_struct_env.site.corpus import corpus_file

    return corpus_file(entry, files)


def site_digest(path: str | Path) -> str:
    """12 hex digits of the SHA-256 of the building ``path`` imports, at every stage.

    Hashed: each element's kind and dataclass fields, outline, openings (outline, name, guid,
    source) and mesh (vertices and faces, bytes); the storeys; each stage's name, elements and
    floor; the report's rows; ``site.source`` but its path; and each stage's landmarks of every
    structural set (ids, positions as bytes, labels, elements).
    """
    from uav_struct_env.site import ifc_stages, load_ifc

    digest = hashlib.sha256()

    def add(*parts: object) -> None:
        for part in parts:
            digest.update(np.ascontiguousarray(part).tobytes() if isinstance(part, np.ndarray)
                          else repr(part).encode())

    site = load_ifc(path)
    for e in site.elements:
        fields = {k: getattr(e, k) for k in e.__dataclass_fields__ if k not in ("mesh", "outline", "holes")}
        add(e.kind, sorted(fields.items()), e.outline, e.mesh.vertices, e.mesh.faces)
        for hole in getattr(e, "holes", ()):
            add(hole.name, hole.guid, hole.source, hole.outline)
    report = site.source["report"]
    add(site.storeys, [(st.name, sorted(st.built), st.floor) for st in site.stages],
        report.kept, report.dropped, report.skipped, report.repaired,
        sorted((k, v) for k, v in site.source.items() if k not in ("report", "path")))
    for stage in ifc_stages(path):
        at = load_ifc(path, stage)
        for name in SETS:
            lm = at.landmarks(name)
            add(stage, name, lm.ids, lm.xyz, lm.labels, lm.elements)
    return digest.hexdigest()[:12]


def measure(path: str) -> dict:
    """Parse and load one file in this process (meant to be a fresh one); the figures as a dict."""
    t = time.perf_counter()
    import ifcopenshell  # noqa: F401

    from uav_struct_env.site import ifc as ifc_module
    from uav_struct_env.site import ifc_stages, load_ifc

    out: dict = {"import_s": time.perf_counter() - t}
    try:
        t, cpu = time.perf_counter(), time.process_time()
        stages = ifc_stages(path)
        out["parse_s"] = time.perf_counter() - t
        out["parse_cpu_s"] = time.process_time() - cpu
        out["stages"] = len(stages)
        t = time.perf_counter()
        site = load_ifc(path)
        out["load_s"] = time.perf_counter() - t
        out["stage"] = site.stage
        out["landmarks"] = {name: len(site.landmarks(name)) for name in SETS}
        out["digest"] = site_digest(path)
        ifc_module._parse_cached.cache_clear()  # as a new process: the parse from the disk cache
        t = time.perf_counter()
        ifc_stages(path)
        out["cached_s"] = time.perf_counter() - t
    except Exception as exc:  # the benchmark reports every failure and goes on
        out["error"] = f"{type(exc).__name__}: {exc}"
        if "parse_s" not in out:  # a refusal: how long the parse took to refuse
            out["parse_s"] = time.perf_counter() - t
            out["parse_cpu_s"] = time.process_time() - cpu
    return out


def _run_child(path: Path, timeout: float) -> dict:
    """:func:`measure` in a fresh process whose parse cache is a fresh, empty folder."""
    from uav_struct_env.site.ifc_cache import IFC_CACHE_ENV

    cmd = [sys.executable, str(Path(__file__).resolve()), "--one", str(path)]
    try:
        with tempfile.TemporaryDirectory(prefix="ifc_corpus_cache_") as cache:
            done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                                  env={**os.environ, IFC_CACHE_ENV: cache})
    except subprocess.TimeoutExpired:
        return {"error": f"TimeoutExpired: still running after {timeout:.0f} s"}
    lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
    if done.returncode != 0 or not lines:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"error": f"exit {done.returncode}: {tail[:200]}"}
    return json.loads(lines[-1])


def main(manifest: str | Path = CORPUS / "manifest.json", split: str = "all", timeout: float = 600.0,
         names: list[str] | None = None, files: str | Path | None = None) -> list[dict]:
    """Measure every present file of the corpus (one fresh process each); print and return rows."""
    entries = json.loads(Path(manifest).read_text())["files"]
    rows = []
    header = (f"{'name':<22} {'tool':<22} {'schema':<7} {'unit':<5} {'MB':>5} {'parse s':>7} {'cpu s':>6} "
              f"{'load s':>6} {'cached':>6} "
              f"{'stages':>6} {'slab':>5} {'open':>5} {'col':>5}  {'split':<7} default stage, digest / error")
    print(header)
    print("-" * len(header))
    for e in entries:
        if split != "all" and e["split"] != split:
            continue
        if names and e["name"] not in names:
            continue
        p = local_path(e, files)
        row = {"name": e["name"], "tool": e["authoring_tool"], "schema": e["ifc_schema"],
               "unit": e["length_unit"], "split": e["split"], "path": str(p)}
        if not p.exists():
            row["error"] = ("not present locally (run benchmarks/fetch_ifc_corpus.py where GitHub "
                            "is reachable)")
        else:
            row["mb"] = p.stat().st_size / 1e6
            row.update(_run_child(p, timeout))
        rows.append(row)
        unit = {"metre": "m", "millimetre": "mm", "foot": "ft"}.get(row["unit"], row["unit"])
        mb = f"{row['mb']:5.1f}" if "mb" in row else "    -"
        parse = f"{row['parse_s']:7.1f}" if "parse_s" in row else "      -"
        cpu = f"{row['parse_cpu_s']:6.1f}" if "parse_cpu_s" in row else "     -"
        load = f"{row['load_s']:6.2f}" if "load_s" in row else "     -"
        cached = f"{row['cached_s']:6.2f}" if "cached_s" in row else "     -"
        stages = f"{row['stages']:6d}" if "stages" in row else "     -"
        lm = row.get("landmarks")
        counts = " ".join(f"{lm[s]:5d}" for s in SETS) if lm else "    -     -     -"
        tail = row.get("error") or f"{row.get('stage', '')}  digest {row.get('digest', '-')}"
        print(f"{row['name']:<22} {row['tool'][:22]:<22} {row['schema']:<7} {unit:<5} {mb} {parse} {cpu} "
              f"{load} {cached} {stages} {counts}  {row['split']:<7} {tail}", flush=True)
    ok = sum(1 for r in rows if "landmarks" in r)
    print(f"{ok} of {len(rows)} files loaded at their default stage")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--manifest", default=str(CORPUS / "manifest.json"), help="the corpus manifest")
    parser.add_argument("--split", default="all", choices=("all", "train", "heldout"), help="which files")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds allowed per file")
    parser.add_argument("--names", nargs="*", default=None, help="only these corpus names")
    parser.add_argument("--files", default=None,
                        help="a folder holding <name>.ifc for each file (none: the manifest's local_path)")
    parser.add_argument("--one", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure(args.one)))
    else:
        main(manifest=args.manifest, split=args.split, timeout=args.timeout, names=args.names,
             files=args.files)
