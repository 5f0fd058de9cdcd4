"""Fixtures for the localization tests: the paper's camera and building landmarks.

The seeded ``rng`` fixture lives in tests/conftest.py.

The landmark coordinates come from ``uav_struct_env.site.paper_site`` when it imports, otherwise
from the fixed numbers below (the same building); the localization package itself never imports
the environment.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from localization.geometry.camera import PAPER_K

_GRID_X = (0.0, 4.0, 8.0)
_GRID_Y = (0.0, 4.0, 7.0, 11.0)
_FALLBACK = {
    "slab_corners": np.array(
        [(-0.3, -0.3, 3.5), (8.3, -0.3, 3.5), (8.3, 11.3, 3.5), (-0.3, 11.3, 3.5)]
    ),
    "opening_corners": np.array(
        [(0.2, 4.2, 3.5), (3.8, 4.2, 3.5), (3.8, 6.8, 3.5), (0.2, 6.8, 3.5)]
    ),
    "column_tops": np.array([(x, y, 6.75) for y in _GRID_Y for x in _GRID_X]),
}
_FALLBACK["all"] = np.vstack(
    [_FALLBACK[k] for k in ("slab_corners", "opening_corners", "column_tops")]
)
CENTER = np.array([4.0, 5.5, 3.375])
DATA = Path(__file__).parents[1] / "data"


@pytest.fixture(scope="session")
def association_case():
    """``association_case(name)``: a recorded association problem ``tests/data/<name>`` (its lists
    as arrays)."""

    def load(name: str) -> dict:
        c = json.loads((DATA / name).read_text())
        return {k: np.asarray(v) if isinstance(v, list) else v for k, v in c.items()}

    return load


def building_landmarks() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (ids, xyz) of the paper building at stage "columns"."""
    try:
        from uav_struct_env.site import paper_site
    except Exception:  # the site module is another package; fall back to fixed numbers
        return {k: (np.arange(len(v)) + 100 * i, v) for i, (k, v) in enumerate(_FALLBACK.items())}
    site = paper_site(stage="columns", marker_size=1.0)
    return {k: (site.landmarks(k).ids, site.landmarks(k).xyz) for k in _FALLBACK}


@pytest.fixture(scope="session")
def K() -> np.ndarray:
    return PAPER_K.copy()


@pytest.fixture(scope="session")
def building() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return building_landmarks()


@pytest.fixture(scope="session")
def center() -> np.ndarray:
    return CENTER.copy()
