"""IFC import time: cold (first parse and tessellation) and warm (another stage, cached).

    .venv/bin/python benchmarks/ifc_import.py [--path tests/data/ifc/duplex.ifc] [--repeats 3]

Cold is the first ``load_ifc`` in the process after ``import ifcopenshell`` (timed separately);
each further cold repeat clears the in-process cache first, and every cold load runs with the disk
cache off (``UAV_STRUCT_IFC_CACHE=off``; ``benchmarks/ifc_corpus.py`` times the load from it).
Warm is ``load_ifc`` of another stage of the same file (the tessellation is cached). Issue 13's
target: at most 5 s for a 3 MB file on one core; the cold CPU time (``time.process_time``) is that
figure when the machine is busy.
A benchmark, not a test: numbers depend on the machine and on what else runs on it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

DUPLEX = Path(__file__).resolve().parents[1] / "tests" / "data" / "ifc" / "duplex.ifc"


def main(path: str | Path = DUPLEX, repeats: int = 3) -> dict[str, float]:
    """Time the import, print the figures and return them (seconds)."""
    t = time.perf_counter()
    import ifcopenshell  # noqa: F401

    from uav_struct_env.site import ifc as ifc_module
    from uav_struct_env.site import ifc_stages, load_ifc
    from uav_struct_env.site.ifc_cache import IFC_CACHE_ENV

    library = time.perf_counter() - t
    cold, cold_cpu = [], []
    before, os.environ[IFC_CACHE_ENV] = os.environ.get(IFC_CACHE_ENV), "off"
    for _ in range(repeats):
        ifc_module._parse_cached.cache_clear()
        t, cpu = time.perf_counter(), time.process_time()
        site = load_ifc(path)
        cold.append(time.perf_counter() - t)
        cold_cpu.append(time.process_time() - cpu)
    if before is None:
        del os.environ[IFC_CACHE_ENV]
    else:
        os.environ[IFC_CACHE_ENV] = before
    stages = ifc_stages(path)
    warm = []
    for k in range(max(repeats, len(stages))):
        t = time.perf_counter()
        load_ifc(path, stage=stages[k % len(stages)])
        warm.append(time.perf_counter() - t)
    size_mb = Path(path).stat().st_size / 1e6
    out = {"import_ifcopenshell_s": library, "cold_s": statistics.median(cold), "cold_first_s": cold[0],
           "cold_cpu_s": statistics.median(cold_cpu), "warm_s": statistics.median(warm)}
    print(f"{Path(path).name}: {size_mb:.1f} MB, {len(site.elements)} elements, stages {stages}")
    print(f"import ifcopenshell + uav_struct_env.site.ifc: {library:.2f} s")
    print(f"cold load_ifc (parse + tessellate + rules): first {cold[0]:.2f} s, median {out['cold_s']:.2f} s "
          f"over {repeats}; CPU median {out['cold_cpu_s']:.2f} s (the one-core figure on a busy machine)")
    print(f"warm load_ifc (another stage, cached):      median {1000 * out['warm_s']:.1f} ms")
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--path", default=str(DUPLEX), help="IFC file to import")
    parser.add_argument("--repeats", type=int, default=3, help="timed imports (the median is reported)")
    args = parser.parse_args()
    main(args.path, args.repeats)
