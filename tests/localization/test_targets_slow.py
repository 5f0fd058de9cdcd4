"""Issue 4, item 7, on the benchmark protocol at full size (slow: run with ``pytest -m slow``)."""

import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
DESIGN_CRB_POSITION = {"slab_corners": 0.14, "opening_corners": 0.55, "column_tops": 0.11}


@pytest.fixture(scope="module")
def results(load_script):
    pytest.importorskip("uav_struct_env.site")
    bench = load_script(ROOT / "benchmarks" / "localizer.py")
    return bench.main(images=200, aruco_images=0, seed=0)["structural"]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(DESIGN_CRB_POSITION))
def test_clean_median_within_1p2_of_design_bound(results, name):
    for mode in ("paper", "robust"):
        med = results[f"{name}/clean/{mode}"]["summary"]["translation_error_m"]["median"]
        assert med <= 1.2 * DESIGN_CRB_POSITION[name], (mode, med)


@pytest.mark.slow
def test_robust_column_tops_with_misses_and_clutter(results):
    robust = results["column_tops/miss10+fp1/robust"]
    paper = results["column_tops/miss10+fp1/paper"]
    assert robust["summary"]["translation_error_m"]["p90"] < 0.4
    assert robust["association"]["f1"] >= 0.98
    assert (
        paper["summary"]["translation_error_m"]["p90"] >= 0.4 or paper["association"]["f1"] < 0.98
    )


@pytest.mark.slow
def test_latency(results):
    for key, r in results.items():
        limit = 0.005 if key.endswith("/paper") else 0.050
        assert r["latency_cpu_s"]["median"] < limit, key
