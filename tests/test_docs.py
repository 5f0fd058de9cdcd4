"""The documentation site builds in strict mode and matches the code it documents."""

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import uav_struct_env
from uav_struct_env.envs.settings import NESTED, UndocumentedSettingError, settings, settings_markdown
from uav_struct_env.study.protocol import METHODS, StudyConfig
from uav_struct_env.study.report import results_dict
from uav_struct_env.study.run import ImageResult

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def _documented(page: str, keys) -> list[str]:
    text = (DOCS / page).read_text()
    return [k for k in keys if f"`{k}`" not in text]


def test_every_env_setting_is_documented_in_the_generated_table():
    table = settings_markdown()
    for cls in (uav_struct_env.envs.EnvConfig, *NESTED.values()):
        for f in dataclasses.fields(cls):
            assert f"| `{f.name}` |" in table, f"{cls.__name__}.{f.name}"
    assert "| `max_cycles` | `int` | `100` | `200` |" in table  # default, then the train preset


def test_a_new_setting_without_a_meaning_fails():
    @dataclasses.dataclass
    class Config:
        """Settings.

        Attributes:
            size: documented.
            gone: a field that no longer exists.
        """

        size: int = 1
        added: float = 0.0

    with pytest.raises(UndocumentedSettingError, match=r"undocumented \[.added.\].*fields \[.gone.\]"):
        settings(Config)


def test_environment_page_names_every_observation_and_info_key():
    env = uav_struct_env.parallel_env(image_size=(64, 36), observe_depth=True, renderer="tiny")
    try:
        obs, infos = env.reset(seed=0)
    finally:
        env.close()
    info = infos["uav_0"]
    landmark_keys = next(iter(info["landmarks"].values())).keys()
    assert _documented("environment.md", [*obs["uav_0"], *info, *landmark_keys]) == []


def test_wrapper_page_names_every_key_it_adds():
    from uav_struct_env.wrappers import LAYOUT_COMPONENTS, make_localization_env

    wenv = make_localization_env("column_tops", env_overrides={"image_size": (64, 36), "renderer": "tiny"})
    try:
        obs, infos = wenv.reset(seed=0)
    finally:
        wenv.close()
    added = set(obs["uav_0"]) - {"image", "gnss", "attitude"}
    keys = [*added, *infos["uav_0"]["localization"], *LAYOUT_COMPONENTS[:3]]
    assert _documented("wrapper.md", keys) == []


def test_study_page_names_every_output_column_and_key():
    row = ImageResult(**{f.name: 0 for f in dataclasses.fields(ImageResult)} | {"method": "column_tops"})
    results = results_dict(StudyConfig(methods=("column_tops",)), [row])
    keys = [
        *(f.name for f in dataclasses.fields(ImageResult)),
        *results,
        *results["software"],
        *results["methods"]["column_tops"],
        *(m.key for m in METHODS),
    ]
    missing = [k for k in keys if k not in (DOCS / "study.md").read_text()]
    assert missing == []


def test_license_and_citation_match_the_package():
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    assert "the uav-struct-env developers" in (ROOT / "LICENSE").read_text()
    cff = (ROOT / "CITATION.cff").read_text()
    assert re.search(r"^version: (\S+)$", cff, flags=re.M).group(1) == uav_struct_env.__version__
    title = "Structural Features as Fiducial Marker Replacements for Multi-UAV Camera Pose"
    assert title in cff and title in (DOCS / "citation.md").read_text()


@pytest.fixture(scope="module")
def benchmark(load_script):
    """``benchmark(name)``: ``benchmarks/<name>.py`` as a fresh module."""
    return lambda name: load_script(ROOT / "benchmarks" / f"{name}.py")


def test_model_card_study_table_is_generated_not_hand_written(benchmark):
    card = benchmark("model_card_study")
    text = card.CARD.read_text()
    block = text[text.index(card.BEGIN):text.index(card.END)]
    assert block.count("| ideal |") == 3 and block.count("| camera |") == 3
    assert benchmark("generated").replace_block(text, card.COMMAND, block + card.END) == text


@pytest.mark.slow
def test_model_card_study_table_matches_a_fresh_run(benchmark):
    assert benchmark("model_card_study").main(check=True) == 0


def test_docs_site_builds_in_strict_mode(tmp_path):
    pytest.importorskip("mkdocs", reason="the docs extra is not installed (pip install -e '.[docs]')")
    pytest.importorskip("mkdocstrings", reason="the docs extra is not installed (pip install -e '.[docs]')")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    page = (tmp_path / "site" / "environment" / "index.html").read_text()
    assert "start_yaw_jitter" in page and "generated: env-settings" not in page
    assert np.all([(tmp_path / "site" / p / "index.html").is_file() for p in ("model-card", "study")])
