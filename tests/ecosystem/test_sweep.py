"""``uav-struct sweep``: sites and seeds parsed, runs merged, and the pool and Ray give one answer."""

import dataclasses
import json

import numpy as np
import pytest

from uav_struct_env.errors import ConfigError
from uav_struct_env.site import make_site
from uav_struct_env.study.protocol import StudyConfig
from uav_struct_env.study.report import results_dict
from uav_struct_env.study.run import run_units
from uav_struct_env.study.sweep import (
    _site_file,
    comparable,
    main,
    parse_seeds,
    parse_sites,
    run_sweep,
    sweep_results,
)

# A tiny study: one landmark set, one viewpoint per UAV, small images.
TINY = StudyConfig(methods=("column_tops",), n_viewpoints=1, image_size=(320, 180), renderer="tiny")


def test_sites_and_seeds_expand_and_bad_ones_are_refused_by_name(tmp_path):
    site_file = tmp_path / "b.json"
    site_file.write_text("{}")
    assert parse_sites(f"paper, random:3-5,{site_file}") == (
        "paper", "random:3", "random:4", "random:5", str(site_file)
    )
    assert parse_seeds("0,4-6") == (0, 4, 5, 6)
    with pytest.raises(ConfigError, match=r"a random site range '5-3' is empty: 3 < 5"):
        parse_sites("random:5-3")
    with pytest.raises(ConfigError, match=r"got 'randm:1'"):
        parse_sites("paper,randm:1")
    with pytest.raises(ConfigError, match=r"got 'missing.ifc'"):
        parse_sites("missing.ifc")
    with pytest.raises(ConfigError, match=r"sites must be distinct, got \['random:2'\]"):
        parse_sites("random:0-2,random:2")
    with pytest.raises(ConfigError, match=r"a seed must be N or A-B .* got 'x'"):
        parse_seeds("1,x")
    with pytest.raises(ConfigError, match="seeds must be distinct"):
        parse_seeds("0-2,1")


def test_random_n_is_the_site_the_study_draws_from_seed_n():
    for n in (0, 7):
        mine = make_site(_site_file(f"random:{n}"), stage="columns", marker_size=1.0)
        study = make_site("random", stage="columns", marker_size=1.0, rng=np.random.default_rng(n))
        np.testing.assert_array_equal(mine.landmarks("all").xyz, study.landmarks("all").xyz)
        np.testing.assert_array_equal(mine.landmarks("all").ids, study.landmarks("all").ids)
    assert not np.array_equal(
        make_site(_site_file("random:0"), stage="columns").landmarks("column_tops").xyz,
        make_site(_site_file("random:7"), stage="columns").landmarks("column_tops").xyz,
    )


@pytest.fixture(scope="module")
def pooled(shared_output):
    """Four runs on a pool of two, made once a session however many xdist workers read them."""
    return shared_output("tiny-sweep", lambda _: run_sweep(TINY, ["paper", "random:1"], [0, 1], workers=2))[1]


@pytest.mark.slow  # four studies on a process pool: a long library run
def test_the_pool_merges_runs_that_equal_the_study_run_alone(pooled):
    assert [(r.site, r.seed) for r in pooled] == [
        ("paper", 0), ("paper", 1), ("random:1", 0), ("random:1", 1)
    ]
    results = sweep_results(TINY, pooled)
    # Each run is the study itself: its summary equals a study run with that site and seed.
    alone, _ = run_units(dataclasses.replace(TINY, seed=1))
    study = results_dict(TINY, alone)["methods"]["column_tops"]
    run = results["runs"][1]
    assert (run["site"], run["seed"]) == ("paper", 1)
    for key in ("successful", "total", "translation_error_m", "rotation_error_deg"):
        assert run["methods"]["column_tops"][key] == study[key], key
    # The pooled entry is over all 4 runs x 4 UAVs x 1 viewpoint, and the seeds differ.
    pooled_entry = results["methods"]["column_tops"]
    assert pooled_entry["total"] == 16 and pooled_entry["runs"] == 4
    assert results["runs"][0]["methods"] != results["runs"][1]["methods"]
    spread = pooled_entry["run_translation_median_m"]
    assert spread["min"] <= spread["median"] <= spread["max"]


@pytest.mark.slow
def test_ray_gives_the_pools_results(pooled):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'uav-struct-env[ray]')")
    on_ray = run_sweep(TINY, ["paper", "random:1"], [0, 1], workers=2, ray="local")
    assert [(r.site, r.seed) for r in on_ray] == [(r.site, r.seed) for r in pooled]
    a, b = comparable(sweep_results(TINY, pooled)), comparable(sweep_results(TINY, on_ray))
    assert a == b
    assert _rows(pooled) == _rows(on_ray) and len(_rows(pooled)) == 16


def _rows(runs):
    """Every per-image row but its wall-clock latency, NaN as None (so == compares them)."""
    out = []
    for run in runs:
        for row in run.rows:
            d = {k: (None if isinstance(v, float) and np.isnan(v) else v)
                 for k, v in dataclasses.asdict(row).items() if k != "latency_s"}
            out.append((run.site, run.seed, d))
    return out


def test_the_command_writes_one_table_and_refuses_study_only_options(tmp_path, capsys):
    out = tmp_path / "sw"
    # TINY's small images (a sixteenth of the paper's pixels): what is checked does not depend on them
    size = "{}x{}".format(*TINY.image_size)
    code = main(["--sites", "random:2", "--seeds", "3", "--detector", "projection", "--quick",
                 "--image-size", size, "--no-progress", "--out", str(out), "--association", "paper",
                 "--methods", "column_tops"])
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    assert results["config"]["sites"] == ["random:2"] and results["config"]["seeds"] == [3]
    assert results["config"]["association"] == "paper" and results["config"]["backend"] == "process pool"
    table = (out / "table.md").read_text()
    assert "| Column tops | 1 |" in table and table in capsys.readouterr().out
    assert list(results["methods"]) == ["column_tops"] and "Slab corners" not in table  # --methods
    # each file says how it was made: the study's settings line over the sweep's sites and seeds
    made, header, first = (out / "per_image.csv").read_text().splitlines()[:3]
    line = results["settings"]
    assert made == f"# Settings: {line}" and table.startswith(f"Settings: {line}\n")
    assert "site random:2" in made and "seed 3" in made and "paper association" in made
    assert "320x180 px" in made  # the small images were the ones rendered
    assert header.startswith("site,seed,method,uav,viewpoint")
    assert first.startswith("random:2,3,")  # each row names the run it came from
    assert main(["--sites", "paper", "--site", "paper", "--out", str(tmp_path / "x")]) == 2
    assert "--site is not a sweep option" in capsys.readouterr().err
    assert main(["--sites", "random:9-1", "--out", str(tmp_path / "y")]) == 2
    assert "is empty: 1 < 9" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_ray_without_ray_installed_is_refused_before_anything_runs(tmp_path, capsys):
    try:
        import ray  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("Ray is installed here")
    assert main(["--sites", "paper", "--ray", "--out", str(tmp_path / "r")]) == 2
    assert "--ray needs Ray: pip install 'uav-struct-env[ray]'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
