"""uav-struct render on a building whose floor has no columns stage says it rendered one stage."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("ifcopenshell")

sys.path.insert(0, str(Path(__file__).resolve().parent / "site"))
from ifc_sites import messy_site  # noqa: E402

from uav_struct_env.demo import main as render_main  # noqa: E402


def test_both_stages_on_a_floor_without_columns_renders_one_and_says_so(tmp_path, capsys):
    ifc = messy_site().to_ifc(tmp_path / "messy.ifc")  # its last floor, L2, has no columns stage
    # 160 x 90 views: which stages render does not depend on the size
    status = render_main(["--site", str(ifc), "--out", str(tmp_path / "r"), "--renderer", "tiny",
                          "--image-size", "160x90"])
    captured = capsys.readouterr()
    assert status == 0
    note = "note: the floor of stage 'L2/slab' has no columns stage; rendered that stage alone"
    assert note in captured.err
    pngs = sorted(p.name for p in (tmp_path / "r").glob("*.png"))
    assert pngs and all(name.startswith("L2_slab_") for name in pngs)
