"""IFC import time: cold (first parse and tessellation) and warm (another stage, cached).

    .venv/bin/python benchmarks/ifc_import.py [--path tests/data/ifc/duplex.ifc] [--repeats 3] [--breakdown]

Cold is the first ``load_ifc`` in the process after ``import ifcopenshell`` (timed separately);
each further cold repeat clears the in-process cache first, and every cold load runs with the disk
cache off (``UAV_STRUCT_IFC_CACHE=off``; ``benchmarks/ifc_corpus.py`` times the load from it).
Warm is ``load_ifc`` of another stage of the same file (the tessellation is cached). Issue 13's
target: at most 5 s for a 3 MB file on one core; the cold CPU time (``time.process_time``) is that
figure when the machine is busy.

``--breakdown`` splits one more cold parse (CPU seconds, ``time.process_time``) into the
geometry kernel (ifcopenshell's iterator tessellating the imported elements, :func:`_tessellate`),
the plan footprints (the union of each element's plan triangles, :func:`_footprint`), the slab
tops (:func:`_slab_top`) and the rest of the import rules; then it tessellates the same elements
once more, one at a time through the iterator, and prints the kernel's CPU per kind of body
representation (``IfcBooleanClippingResult[2]/IfcExtrudedAreaSolid/IfcIShapeProfileDef``: a
boolean result two levels deep over an extruded I-section), the costliest first. The split wraps
the importer's own functions in timers for that one parse; nothing else changes.
A benchmark, not a test: numbers depend on the machine and on what else runs on it.
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

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


@contextmanager
def _timed(module: Any, names: tuple[str, ...], spent: Counter) -> Iterator[None]:
    """Wrap ``module.<name>`` for each name in a CPU timer adding to ``spent[name]``; restore on exit."""
    originals = {name: getattr(module, name) for name in names}

    def timer(name: str, fn: Callable) -> Callable:
        @functools.wraps(fn)
        def wrapped(*args: Any, **kwargs: Any) -> Any:
            t = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] += time.process_time() - t
        return wrapped

    try:
        for name, fn in originals.items():
            setattr(module, name, timer(name, fn))
        yield
    finally:
        for name, fn in originals.items():
            setattr(module, name, fn)


def representation_kind(product: Any) -> str:
    """The kind of ``product``'s body: its items' classes, booleans with their depth and first operand."""
    kinds = []
    body = [rep for rep in (product.Representation.Representations if product.Representation else ())
            if rep.RepresentationIdentifier == "Body"]
    for item in (i for rep in body for i in rep.Items):
        prefix = ""
        while item.is_a("IfcMappedItem"):
            prefix, item = prefix + "IfcMappedItem/", item.MappingSource.MappedRepresentation.Items[0]
        kind, depth = item.is_a(), 0
        while item.is_a("IfcBooleanResult"):
            item, depth = item.FirstOperand, depth + 1
        if depth:
            kind += f"[{depth}]/" + item.is_a()
        if item.is_a("IfcSweptAreaSolid"):
            kind += "/" + item.SweptArea.is_a()
        kinds.append(prefix + kind)
    return " + ".join(kinds) or "no body"


def kernel_by_kind(path: str | Path) -> list[tuple[str, int, int, float]]:
    """``(kind, elements, triangles, kernel CPU s)`` of the imported elements of ``path``, costliest first.

    The iterator computes an element's shape in the ``next()`` that reaches it: that call's CPU
    is the element's (the first element's is ``initialize()``'s).
    """
    import ifcopenshell
    import ifcopenshell.geom

    from uav_struct_env.site.ifc import IMPORTED_CLASSES

    f = ifcopenshell.open(str(path))
    include = [e for cls in IMPORTED_CLASSES for e in f.by_type(cls)]
    kinds = {e.id(): representation_kind(e) for e in include}
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    it = ifcopenshell.geom.iterator(settings, f, 1, include=include)
    cpu, count, triangles = Counter(), Counter(), Counter()
    t = time.process_time()
    more = bool(include) and it.initialize()
    while more:
        shape = it.get()
        kind = kinds[shape.id]
        cpu[kind] += time.process_time() - t
        count[kind] += 1
        triangles[kind] += len(shape.geometry.faces) // 3
        t = time.process_time()
        more = it.next()
    return sorted(((k, count[k], triangles[k], cpu[k]) for k in count), key=lambda r: -r[3])


def breakdown(path: str | Path) -> dict[str, float]:
    """One cold parse of ``path`` (disk cache off) split into its parts, CPU s; printed and returned."""
    import numpy as np

    from uav_struct_env.site import ifc as ifc_module

    parts = ("_tessellate", "_footprint", "_slab_top")
    spent: Counter = Counter()
    t = time.process_time()
    with _timed(ifc_module, parts, spent):
        ifc_module._parse(Path(path), np.eye(4))
    total = time.process_time() - t
    out = {"total_cpu_s": total, "kernel_cpu_s": spent["_tessellate"], "footprint_cpu_s": spent["_footprint"],
           "slab_top_cpu_s": spent["_slab_top"],
           "rules_cpu_s": total - spent["_tessellate"] - spent["_footprint"] - spent["_slab_top"]}
    print(f"cold parse, CPU: {total:.2f} s = kernel {out['kernel_cpu_s']:.2f} s (ifcopenshell's iterator) "
          f"+ footprints {out['footprint_cpu_s']:.2f} s + slab tops {out['slab_top_cpu_s']:.2f} s "
          f"+ the other rules {out['rules_cpu_s']:.2f} s")
    rows = kernel_by_kind(path)
    print(f"kernel CPU by body representation (a second tessellation, {sum(r[3] for r in rows):.2f} s):")
    for kind, n, tri, cpu in rows:
        print(f"  {cpu:7.2f} s  {n:5d} elements  {tri / n:7.1f} triangles each  {kind}")
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--path", default=str(DUPLEX), help="IFC file to import")
    parser.add_argument("--repeats", type=int, default=3, help="timed imports (the median is reported)")
    parser.add_argument("--breakdown", action="store_true",
                        help="then split a cold parse into kernel, footprints and rules, and the kernel by "
                        "body representation")
    args = parser.parse_args()
    main(args.path, args.repeats)
    if args.breakdown:
        breakdown(args.path)
