"""The named weight sets of the learned detector: names, aliases, the files they ship."""

from __future__ import annotations

import re

import pytest

from localization.detect.learned import DEFAULT_MODEL
from localization.detect.refiner import DEFAULT_REFINER
from localization.detect.weights import (
    DEFAULT_WEIGHTS,
    MODELS_DIR,
    WEIGHT_ALIASES,
    WEIGHT_NAMES,
    WEIGHT_SETS,
    weight_set,
)


def test_names_resolve_to_their_pair_of_files():
    assert WEIGHT_NAMES == ("landmarks_v1", "landmarks_active_v4", "active")
    assert weight_set() == weight_set(DEFAULT_WEIGHTS) == weight_set("landmarks_v1")
    assert (weight_set().model, weight_set().refiner) == (DEFAULT_MODEL, DEFAULT_REFINER)
    active = weight_set("active")
    assert active is weight_set("landmarks_active_v4") and WEIGHT_ALIASES["active"] == active.name
    assert (active.model.name, active.refiner.name) == ("landmarks_active_v2.onnx",
                                                        "landmarks_active_v4_refiner.onnx")


def test_the_package_ships_exactly_the_named_sets_files():
    """Superseded weights leave the package: every ONNX file there belongs to a named set."""
    named = {p for s in WEIGHT_SETS.values() for p in (s.model, s.refiner)}
    assert all(p.is_file() for p in named)
    assert set(MODELS_DIR.glob("*.onnx")) == named


@pytest.mark.parametrize("bad", ["landmarks_active_v3", "Active", "", "default", 3])
def test_an_unknown_name_is_refused_with_the_known_ones(bad):
    with pytest.raises(ValueError, match=r"weights must be one of \('landmarks_v1', 'landmarks_active_v4', "
                                         r"'active'\), got " + re.escape(repr(bad))):
        weight_set(bad)
