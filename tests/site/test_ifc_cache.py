"""The IFC parse cache on disk (uav_struct_env.site.ifc_cache): a second process reads the parse back."""

from __future__ import annotations

import logging
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest

ifcopenshell = pytest.importorskip("ifcopenshell")

from ifc_sites import DUPLEX, messy_site  # noqa: E402

from uav_struct_env.site import ifc as ifc_module  # noqa: E402
from uav_struct_env.site import ifc_cache, ifc_report, ifc_stages, load_ifc, write_ifc  # noqa: E402


def _fresh_process():
    """What a new process has: no in-process parse."""
    ifc_module._parse_cached.cache_clear()


def _no_parse(*args, **kwargs):
    raise AssertionError("the file was parsed, not read from the cache")


def _same_site(a, b):
    assert [e.guid for e in a.elements] == [e.guid for e in b.elements]
    assert [e.name for e in a.elements] == [e.name for e in b.elements]
    for ea, eb in zip(a.elements, b.elements, strict=True):
        np.testing.assert_array_equal(ea.outline, eb.outline)
        np.testing.assert_array_equal(ea.mesh.vertices, eb.mesh.vertices)
        np.testing.assert_array_equal(ea.mesh.faces, eb.mesh.faces)
    for name in ("slab_corners", "opening_corners", "column_tops"):
        np.testing.assert_array_equal(a.landmarks(name).ids, b.landmarks(name).ids)
        np.testing.assert_array_equal(a.landmarks(name).xyz, b.landmarks(name).xyz)
        assert a.landmarks(name).labels == b.landmarks(name).labels


@pytest.fixture(scope="module")
def seeded(tmp_path_factory):
    """The duplex parsed once into a cache folder of this module: (its entry, the site, its stages)."""
    root = tmp_path_factory.mktemp("seeded_ifc_cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(ifc_cache.IFC_CACHE_ENV, str(root))
        _fresh_process()
        site, stages = load_ifc(DUPLEX, stage="Level 2/slab"), ifc_stages(DUPLEX)
        _fresh_process()
    (entry,) = root.glob("*.pickle")
    return entry, site, stages


@pytest.fixture
def cache(tmp_path, monkeypatch, seeded):
    """A cache folder holding the duplex's entry, as the first process left it; no in-process parse."""
    root = tmp_path / "cache"
    root.mkdir()
    shutil.copyfile(seeded[0], root / seeded[0].name)
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(root))
    _fresh_process()
    yield root
    _fresh_process()


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Path:
    """A small synthetic IFC file (fast to parse)."""
    return write_ifc(messy_site(), tmp_path_factory.mktemp("small") / "small.ifc")


def test_the_entry_is_keyed_by_the_content_and_the_importer_version(seeded):
    entry = seeded[0]
    assert entry.name.startswith(f"{ifc_module.file_sha256(DUPLEX)}-{ifc_cache.importer_version()}-")
    assert ifc_cache.cache_path(ifc_module.file_sha256(DUPLEX), np.eye(4).tobytes(), entry.parent) == entry


def test_the_next_process_reads_the_parse_back_unchanged(cache, seeded, monkeypatch):
    _, first, stages = seeded
    monkeypatch.setattr(ifc_module, "_parse", _no_parse)
    again = load_ifc(DUPLEX, stage="Level 2/slab")
    _same_site(first, again)
    assert ifc_stages(DUPLEX) == stages
    assert again.source["report"].kept == first.source["report"].kept
    assert again.source["report"].dropped == first.source["report"].dropped


def test_a_copy_elsewhere_is_served_under_its_own_path(cache, tmp_path, monkeypatch):
    copy = tmp_path / "elsewhere" / "copy.ifc"
    copy.parent.mkdir()
    shutil.copyfile(DUPLEX, copy)
    monkeypatch.setattr(ifc_module, "_parse", _no_parse)
    site = load_ifc(copy)
    assert site.source["path"] == str(copy.resolve()) == site.source["report"].path
    assert ifc_report(copy).path == str(copy.resolve())


def test_another_transform_is_another_entry(tmp_path, monkeypatch, small):
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(tmp_path))
    _fresh_process()
    shifted = np.eye(4)
    shifted[:3, 3] = (10.0, -5.0, 0.0)
    base, moved = load_ifc(small), load_ifc(small, transform=shifted)
    assert len(list(tmp_path.glob("*.pickle"))) == 2
    offset = moved.landmarks("slab_corners").xyz - base.landmarks("slab_corners").xyz
    np.testing.assert_allclose(offset, np.tile([10.0, -5.0, 0.0], (len(offset), 1)), atol=1e-9)
    _fresh_process()


def test_off_disables_it(tmp_path, monkeypatch, small):
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(tmp_path))
    _fresh_process()
    load_ifc(small)
    assert len(list(tmp_path.glob("*.pickle"))) == 1
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, "off")
    assert ifc_cache.cache_root() is None and ifc_cache.cache_path("0" * 64, b"") is None
    _fresh_process()
    calls = []
    parse = ifc_module._parse
    monkeypatch.setattr(ifc_module, "_parse", lambda *a: calls.append(1) or parse(*a))
    load_ifc(small)  # the entry in the folder is not read
    assert calls == [1]
    _fresh_process()


def test_the_default_folder_is_beside_the_adapted_weights(monkeypatch, tmp_path):
    monkeypatch.delenv(ifc_cache.IFC_CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert ifc_cache.cache_root() == tmp_path / "uav-struct" / "ifc"


def test_a_damaged_entry_is_parsed_again_and_overwritten(tmp_path, monkeypatch, small, caplog):
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(tmp_path))
    _fresh_process()
    first = load_ifc(small)
    (entry,) = tmp_path.glob("*.pickle")
    entry.write_bytes(b"not a pickle")
    _fresh_process()
    with caplog.at_level(logging.WARNING, logger="uav_struct_env.site.ifc_cache"):
        again = load_ifc(small)
    assert "cannot be read" in caplog.text and "parsing the file again" in caplog.text
    _same_site(first, again)
    assert entry.stat().st_size > 1000  # rewritten
    _fresh_process()


def test_a_folder_that_cannot_be_written_is_warned_of_and_the_import_goes_on(tmp_path, monkeypatch, small,
                                                                              caplog):
    blocker = tmp_path / "a file, not a folder"
    blocker.write_text("x")
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(blocker / "ifc"))
    _fresh_process()
    with caplog.at_level(logging.WARNING, logger="uav_struct_env.site.ifc_cache"):
        site = load_ifc(small)
    assert "cannot write" in caplog.text and len(site.landmarks("slab_corners")) > 0
    _fresh_process()


def test_a_process_that_finds_the_entry_being_parsed_waits_for_it(tmp_path, monkeypatch, small):
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(tmp_path / "made"))
    _fresh_process()
    first = load_ifc(small)
    (made,) = (tmp_path / "made").glob("*.pickle")
    monkeypatch.setenv(ifc_cache.IFC_CACHE_ENV, str(tmp_path / "empty"))
    _fresh_process()
    entry = tmp_path / "empty" / made.name
    monkeypatch.setattr(ifc_module, "_parse", _no_parse)
    out: dict = {}

    def load():
        try:
            out["site"] = load_ifc(small)
        except Exception as exc:  # reported below
            out["error"] = exc

    with ifc_cache.entry_lock(entry):  # another process is parsing the file
        waiter = threading.Thread(target=load)
        waiter.start()
        waiter.join(0.5)
        assert waiter.is_alive() and not entry.exists()
        shutil.copyfile(made, entry)  # ... and writes its entry
    waiter.join(60)
    assert "error" not in out, out.get("error")
    _same_site(first, out["site"])
    _fresh_process()
