"""The upright two-point pose solver: with the camera's tilt known, two correspondences fix the pose.

An onboard attitude sensor measures roll and pitch (the tilt, the direction of gravity in the
camera) far better than yaw and position. With the tilt taken from the prior, the pose has four
unknowns -- the yaw and the camera centre -- and two 2D-3D correspondences (four equations) fix
it in closed form (the "upright" or "up2p" minimal problem, solved as in Kukelova et al.,
"Closed-form solutions to minimal absolute pose problems with known vertical direction", ACCV
2010, and PoseLib's ``up2p``). Robust association (:mod:`localization.associate`) draws its
hypotheses this way: every pair of landmarks for a few pairs of detections, all solved at once.

Derivation. Let ``d_k = R_wc0 K^-1 (u_k, 1)`` be the world direction of detection ``k`` under
the prior's attitude. The pose is the prior's attitude turned by ``psi`` about the world z axis,
``R_wc = Rz(psi) R_wc0``, and the centre ``C``, so ``X_k = C + l_k Rz(psi) d_k`` with depths
``l_k > 0``. The difference ``X_1 - X_2 = Rz(psi) (l_1 d_1 - l_2 d_2)`` removes ``C``; ``Rz``
keeps the z component and the horizontal length, which gives one linear and one quadratic
equation in ``(l_1, l_2)``:

    l_1 d_1z - l_2 d_2z = dZ,      |l_1 d_1xy - l_2 d_2xy|^2 = |dXY|^2.

On the line of the first, the second is a quadratic in one unknown: up to two solutions. ``psi``
is then the angle from ``l_1 d_1xy - l_2 d_2xy`` to ``dXY``, and ``C = X_1 - l_1 Rz(psi) d_1``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["upright_two_point"]


def upright_two_point(
    d1: NDArray[np.float64], d2: NDArray[np.float64], X1: NDArray[np.float64], X2: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Yaw corrections and camera centres that put two world points on two viewing directions.

    Args:
        d1: (S, 3) world direction of the first detection under the prior's attitude
            (``R_wc0 K^-1 (u, 1)``; any positive length).
        d2: (S, 3) the same for the second detection.
        X1: (S, 3) the landmark each sample assigns to the first detection.
        X2: (S, 3) the landmark each sample assigns to the second.

    Returns:
        ``(psi (2S,), C (2S, 3), valid (2S,))``: for each sample its two solutions (rows ``s``
        and ``S + s``): ``psi`` the rotation about the world z axis to apply to the prior's
        ``world_from_cam`` rotation (``R_wc = Rz(psi) R_wc0``) and ``C`` the camera centre;
        ``valid`` is False where the solution does not exist (complex roots, a depth not
        positive, both directions horizontal, or the two points at one place).
    """
    dX = X1 - X2
    a = np.stack([d1[:, 2], -d2[:, 2]], axis=1)  # a . (l1, l2) = dZ
    na2 = np.sum(a * a, axis=1)
    ok = (na2 > 1e-12) & (np.sum(dX * dX, axis=1) > 1e-12)
    na2 = np.where(ok, na2, 1.0)
    lp = a * (dX[:, 2] / na2)[:, None]  # the point of the line nearest the origin
    nrm = np.sqrt(na2)
    n = np.stack([a[:, 1], -a[:, 0]], axis=1) / nrm[:, None]  # the line's direction
    # |l1 d1xy - l2 d2xy|^2 = l^T Q l
    q11 = np.sum(d1[:, :2] ** 2, axis=1)
    q22 = np.sum(d2[:, :2] ** 2, axis=1)
    q12 = -np.sum(d1[:, :2] * d2[:, :2], axis=1)

    def quad(x: NDArray, y: NDArray) -> NDArray:
        cross = x[:, 0] * y[:, 1] + x[:, 1] * y[:, 0]
        return q11 * x[:, 0] * y[:, 0] + q12 * cross + q22 * x[:, 1] * y[:, 1]

    A = quad(n, n)
    B = 2.0 * quad(lp, n)
    Cc = quad(lp, lp) - np.sum(dX[:, :2] ** 2, axis=1)
    disc = B * B - 4.0 * A * Cc
    ok &= (disc >= 0.0) & (A > 1e-15)
    root = np.sqrt(np.maximum(disc, 0.0))
    A = np.where(ok, A, 1.0)
    s = np.concatenate([(-B + root) / (2.0 * A), (-B - root) / (2.0 * A)])
    ok = np.concatenate([ok, ok])
    lp2, n2 = np.concatenate([lp, lp]), np.concatenate([n, n])
    lam = lp2 + s[:, None] * n2  # (2S, 2) depths along d1, d2
    ok &= (lam[:, 0] > 0.0) & (lam[:, 1] > 0.0)
    D1, D2, X1b, dXb = (np.concatenate([v, v]) for v in (d1, d2, X1, dX))
    v = lam[:, :1] * D1[:, :2] - lam[:, 1:] * D2[:, :2]
    psi = np.arctan2(v[:, 0] * dXb[:, 1] - v[:, 1] * dXb[:, 0], np.sum(v * dXb[:, :2], axis=1))
    c, sn = np.cos(psi), np.sin(psi)
    rd = np.stack([c * D1[:, 0] - sn * D1[:, 1], sn * D1[:, 0] + c * D1[:, 1], D1[:, 2]], axis=1)
    C = X1b - lam[:, :1] * rd
    return psi, C, ok
