"""Rendering fixtures: session-wide SiteWorlds (the site loads once per stage and backend).

"""

from __future__ import annotations

from collections.abc import Iterator

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


class PaperWorlds:
    """``paper_world(stage, backend)``: the paper site, loaded once per stage and backend.

    All stay open for the session (several EGL clients coexist: see
    ``uav_struct_env.sim.client``).
    """

    def __init__(self) -> None:
        self.worlds: dict[tuple[str, str], SiteWorld] = {}

    def __call__(self, stage: str, backend: str) -> SiteWorld:
        key = (stage, backend)
        if key not in self.worlds:
            self.worlds[key] = SiteWorld(
                paper_site(stage), renderer=backend, rng=np.random.default_rng(7)
            )
        return self.worlds[key]

    def close(self) -> None:
        for world in self.worlds.values():
            world.close()


@pytest.fixture(scope="session")
def paper_world() -> Iterator[PaperWorlds]:
    """The session's :class:`PaperWorlds`."""
    worlds = PaperWorlds()
    yield worlds
    worlds.close()
