"""Rendering fixtures: session-wide SiteWorlds (the site loads once per stage and backend)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from uav_struct_env.errors import RendererUnavailableError
from uav_struct_env.sim.client import RenderClient
from uav_struct_env.sim.world import SiteWorld
from uav_struct_env.site import paper_site

_EGL: list[bool] = []


def egl_available() -> bool:
    """Whether the EGL plugin starts here (checked once)."""
    if not _EGL:
        try:
            RenderClient("egl").close()
            _EGL.append(True)
        except RendererUnavailableError:
            _EGL.append(False)
    return _EGL[0]


@pytest.fixture(scope="session")
def egl_ok() -> bool:
    """Whether the EGL backend starts on this machine."""
    return egl_available()


@pytest.fixture(params=["tiny", "egl"])
def backend(request: pytest.FixtureRequest) -> str:
    """Each rendering backend in turn (EGL skipped where it cannot start)."""
    if request.param == "egl" and not egl_available():
        pytest.skip("EGL rendering is unavailable on this machine")
    return request.param


@pytest.fixture(scope="session")
def paper_world() -> Iterator[Callable[[str, str], SiteWorld]]:
    """``paper_world(stage, backend)``: the paper site loaded once per session and backend."""
    worlds: dict[tuple[str, str], SiteWorld] = {}

    def get(stage: str, backend: str) -> SiteWorld:
        if (stage, backend) not in worlds:
            worlds[stage, backend] = SiteWorld(
                paper_site(stage), renderer=backend, rng=np.random.default_rng(7)
            )
        return worlds[stage, backend]

    yield get
    for world in worlds.values():
        world.close()
