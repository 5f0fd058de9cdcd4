"""The calibrated pinhole camera and its exact conversion to pybullet's matrices.

Conventions are those of :mod:`localization.geometry`: OpenCV camera frame (x right, y down,
z forward) and pixel centres at integer ``(u, v)``. pybullet (like OpenGL) wants a view matrix
for a camera looking down its -z axis with y up, and a projection matrix mapping eye coordinates
to normalized device coordinates (NDC). Both are 16 floats in column-major order.

Derivation of :func:`projection_matrix` from ``K``: the pixel in column ``i`` covers
``u in [i - 0.5, i + 0.5]``, so the image spans ``u in [-0.5, W - 0.5]`` and NDC
``x_ndc = 2 (u + 0.5) / W - 1``. pybullet returns image row 0 at the top, which is NDC ``y = +1``:
``y_ndc = 1 - 2 (v + 0.5) / H``. With ``u = fx X/Z + s Y/Z + cx`` and GL eye coordinates
``(x_e, y_e, z_e) = (X, -Y, -Z)`` (clip ``w = -z_e = Z``), matching coefficients gives the
matrix below; the principal point and skew enter exactly, no field-of-view approximation.
Both renderers sample triangles at pixel centres (measured in ``tests/sim/test_projection.py``),
so no extra offset is needed.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from localization.checks import check_number
from localization.geometry.camera import PAPER_IMAGE_SIZE, PAPER_K
from localization.geometry.transforms import check_intrinsics, check_transform

__all__ = ["GL_FROM_CV", "Camera", "depth_from_buffer", "projection_matrix", "view_matrix"]

#: Flip from the OpenCV camera frame (y down, z forward) to OpenGL's eye frame (y up, z back).
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics, image size in pixels and the renderer's clip planes (metres).

    The default is the paper's camera (:data:`localization.geometry.camera.PAPER_K`, the project's one
    definition): 1280 x 720, fx = fy = 1108.5 px, principal point (640, 360).
    """

    width: int = PAPER_IMAGE_SIZE[0]
    height: int = PAPER_IMAGE_SIZE[1]
    fx: float = float(PAPER_K[0, 0])
    fy: float = float(PAPER_K[1, 1])
    cx: float = float(PAPER_K[0, 2])
    cy: float = float(PAPER_K[1, 2])
    near: float = 0.1
    far: float = 400.0
    skew: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width", "height"):  # pixels
            value = check_number(f"Camera.{name}", getattr(self, name), 1, integer=True,
                                 type_error=ValueError)
            object.__setattr__(self, name, int(value))
        for name in ("fx", "fy", "cx", "cy", "near", "far", "skew"):
            object.__setattr__(self, name, check_number(f"Camera.{name}", getattr(self, name)))
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(
                f"Camera focal lengths must be positive, got fx={self.fx}, fy={self.fy}"
            )
        if not 0 < self.near < self.far:
            raise ValueError(
                f"Camera clip planes need 0 < near < far, got near={self.near}, far={self.far}"
            )

    @property
    def K(self) -> NDArray[np.float64]:
        """(3, 3) float64 intrinsic matrix (a fresh copy; built once per camera)."""
        cached = self.__dict__.get("_K")
        if cached is None:  # a frozen camera's K never changes; every agent-step asks for it
            cached = np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
            object.__setattr__(self, "_K", cached)
        return cached.copy()

    def _replaced(self, **floats: float) -> Camera:
        """``dataclasses.replace`` of float fields, without the checks.

        For values the caller derived from this camera's own (a render's near plane, a shifted
        principal point): every render makes one or two such cameras. The cached ``K`` is not
        carried over.
        """
        out = object.__new__(Camera)
        values = {name: getattr(self, name) for name in _FIELDS}
        values.update({name: float(v) for name, v in floats.items()})
        out.__dict__.update(values)  # a frozen dataclass's fields live in its __dict__
        return out

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return self.width, self.height

    def scaled(self, width: int, height: int) -> Camera:
        """The same camera (same field of view and optical axis) at another resolution.

        Pixel edges scale, not pixel centres: ``u' + 0.5 = (u + 0.5) * width / self.width``, so
        ``cx' = (cx + 0.5) * sx - 0.5`` and ``fx' = fx * sx``.
        """
        sx, sy = width / self.width, height / self.height
        return replace(
            self,
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            skew=self.skew * sx,
        )

    @classmethod
    def from_K(
        cls, K: ArrayLike, width: int, height: int, near: float = 0.1, far: float = 400.0
    ) -> Camera:
        """A camera from a (3, 3) intrinsic matrix and an image size.

        Raises:
            TypeError, ValueError: if ``K`` is not a valid pinhole intrinsic matrix.
        """
        K = check_intrinsics("K", K)
        return cls(
            width=width, height=height, fx=float(K[0, 0]), fy=float(K[1, 1]),
            cx=float(K[0, 2]), cy=float(K[1, 2]), near=near, far=far, skew=float(K[0, 1]),
        )


def projection_matrix(camera: Camera) -> tuple[float, ...]:
    """Pybullet's projection matrix (16 floats, column-major) derived exactly from ``camera.K``.

    See the module docstring for the derivation.
    """
    W, H = camera.width, camera.height
    n, f = camera.near, camera.far
    P = np.zeros((4, 4))
    P[0, 0] = 2.0 * camera.fx / W
    P[0, 1] = -2.0 * camera.skew / W
    P[0, 2] = 1.0 - 2.0 * (camera.cx + 0.5) / W
    P[1, 1] = 2.0 * camera.fy / H
    P[1, 2] = 2.0 * (camera.cy + 0.5) / H - 1.0
    P[2, 2] = -(f + n) / (f - n)
    P[2, 3] = -2.0 * f * n / (f - n)
    P[3, 2] = -1.0
    return tuple(float(x) for x in P.T.reshape(-1))


def view_matrix(cam_from_world: ArrayLike) -> tuple[float, ...]:
    """Pybullet's view matrix (16 floats, column-major) of an OpenCV ``cam_from_world``.

    Raises:
        TypeError, ValueError: if ``cam_from_world`` is not a 4x4 rigid transform.
    """
    T = check_transform("cam_from_world", cam_from_world)
    V = GL_FROM_CV @ T
    return tuple(float(x) for x in V.T.reshape(-1))


_FIELDS = tuple(f.name for f in fields(Camera))


def depth_from_buffer(buffer: ArrayLike, camera: Camera) -> NDArray[np.float32]:
    """Metric depth along the optical axis (m) from a [0, 1] OpenGL depth buffer.

    ``z = far * near / (far - (far - near) * d)``; background pixels (``d = 1``) give ``far``.
    """
    d = np.asarray(buffer, dtype=np.float64)
    n, f = camera.near, camera.far
    return (f * n / (f - (f - n) * d)).astype(np.float32)
