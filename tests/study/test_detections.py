"""uav_struct_env.study.detections: what each detection of a localization was."""

import numpy as np
import pytest

from uav_struct_env.study.detections import detection_rows


def test_rows_name_the_assigned_the_true_and_the_nearest_landmark():
    truth = {"ids": np.array([10, 11, 12]), "uv": np.array([[100.0, 100.0], [200.0, 100.0], [300.0, 100.0]]),
             "visible": np.array([True, False, True])}
    uv = np.array([[100.5, 100.0], [204.0, 100.0], [600.0, 400.0]])  # a corner, a hidden one, clutter
    rows = detection_rows("slab_corners", 2, 7, uv, np.array([0.9, 0.3, 0.1]), np.array([10, -1, -1]),
                          np.array([0, 1, -1]), np.array([10, 11, 12]), truth)
    assert [(r.assigned_id, r.true_id, r.nearest_id, r.nearest_visible) for r in rows] == [
        (10, 10, 10, True), (11, -1, 11, False), (-1, -1, 12, True)]
    assert rows[1].nearest_px == pytest.approx(4.0) and rows[1].score == pytest.approx(0.3)
    assert (rows[0].method, rows[0].uav, rows[0].viewpoint, rows[2].detection) == ("slab_corners", 2, 7, 2)
    plain = detection_rows("slab_corners", 0, 0, uv[:1], None, None, np.array([-1]), np.array([10, 11, 12]),
                           truth)
    assert np.isnan(plain[0].score) and plain[0].true_id == -1 and plain[0].assigned_id == -1
