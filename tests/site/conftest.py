"""The site tests parse into a parse cache of their own (``UAV_STRUCT_IFC_CACHE``), not the user's."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _own_ifc_parse_cache(tmp_path_factory):
    from uav_struct_env.site.ifc_cache import IFC_CACHE_ENV

    before = os.environ.get(IFC_CACHE_ENV)
    os.environ[IFC_CACHE_ENV] = str(tmp_path_factory.mktemp("ifc_parse_cache"))
    yield
    if before is None:
        os.environ.pop(IFC_CACHE_ENV, None)
    else:
        os.environ[IFC_CACHE_ENV] = before
