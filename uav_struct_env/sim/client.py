"""One pybullet client and its rendering backend: TinyRenderer ("tiny") or the EGL plugin ("egl").

A :class:`RenderClient` owns a ``p.connect(p.DIRECT)`` client (never the module-level default
client). Once pybullet's ``eglRenderer`` plugin is loaded on a client, ``getCameraImage`` goes
through EGL whatever renderer flag is passed, so the backend is chosen when the client is made.

Both backends are calibrated to the exact-K projection of :mod:`uav_struct_env.sim.camera`
(pixel centres at integer ``(u, v)``); their quirks are compensated here, in one place, and
measured by ``tests/sim/test_projection.py``:

* **TinyRenderer** rasterizes at integer screen coordinates, i.e. at pixel *corners* rather than
  centres: geometry lands ``(+0.5, -0.5)`` px from where ``K`` puts it (measured: 0.49-0.51 px at
  1280x720, 640x360 and 320x180). We render with the principal point moved by
  ``(-0.5, +0.5)`` px (:data:`TINY_PIXEL_SHIFT`), which cancels it exactly.
* **EGL** renders into a fixed 1024 x 768 off-screen surface (``START_WIDTH``/``START_HEIGHT`` in
  pybullet's ``eglRendererVisualShapeConverter.cpp``) and *nearest-neighbour resamples* larger
  requests to the requested size: at 1280 x 720 it renders 1024 columns and stretches them
  (measured: a +0.37 px mean shift and lost resolution). We split larger images into tiles of at
  most 1024 x 768, each rendered with the same ``K`` shifted by the tile origin, and stitch them:
  exact, and at the same cost (two 640 x 720 tiles take as long as one stretched 1280 x 720).

**Several EGL clients in one process.** The plugin makes its EGL context current once, when it
starts, and never again: with two EGL clients alive, every GL call (uploads at shape creation,
rendering, and the clean-up at disconnect) goes to whichever context was made current last.
Measured with pybullet 3.2.7: one client's shapes appear in the other's images (right positions,
wrong sizes), and disconnecting one client while another's context is current deletes that
other client's GL objects (its images go blank) or crashes the process. We therefore record
each client's EGL display, surface and context (``eglGetCurrent*`` through ctypes, right after
the plugin starts) and make them current (:meth:`RenderClient.activate`) before every pybullet
call that may touch GL: shape loading, rendering, body changes and disconnect. With that, any
number of EGL clients coexist and each renders exactly what a fresh process renders (tested).
If libEGL cannot be reached through ctypes, at most one EGL client is allowed per process and a
second raises :class:`RendererUnavailableError` (``"auto"`` then falls back to TinyRenderer).

**The first EGL frames.** A client's first two ``getCameraImage`` calls through the plugin differ
from every later render of the same request (measured with pybullet 3.2.7 and Mesa llvmpipe: 200-1,000
pixels of six random 1280 x 720 views of the paper site, one call per tile, so the first frame;
about 20 pixels of a 320 x 180 view, the first two frames; later renders agree exactly). Which
frame of a world came first depends on how the work is split (the study's ``--workers``), so an
EGL client renders its first request :data:`EGL_WARMUP_RENDERS` times and discards them
(:meth:`RenderClient.render`; ``tests/sim/test_client.py``).

pybullet prints "pybullet build time: ..." on the C-level stderr when it is imported, and the EGL
plugin its device choice (stderr), OpenGL banner and per-frame chatter (stdout). None of it may
reach a user's terminal between progress bars: pybullet is imported here, once, with file
descriptors 1 and 2 pointed at ``/dev/null`` (the other ``sim`` modules take ``pybullet`` from
this module), and the plugin's calls run the same way (:func:`quiet_c_output`).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import pkgutil
import sys
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from uav_struct_env.errors import ConfigError, RendererUnavailableError
from uav_struct_env.sim.camera import Camera, projection_matrix

__all__ = [
    "BACKENDS",
    "EGL_MAX_TILE",
    "EGL_WARMUP_RENDERS",
    "RENDERERS",
    "TINY_PIXEL_SHIFT",
    "RawImage",
    "RenderClient",
    "egl_plugin_path",
    "quiet_c_output",
    "resolve_renderer",
]

BACKENDS = ("tiny", "egl")
RENDERERS = ("auto", *BACKENDS)

#: Where TinyRenderer draws geometry relative to the exact-K pixel position, (du, dv) in pixels.
TINY_PIXEL_SHIFT = (0.5, -0.5)
#: The EGL plugin's off-screen surface, (width, height); larger images are rendered in tiles.
EGL_MAX_TILE = (1024, 768)
#: "auto" uses EGL for images with at least this many pixels (about 420 x 240): TinyRenderer's
#: cost grows with the pixels, EGL's is mostly a fixed cost per frame, and on the 2-core machine
#: they cross near 1e5 pixels (``benchmarks/render.py``; figures in docs/benchmarks.md).
AUTO_EGL_MIN_PIXELS = 100_000

#: Throwaway renders of an EGL client's first request (its first two plugin calls differ from later ones).
EGL_WARMUP_RENDERS = 2

#: Client ids of the EGL clients alive in this process.
_LIVE_EGL: set[int] = set()
#: The client whose EGL context is current in this process (-1: none or unknown).
_CURRENT_EGL = [-1]

_EGL_DRAW, _EGL_READ = 0x3059, 0x305A


class _EglApi:
    """The few libEGL calls needed to switch between the plugin's per-client contexts."""

    _instance: _EglApi | None | bool = False

    def __init__(self, lib: ctypes.CDLL) -> None:
        for name in ("eglGetCurrentDisplay", "eglGetCurrentContext"):
            getattr(lib, name).restype = ctypes.c_void_p
            getattr(lib, name).argtypes = []
        lib.eglGetCurrentSurface.restype = ctypes.c_void_p
        lib.eglGetCurrentSurface.argtypes = [ctypes.c_int]
        lib.eglMakeCurrent.restype = ctypes.c_uint
        lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
        self._lib = lib

    @classmethod
    def get(cls) -> _EglApi | None:
        """The process's libEGL (the one the plugin loads), or None if ctypes cannot load it."""
        if cls._instance is False:
            try:
                cls._instance = cls(ctypes.CDLL("libEGL.so.1"))
            except (OSError, AttributeError):
                cls._instance = None
        return cls._instance  # type: ignore[return-value]

    def current(self) -> tuple[int, int, int, int] | None:
        """(display, draw surface, read surface, context) current in this thread, or None."""
        lib = self._lib
        state = (lib.eglGetCurrentDisplay(), lib.eglGetCurrentSurface(_EGL_DRAW),
                 lib.eglGetCurrentSurface(_EGL_READ), lib.eglGetCurrentContext())
        return state if all(state) else None

    def make_current(self, state: tuple[int, int, int, int]) -> bool:
        """eglMakeCurrent(display, draw, read, context); True on success."""
        return bool(self._lib.eglMakeCurrent(*state))


@dataclass(frozen=True)
class RawImage:
    """Buffers as rendered: RGB, the [0, 1] depth buffer and the body-id mask (or None)."""

    rgb: NDArray[np.uint8]  # (H, W, 3)
    depth_buffer: NDArray[np.float32]  # (H, W)
    segmentation: NDArray[np.int32] | None  # (H, W) body ids, -1 for background


def egl_plugin_path() -> str | None:
    """File of pybullet's ``eglRenderer`` plugin, or None where this pybullet has none."""
    loader = pkgutil.get_loader("eglRenderer")
    return None if loader is None else loader.get_filename()


_DEVNULL: list[int] = []  # one descriptor on /dev/null, opened on first use


@contextlib.contextmanager
def quiet_c_output(fds: tuple[int, ...] = (1, 2)) -> Iterator[None]:
    """Silence C-level writes to the file descriptors ``fds`` (stdout, stderr) for the duration.

    C code writes to descriptors 1 and 2 whatever Python's ``sys.stdout`` / ``sys.stderr`` are
    (pytest swaps them), so the descriptors themselves are pointed at ``/dev/null`` and restored.
    Python's own buffered output is flushed first, so nothing of it is lost.
    """
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    if not _DEVNULL:
        _DEVNULL.append(os.open(os.devnull, os.O_WRONLY))
    saved = [os.dup(fd) for fd in fds]
    try:
        for fd in fds:
            os.dup2(_DEVNULL[0], fd)
        yield
    finally:
        for fd, copy in zip(fds, saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)


with quiet_c_output():  # "pybullet build time: ..." on import
    import pybullet

p = pybullet


def resolve_renderer(renderer: str, image_size: tuple[int, int]) -> str:
    """The backend that ``renderer`` asks for at ``image_size``: "tiny" or "egl".

    ``"auto"`` picks EGL for images of at least :data:`AUTO_EGL_MIN_PIXELS` pixels and
    TinyRenderer for smaller ones (availability is checked when the client starts).

    Raises:
        ConfigError: for an unknown renderer name or a bad image size.
    """
    if renderer not in RENDERERS:
        raise ConfigError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
    try:
        w, h = (int(x) for x in image_size)
    except (TypeError, ValueError):
        raise ConfigError(
            f"image_size must be (width, height) in pixels, got {image_size!r}"
        ) from None
    if w <= 0 or h <= 0:
        raise ConfigError(f"image_size must be positive (width, height), got {image_size!r}")
    if renderer != "auto":
        return renderer
    return "egl" if w * h >= AUTO_EGL_MIN_PIXELS else "tiny"


class RenderClient:
    """A DIRECT pybullet client with one rendering backend.

    Args:
        backend: ``"tiny"`` or ``"egl"``.

    Raises:
        ConfigError: for an unknown backend.
        RendererUnavailableError: if ``backend == "egl"`` and the plugin cannot start.
    """

    def __init__(self, backend: str) -> None:
        if backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.backend = backend
        self.client_id = -1
        self._closed = True
        self._egl_state: tuple[int, int, int, int] | None = None
        #: False until the first EGL frames have been rendered (and discarded: module docstring).
        self._primed = backend != "egl"
        if backend == "egl" and _LIVE_EGL and _EglApi.get() is None:
            raise RendererUnavailableError(
                f"EGL client {next(iter(_LIVE_EGL))} is alive and libEGL cannot be reached through "
                "ctypes to switch contexts, so a second EGL client would render the first one's "
                "scene; close that SiteWorld first, render in another process, or use "
                "renderer='tiny'"
            )
        self.client_id = p.connect(p.DIRECT)
        if self.client_id < 0:
            raise RendererUnavailableError("pybullet could not create a DIRECT client")
        self._closed = False
        # The physics server's file cache outlives the client: every mesh and texture loaded
        # would stay in memory after disconnect (see uav_struct_env.sim.scene, "Memory").
        p.setPhysicsEngineParameter(enableFileCaching=0, physicsClientId=self.client_id)
        if backend == "egl":
            try:
                self._load_egl()
            except BaseException:
                self.close()
                raise

    def _load_egl(self) -> None:
        path = egl_plugin_path()
        if path is None:
            raise RendererUnavailableError(
                "this pybullet build has no eglRenderer plugin; use renderer='tiny'"
            )
        os.environ.setdefault("EGL_PLATFORM", "surfaceless")
        with quiet_c_output():
            plugin = p.loadPlugin(path, "_eglRendererPlugin", physicsClientId=self.client_id)
        if plugin < 0:
            raise RendererUnavailableError(
                f"pybullet's eglRenderer plugin ({path}) failed to start (no usable EGL device or "
                "driver; on a headless machine Mesa's llvmpipe is enough); use renderer='tiny'"
            )
        self._plugin = plugin
        # The plugin has just made its new context current: remember it for activate().
        api = _EglApi.get()
        self._egl_state = None if api is None else api.current()
        if self._egl_state is None and _LIVE_EGL:
            raise RendererUnavailableError(
                "could not read the EGL plugin's context, so a second EGL client cannot be used "
                "safely; close the other EGL SiteWorld first or use renderer='tiny'"
            )
        _LIVE_EGL.add(self.client_id)
        _CURRENT_EGL[0] = self.client_id

    def activate(self) -> None:
        """Make this client's EGL context current (no-op for TinyRenderer).

        Call before any pybullet call on this client that may reach the renderer: creating or
        changing visual shapes and bodies, rendering, disconnecting.
        """
        if self.backend != "egl" or self._closed or _CURRENT_EGL[0] == self.client_id:
            return
        api = _EglApi.get()
        if api is None or self._egl_state is None or not api.make_current(self._egl_state):
            raise RendererUnavailableError(
                f"could not make EGL client {self.client_id}'s context current"
            )
        _CURRENT_EGL[0] = self.client_id

    # ------------------------------------------------------------------------------ rendering
    def render(
        self,
        view: tuple[float, ...],
        camera: Camera,
        *,
        segmentation: bool = False,
        light: dict | None = None,
    ) -> RawImage:
        """Render through ``camera`` from ``view`` (pybullet view matrix, 16 floats).

        Args:
            view: column-major view matrix (:func:`uav_struct_env.sim.camera.view_matrix`).
            camera: intrinsics and size; the backend's pixel convention is compensated.
            segmentation: also render the body-id mask (costs an extra pass with EGL).
            light: extra ``getCameraImage`` lighting keywords (``lightDirection``, ...).
        """
        if self._closed:
            raise RuntimeError("this RenderClient is closed")
        self.activate()
        if not self._primed:
            self._primed = True
            for _ in range(EGL_WARMUP_RENDERS):
                self.render(view, camera, segmentation=segmentation, light=light)
        if self.backend == "tiny":
            du, dv = TINY_PIXEL_SHIFT
            shifted = camera._replaced(cx=camera.cx - du, cy=camera.cy - dv)
            raw = self._render_once(view, shifted, segmentation, light, p.ER_TINY_RENDERER)
            return RawImage(np.ascontiguousarray(raw.rgb), raw.depth_buffer, raw.segmentation)
        tw, th = EGL_MAX_TILE
        if camera.width <= tw and camera.height <= th:
            raw = self._render_once(view, camera, segmentation, light, p.ER_BULLET_HARDWARE_OPENGL)
            return RawImage(np.ascontiguousarray(raw.rgb), raw.depth_buffer, raw.segmentation)
        nx, ny = -(-camera.width // tw), -(-camera.height // th)
        xs = np.linspace(0, camera.width, nx + 1).round().astype(int)
        ys = np.linspace(0, camera.height, ny + 1).round().astype(int)
        rgb = np.empty((camera.height, camera.width, 3), np.uint8)
        depth = np.empty((camera.height, camera.width), np.float32)
        seg = np.empty((camera.height, camera.width), np.int32) if segmentation else None
        for j in range(ny):
            for i in range(nx):
                tile = replace(
                    camera,
                    width=int(xs[i + 1] - xs[i]),
                    height=int(ys[j + 1] - ys[j]),
                    cx=camera.cx - xs[i],
                    cy=camera.cy - ys[j],
                )
                part = self._render_once(view, tile, segmentation, light,
                                         p.ER_BULLET_HARDWARE_OPENGL)
                window = np.s_[ys[j]:ys[j + 1], xs[i]:xs[i + 1]]
                rgb[window] = part.rgb
                depth[window] = part.depth_buffer
                if seg is not None:
                    seg[window] = part.segmentation
        return RawImage(rgb, depth, seg)

    def _render_once(
        self, view: tuple[float, ...], camera: Camera, segmentation: bool, light: dict | None,
        renderer: int,
    ) -> RawImage:
        flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
        w, h = camera.width, camera.height
        quiet = quiet_c_output() if self.backend == "egl" else contextlib.nullcontext()
        with quiet:
            _, _, rgba, depth, seg = p.getCameraImage(
                w, h, viewMatrix=view, projectionMatrix=projection_matrix(camera),
                renderer=renderer, flags=flags, physicsClientId=self.client_id, **(light or {}),
            )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[:, :, :3]
        depth = np.asarray(depth, dtype=np.float32).reshape(h, w)
        mask = np.asarray(seg, dtype=np.int32).reshape(h, w) if segmentation else None
        return RawImage(rgb, depth, mask)  # rgb: a view of the RGBA buffer

    # ------------------------------------------------------------------------------ lifetime
    @property
    def closed(self) -> bool:
        """True once :meth:`close` has run."""
        return self._closed

    def close(self) -> None:
        """Disconnect the client (idempotent)."""
        if self._closed:
            return
        if self.backend == "egl" and self.client_id in _LIVE_EGL:
            # The plugin deletes its GL objects in whatever context is current: make it ours.
            with contextlib.suppress(RendererUnavailableError):
                self.activate()
        self._closed = True
        quiet = quiet_c_output() if self.backend == "egl" else contextlib.nullcontext()
        with quiet, contextlib.suppress(p.error):
            p.disconnect(physicsClientId=self.client_id)
        if _CURRENT_EGL[0] == self.client_id:
            _CURRENT_EGL[0] = -1  # the plugin released its context on the way out
        _LIVE_EGL.discard(self.client_id)

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()
