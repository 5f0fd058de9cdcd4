"""results.json statistics come from localization.metrics; failures are grouped by code."""

import dataclasses
import json

import numpy as np
import pytest

from localization import FailureCode, Localizer
from localization.geometry.camera import PAPER_K
from uav_struct_env.errors import ConfigError
from uav_struct_env.study.protocol import METHODS, StudyConfig
from uav_struct_env.study.report import (
    results_dict,
    settings_line,
    summarize,
    table2_markdown,
    write_results_json,
)
from uav_struct_env.study.run import ImageResult, bound_pixel_sigma

NAN = float("nan")


def _row(est, k, t_err=NAN, r_err=NAN):
    fields = {f.name: 0 for f in dataclasses.fields(ImageResult)}
    fields.update(
        method="column_tops",
        uav=k % 4,
        viewpoint=k // 4,
        success=bool(est.success),
        failure_reason=est.failure_reason or "",
        failure_code=est.failure_code.value if est.failure_code else "",
        translation_error_m=t_err,
        rotation_error_deg=r_err,
        crb_translation_m=0.1,
        crb_rotation_deg=0.2,
        latency_s=0.01,
    )
    return ImageResult(**fields)


def test_failures_group_by_code_and_nan_is_null(tmp_path):
    loc = Localizer(np.random.default_rng(0).uniform(-5, 5, (8, 3)), PAPER_K)
    # three failures of one cause with three different messages, one success-like row
    fails = [loc.localize(np.zeros((n, 2)), np.eye(4)) for n in (0, 1, 2)]
    assert {f.failure_code for f in fails} == {FailureCode.TOO_FEW_DETECTIONS}
    assert len({f.failure_reason for f in fails}) == 3
    ok = dataclasses.replace(fails[0], success=True, failure_reason=None, failure_code=None)
    rows = [_row(f, k) for k, f in enumerate(fails)] + [_row(ok, 3, 0.2, 0.5)]
    method = next(m for m in METHODS if m.key == "column_tops")
    entry = summarize(method, rows)
    assert entry["failures"] == {
        "too_few_detections": {"count": 3, "example": "too few detections: no detections, need 4"}
    }
    assert entry["successful"] == 1 and entry["total"] == 4
    assert entry["translation_error_m"] == {"median": 0.2, "p90": pytest.approx(0.2)}
    assert entry["recall_at"] == {"0.25m_1.0deg": 0.25, "0.5m_2.0deg": 0.25, "1.0m_5.0deg": 0.25}
    assert entry["median_error_over_bound"] == pytest.approx(2.0)
    assert np.isnan(entry["association_f1"])  # nothing assigned, nothing true: undefined
    results = results_dict(StudyConfig(methods=("column_tops",)), rows)
    write_results_json(tmp_path / "results.json", results)
    written = json.loads((tmp_path / "results.json").read_text())["methods"]["column_tops"]
    assert written["association_f1"] is None and written["association_precision"] is None
    assert written["failures"]["too_few_detections"]["count"] == 3


def _method(key):
    return next(m for m in METHODS if m.key == key)


def test_learned_detector_bound_uses_its_measured_pixel_error():
    """The bound is at the run's own detector noise: measured for the learned detector (RMS of
    the true detections' pixel errors, per axis), configured for the projection detector."""
    base = _row(Localizer(np.eye(3) * 5, PAPER_K).localize(np.zeros((0, 2)), np.eye(4)), 0)
    rows = [dataclasses.replace(base, n_true_detections=n, pixel_error_rms_px=e)
            for n, e in ((4, 0.3), (12, 0.5), (0, NAN))]
    expected = np.sqrt((4 * 0.3**2 + 12 * 0.5**2) / 16 / 2)
    learned = StudyConfig(detector="learned")
    assert bound_pixel_sigma(learned, _method("column_tops"), rows) == pytest.approx(expected)
    assert bound_pixel_sigma(StudyConfig(pixel_sigma=2.0), _method("column_tops"), rows) == 2.0
    assert np.isnan(bound_pixel_sigma(learned, _method("aruco_1.0m"), rows))


def _results(**config):
    rows = [_row(Localizer(np.eye(3) * 5, PAPER_K).localize(np.zeros((0, 2)), np.eye(4)), k)
            for k in range(8)]
    return results_dict(StudyConfig(methods=("column_tops",), **config), rows)


def test_settings_line_names_every_setting_and_the_version():
    line = settings_line(_results(detector="learned", miss_rate=0.1, false_positives=1.0, seed=3,
                                  noise="gnss_ins", imaging="camera", n_viewpoints=2))
    for part in ("uav-struct-env 0.1.0", "site paper", "landmarks_v1.onnx + landmarks_v1_refiner.onnx",
                 "robust association", "gnss_ins prior", "pixel sigma 1.0 px", "miss rate 0.1",
                 "false positives 1.0/image", "camera imaging", "seed 3", "QUICK"):
        assert part in line, part
    assert "site paper, as designed" in line
    assert "site paper, as built aci117 x 4" in settings_line(_results(as_built="aci117", as_built_scale=4))
    assert "camera imaging, fixed lighting" in line
    assert "random lighting" in settings_line(_results(lighting="random"))
    assert "as designed, site activity none" in line
    assert "as designed, site activity busy" in settings_line(_results(activity="busy"))
    with pytest.raises(ConfigError, match=r"activity must be one of \('none', 'light', 'busy'\), got 'rush'"):
        StudyConfig(activity="rush")
    assert "paper camera, camera imaging" in line
    assert "mavic2pro camera, ideal imaging" in settings_line(_results(camera="mavic2pro"))
    assert _results(camera="mavic2pro")["config"]["camera"] == "mavic2pro"
    with pytest.raises(ConfigError, match=r"camera must be one of \('paper', 'mavic2pro'\), got 'gopro'"):
        StudyConfig(camera="gopro")
    with pytest.raises(ConfigError, match=r"lighting must be one of \('fixed', 'random'\), got 'dusk'"):
        StudyConfig(lighting="dusk")
    results = _results()
    results["config"]["new_setting"] = True  # a setting added later is listed all the same
    assert "new_setting True" in settings_line(results)


def test_table2_opens_with_the_settings_and_sets_counts_against_the_paper_only_when_alike():
    quick = table2_markdown(_results(n_viewpoints=2))
    assert quick.startswith("Settings: uav-struct-env")
    assert "(paper 40/40)" not in quick and "left out" in quick
    full = _results()
    full["methods"]["column_tops"]["total"] = 40
    assert "(paper 40/40)" in table2_markdown(full)
