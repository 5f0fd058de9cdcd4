"""Procedural textures: non-repeating concrete, site ground and crisp ArUco marker sheets.

Every texture is an ``(H, W, 3)`` uint8 RGB array (row 0 at the top, as in an image file), drawn
from a ``numpy.random.Generator`` so that a seed reproduces it. Noise features are specified in
metres, not texels: a texture covering ``extent`` metres looks the same at any resolution, and
neighbouring surfaces of one element (whose faces share an atlas) get consistent grain.

Only numpy, OpenCV (for the ArUco bit pattern) and nothing else: no pybullet here.

Drawing a texture costs 10-250 ms (a 1024 x 1024 ground most), and the same site is often built
again in one process (each ``reset`` of a fixed site, env copies, a test suite): the concrete and
ground textures are memoized on the generator's state and the arguments (:func:`_replayable`);
a repeated draw returns a copy of the texture and leaves the generator where drawing it would
have, so every seed gives the same texture and the same later draws as without the memo.
"""

from __future__ import annotations

import functools
from collections import OrderedDict
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from uav_struct_env.site.markers import ArucoMarker

__all__ = [
    "REPLAY_BYTES",
    "aruco_texture",
    "clear_texture_memo",
    "concrete_texture",
    "fractal_noise",
    "ground_palette",
    "ground_texture",
    "texture_memo",
    "value_noise",
]


def _check_rng(rng: object) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    return rng


#: Most bytes of textures :func:`_replayable` keeps (least recently used dropped first).
REPLAY_BYTES = 64 * 2**20
_REPLAY: OrderedDict[str, tuple[NDArray[np.uint8], dict]] = OrderedDict()


def _replayable(draw: Callable[..., NDArray[np.uint8]]) -> Callable[..., NDArray[np.uint8]]:
    """``draw(rng, ...)`` memoized on ``rng``'s state and the arguments (see the module docstring)."""

    @functools.wraps(draw)
    def replay(rng: np.random.Generator, *args, **kwargs) -> NDArray[np.uint8]:
        rng = _check_rng(rng)
        key = repr((draw.__name__, rng.bit_generator.state, args, sorted(kwargs.items())))
        if key in _REPLAY:
            _REPLAY.move_to_end(key)
            texture, after = _REPLAY[key]
            rng.bit_generator.state = after
            return texture.copy()
        texture = draw(rng, *args, **kwargs)
        if texture.nbytes <= REPLAY_BYTES:
            _REPLAY[key] = (texture.copy(), rng.bit_generator.state)
            while texture_memo()[1] > REPLAY_BYTES:
                _REPLAY.popitem(last=False)
        return texture

    return replay


def texture_memo() -> tuple[int, int]:
    """(textures, bytes) the memo of :func:`_replayable` holds in this process."""
    return len(_REPLAY), sum(t.nbytes for t, _ in _REPLAY.values())


def clear_texture_memo() -> None:
    """Forget every memoized texture (the next draws compute them again)."""
    _REPLAY.clear()


def _check_size(size: int) -> int:
    check_number("texture size (pixels)", size, 2, integer=True, type_error=ValueError)
    return int(size)


def value_noise(
    rng: np.random.Generator, size: int, cells: float, *, period: bool = False
) -> NDArray[np.float32]:
    """One octave of smooth value noise on a ``size x size`` grid, values in about [-1, 1].

    Args:
        rng: source of the random lattice values.
        size: output side in pixels.
        cells: number of lattice cells across the texture (feature size = side / cells).
        period: if True the noise wraps around (tileable); the site never tiles textures, so the
            default is False.

    Returns:
        ``(size, size)`` float32.
    """
    rng = _check_rng(rng)
    size = _check_size(size)
    if not cells > 0:
        raise ValueError(f"cells must be positive, got {cells!r}")
    n = int(np.ceil(cells)) + 2
    lattice = rng.uniform(-1.0, 1.0, (n, n)).astype(np.float32)
    if period:
        m = max(int(round(cells)), 1)
        lattice = lattice[np.arange(n) % m][:, np.arange(n) % m]
    # Random sub-cell offset so that octaves do not align on pixel (0, 0).
    off = rng.uniform(0.0, 1.0, 2)
    t = (np.arange(size, dtype=np.float64) + 0.5) / size * cells
    ty, tx = t + off[0], t + off[1]
    iy, ix = np.floor(ty).astype(np.intp), np.floor(tx).astype(np.intp)
    fy, fx = ty - iy, tx - ix
    sy = (fy * fy * (3.0 - 2.0 * fy)).astype(np.float32)[:, None]  # smoothstep
    sx = (fx * fx * (3.0 - 2.0 * fx)).astype(np.float32)[None, :]
    # Separable: interpolate the lattice rows along x first (small), then along y.
    rows = lattice[:, ix] + (lattice[:, ix + 1] - lattice[:, ix]) * sx  # (n, size)
    return rows[iy] + (rows[iy + 1] - rows[iy]) * sy


def fractal_noise(
    rng: np.random.Generator,
    size: int,
    extent: float,
    feature: float,
    *,
    octaves: int = 5,
    persistence: float = 0.5,
) -> NDArray[np.float32]:
    """Multi-octave value noise over a texture covering ``extent`` metres.

    The first octave has features of ``feature`` metres; each further octave halves the feature
    size and multiplies the amplitude by ``persistence``. Octaves finer than two texels are
    skipped (they would only alias). The result is normalised to unit standard deviation.

    Returns:
        ``(size, size)`` float32 with mean about 0 and standard deviation 1.
    """
    size = _check_size(size)
    if not (extent > 0 and feature > 0):
        raise ValueError(f"extent and feature must be positive metres, got {extent!r}, {feature!r}")
    out = np.zeros((size, size), dtype=np.float32)
    amplitude = 1.0
    for k in range(octaves):
        cells = extent / (feature / 2**k)
        if cells > size / 2:
            break
        out += amplitude * value_noise(rng, size, cells)
        amplitude *= persistence
    std = float(out.std())
    return (out - out.mean()) / std if std > 0 else out


def _to_uint8(rgb: NDArray[np.floating]) -> NDArray[np.uint8]:
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


@_replayable
def concrete_texture(
    rng: np.random.Generator, size: int = 512, extent: float = 4.0
) -> NDArray[np.uint8]:
    """A cast-concrete surface: grey with blotchy stains, fine grain, pores and faint lift lines.

    Args:
        rng: generator; two calls never give the same texture.
        size: side in pixels.
        extent: side of the square area the texture covers, metres (sets the feature scale).

    Returns:
        ``(size, size, 3)`` uint8 RGB.
    """
    rng = _check_rng(rng)
    size = _check_size(size)
    base = rng.uniform(128.0, 168.0)  # overall grey level differs from pour to pour
    tint = rng.uniform(-4.0, 6.0) * np.array([1.0, 0.6, -0.6])  # slightly warm or cool
    stains = fractal_noise(rng, size, extent, feature=rng.uniform(0.8, 1.6), octaves=4)
    grain = fractal_noise(rng, size, extent, feature=0.06, octaves=3, persistence=0.6)
    # Darker streaks running down the face (water runs, formwork marks): low-frequency in u,
    # stretched along v.
    streak = value_noise(rng, size, cells=extent / 0.25)
    streak = np.repeat(streak.mean(axis=0, keepdims=True), size, axis=0)
    lum = base + 16.0 * stains + 7.0 * grain + 5.0 * streak
    # Pores: sparse small dark dots (air voids), a few texels wide at most.
    n_pores = int(rng.poisson(100.0 * extent**2))  # about 100 voids per square metre
    if n_pores:
        py = rng.integers(0, size, n_pores)
        px = rng.integers(0, size, n_pores)
        np.subtract.at(lum, (py, px), rng.uniform(25.0, 60.0, n_pores))
    # Faint horizontal formwork joints every 0.5-1.2 m (v direction), randomly phased.
    pitch = rng.uniform(0.5, 1.2)
    rows = ((np.arange(size) + 0.5) / size * extent + rng.uniform(0, pitch)) % pitch
    joint = np.exp(-0.5 * (rows / 0.008) ** 2) + np.exp(-0.5 * ((pitch - rows) / 0.008) ** 2)
    lum -= 14.0 * joint[:, None].astype(np.float32)
    rgb = lum[:, :, None] + tint[None, None, :]
    return _to_uint8(rgb)


def ground_palette(rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A site's (soil, gravel) RGB colours, drawn once and shared by all ground textures."""
    rng = _check_rng(rng)
    soil = np.array([112.0, 94.0, 72.0]) + rng.uniform(-8.0, 8.0, 3)
    gravel = np.array([128.0, 124.0, 116.0]) + rng.uniform(-8.0, 8.0, 3)
    return soil, gravel


@_replayable
def ground_texture(
    rng: np.random.Generator,
    size: int = 1024,
    extent: float = 48.0,
    *,
    palette: tuple[ArrayLike, ArrayLike] | None = None,
) -> NDArray[np.uint8]:
    """Site ground: brown compacted soil with gravel patches and pebble speckle.

    Args:
        rng: generator.
        size: side in pixels.
        extent: side of the square area the texture covers, metres.
        palette: (soil, gravel) RGB colours (default: drawn from ``rng``, see
            :func:`ground_palette`).

    Returns:
        ``(size, size, 3)`` uint8 RGB.
    """
    rng = _check_rng(rng)
    size = _check_size(size)
    if palette is None:
        palette = ground_palette(rng)
    soil, gravel = (np.asarray(c, dtype=np.float64) for c in palette)
    mix_field = fractal_noise(rng, size, extent, feature=6.0, octaves=4)
    mix = 1.0 / (1.0 + np.exp(-2.5 * (mix_field - 0.3)))  # 0 soil .. 1 gravel
    lum = 14.0 * fractal_noise(rng, size, extent, feature=1.5, octaves=5, persistence=0.55)
    rgb = soil * (1.0 - mix[..., None]) + gravel * mix[..., None] + lum[..., None]
    # Pebbles: texel-scale speckle whose density follows the gravel mix, faded where a texel is
    # much larger than a pebble (it would average out).
    texel = extent / size
    speckle = rng.normal(0.0, 1.0, (size, size)).astype(np.float32)
    rgb += (10.0 + 18.0 * mix[..., None]) * speckle[..., None] * min(1.0, 0.02 / texel)
    return _to_uint8(rgb)


def aruco_texture(marker: ArucoMarker, module_px: int = 16) -> NDArray[np.uint8]:
    """The printed sheet of ``marker``: its ArUco pattern with the white quiet zone around it.

    The pattern comes from ``cv2.aruco.generateImageMarker`` at one pixel per module and is
    upscaled by pixel replication (crisp edges). The quiet zone is ``marker.quiet_zone * side``
    on each side, rounded to whole pixels. Image row 0 is the marker's top edge (marker +y),
    column 0 its left edge (marker -x): the OpenCV corner order of ``marker.corners_world``
    (top-left first) is that of the image.

    Args:
        marker: the marker.
        module_px: pixels per module (bit cell) of the pattern.

    Returns:
        ``(S, S, 3)`` uint8 RGB, ``S = modules * module_px + 2 * quiet``.
    """
    import cv2

    check_number("module_px", module_px, 1, integer=True, type_error=ValueError)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, marker.dictionary))
    modules = dictionary.markerSize + 2  # data bits plus the one-module black border
    pattern = cv2.aruco.generateImageMarker(dictionary, int(marker.id), modules, borderBits=1)
    big = np.kron(pattern, np.ones((module_px, module_px), dtype=np.uint8))
    quiet = int(round(marker.quiet_zone * modules * module_px))
    sheet = np.pad(big, quiet, constant_values=255)
    return np.repeat(sheet[:, :, None], 3, axis=2)
