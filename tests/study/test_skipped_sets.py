"""The study on any building evaluates the landmark sets its stage has and says why it skips the rest."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ifcopenshell")

from localization import Localizer  # noqa: E402
from localization.geometry.camera import PAPER_K  # noqa: E402
from uav_struct_env.study import study as study_cli  # noqa: E402
from uav_struct_env.study.protocol import StudyConfig  # noqa: E402
from uav_struct_env.study.report import results_dict, table1_markdown, table2_markdown  # noqa: E402
from uav_struct_env.study.run import ImageResult  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "site"))
from ifc_sites import messy_site  # noqa: E402


@pytest.fixture(scope="module")
def messy(tmp_path_factory) -> str:
    return str(messy_site().to_ifc(tmp_path_factory.mktemp("messy") / "messy.ifc"))


def _rows(key: str) -> list[ImageResult]:
    loc = Localizer(np.random.default_rng(0).uniform(-5, 5, (8, 3)), PAPER_K)
    est = loc.localize(np.zeros((0, 2)), np.eye(4))
    fields = {f.name: 0 for f in dataclasses.fields(ImageResult)}
    fields.update(method=key, success=False, failure_reason=est.failure_reason, latency_s=0.01,
                  failure_code=est.failure_code.value)
    return [ImageResult(**fields)]


def test_a_stage_without_openings_skips_them_with_the_reason(messy):
    config = StudyConfig(site=messy, stage="L1/slab")
    reasons = config.skip_reasons
    assert reasons["opening_corners"] == ("stage 'L1/slab' exposes 0 opening_corners (at least 4 are "
                                          "needed for a pose)")
    assert "slab_corners" not in reasons
    assert [m.key for m in config.selected_methods][:1] == ["slab_corners"]
    assert "opening_corners" not in [m.key for m in config.selected_methods]


def test_results_and_tables_name_what_was_left_out_and_keep_the_paper_to_its_site(messy):
    config = StudyConfig(site=messy, stage="L1/slab", methods=("slab_corners", "opening_corners"))
    results = results_dict(config, _rows("slab_corners"))
    assert results["skipped"] == {"opening_corners": config.skip_reasons["opening_corners"]}
    assert list(results["methods"]) == ["slab_corners"]
    for table in (table1_markdown(results), table2_markdown(results)):
        assert "Left out: opening_corners -- stage 'L1/slab' exposes 0 opening_corners" in table
    row = next(line for line in table2_markdown(results).splitlines() if line.startswith("| Slab corners"))
    assert "0.185" not in row  # the paper's figures stand beside the paper's building only
    paper = results_dict(StudyConfig(methods=("slab_corners",)), _rows("slab_corners"))
    assert "skipped" not in paper
    assert "0.185 / 0.363" in table2_markdown(paper)


def test_the_cli_notes_each_skip_and_evaluates_the_rest(messy, tmp_path, capsys):
    # the skips do not depend on the image size: a quarter of the paper's width and height
    status = study_cli.main(["--site", messy, "--stage", "L1/slab", "--detector", "projection",
                             "--quick", "--image-size", "320x180", "--out", str(tmp_path / "r"),
                             "--no-progress", "--no-figures"])
    err = capsys.readouterr().err
    assert status == 0
    assert "note: opening_corners left out: stage 'L1/slab' exposes 0 opening_corners" in err
    assert "column_tops left out" not in err  # L1/columns stands on this floor
    results = json.loads((tmp_path / "r" / "results.json").read_text())
    assert "opening_corners" not in results["methods"] and "slab_corners" in results["methods"]
    assert results["methods"]["column_tops"]["total"] == 8
    assert results["config"]["image_size"] == [320, 180]  # the smaller images were the ones rendered
