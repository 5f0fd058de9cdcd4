"""Issue 44, items 1 and 5: every file of the real-IFC corpus that is present imports, or is refused
with its documented reason, within the parse-time target; a file that imports loads from the disk
parse cache in the next process within it too, unchanged.

Slow (``pytest -m slow``): the files are not in the repository; ``benchmarks/fetch_ifc_corpus.py``
downloads them into ``data/ifc_corpus/files/`` (a test skips, naming it, when its file is absent).
The default suite keeps the real duplex (``tests/site/test_ifc.py``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from uav_struct_env.errors import IfcImportError  # noqa: E402
from uav_struct_env.site import ifc as ifc_module  # noqa: E402
from uav_struct_env.site import ifc_cache, ifc_stages, load_ifc  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = json.loads((ROOT / "data" / "ifc_corpus" / "manifest.json").read_text())
#: The parse-time target: CPU seconds for a 3 MB file on one core (issue 13, issue 44 item 5).
TARGET_S_PER_3MB = 5.0
#: The files that cannot give a camera a stage, and what the refusal says (counted by rule).
REFUSED = {
    "sketchup_pcert_house": "(3 IfcSlab: 2 sloped or stepped; 1 ground-bearing at the terrain; 0 IfcColumn",
    "bricscad_roof": "(6 IfcSlab: 6 sloped or stepped; 0 IfcColumn",
    "revit_office_a": "(2 IfcSlab: 2 thinner than a structural floor; 0 IfcColumn",
    "revit_cpm": "(40 IfcSlab: 30 sloped or stepped; 5 aggregates of parts; 5 ground-bearing at the terrain",
}
#: The files whose tessellation alone (OpenCASCADE, in ifcopenshell) outlasts the target.
TOO_SLOW = {
    "tekla_carwash": "1,999 beams, columns and slabs (89 CSG booleans, 127 faceted breps): "
                     "OpenCASCADE's tessellation takes about 17 s CPU",
    "tekla_steel_frame": "2,686 steel members and plates: OpenCASCADE's tessellation takes about 43 s CPU, "
                         "34 s of it the boolean cuts of 644 beams",
    "renga_house": "its walls are IfcBooleanClippingResult: OpenCASCADE clips each in about 0.35 s CPU",
}


def _path(entry: dict) -> Path:
    p = Path(entry["local_path"])
    return p if p.is_absolute() else ROOT / p


@pytest.mark.slow
@pytest.mark.parametrize("entry", MANIFEST["files"], ids=[e["name"] for e in MANIFEST["files"]])
def test_every_corpus_file_loads_or_is_refused_with_its_reason(entry, tmp_path, monkeypatch):
    path = _path(entry)
    if not path.exists():
        pytest.skip(f"{path} is absent: run benchmarks/fetch_ifc_corpus.py where GitHub is reachable")
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(tmp_path))  # empty: a first parse
    ifc_module._parse_cached.cache_clear()
    cpu = time.process_time()
    name = entry["name"]
    if name in REFUSED:
        with pytest.raises(IfcImportError, match="has no stage a camera can use") as info:
            ifc_stages(path)
        assert REFUSED[name] in str(info.value) and "\n" not in str(info.value)
    else:
        stages = ifc_stages(path)
        site = load_ifc(path)
        assert site.stage == stages[-1]
        counts = {n: len(site.landmarks(n)) for n in ("slab_corners", "opening_corners", "column_tops")}
        assert max(counts.values()) >= 4, f"default stage {site.stage!r} of {name}: {counts}"
        assert all(z > ifc_module.GROUND_TOL for n in counts for z in site.landmarks(n).xyz[:, 2])
    parse = time.process_time() - cpu
    budget = TARGET_S_PER_3MB * max(1.0, path.stat().st_size / 3e6)
    cached = 0.0
    if name not in REFUSED:  # the next process: from the disk cache, the same landmarks
        ifc_module._parse_cached.cache_clear()
        cpu = time.process_time()
        again = load_ifc(path)
        cached = time.process_time() - cpu
        assert cached <= budget
        for n in counts:
            np.testing.assert_array_equal(again.landmarks(n).xyz, site.landmarks(n).xyz)
        ifc_module._parse_cached.cache_clear()
    if name in TOO_SLOW and parse > budget:
        pytest.xfail(f"{name} parsed in {parse:.1f} s CPU (target {budget:.1f} s): {TOO_SLOW[name]}; the "
                     f"next process loads it from the disk cache in {cached:.2f} s CPU")
    assert parse <= budget, f"{name}: {parse:.1f} s CPU to parse, the target is {budget:.1f} s"
