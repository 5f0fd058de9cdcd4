"""Cross-view association of worker detections by reprojection consistency.

Two detections in two cameras are the same worker when one 3D feet point and one 3D head point
explain both: each candidate pair is triangulated (:func:`~tracking.triangulate.dlt` then
:func:`~tracking.triangulate.refine`, batched over every pair of every two cameras) and scored by
its chi-square (whitened reprojection error of feet and head, 2 degrees of freedom). A pair is a
candidate when that chi-square is within the ``gate_probability`` quantile, both points lie in
front of both cameras, the rays are not nearly parallel and, if ``height_range`` is given, the
head lies that far above the feet.

Groups are then built greedily, best candidate first (union-find with a test): a pair starts a
group, or joins a detection to a group, or merges two groups, only when the groups' cameras are
disjoint (one detection per camera and worker) and the grown group, triangulated from all its
views, still passes the gate at its own degrees of freedom (``4 n - 6`` for n views). A wrong pair
between two close workers that happens to fit two views is therefore refused as soon as a third
view disagrees, and a detection is never used twice.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from localization.stats import chi2_quantile
from tracking.triangulate import dlt, max_ray_angle_deg, pixel_covariances, refine
from tracking.views import CameraView

__all__ = ["Candidate", "associate", "candidates", "gate"]


def gate(probability: float, dof: int) -> float:
    """The chi-square value below which a fit with ``dof`` degrees of freedom is consistent."""
    return chi2_quantile(probability, dof)


@dataclass(frozen=True)
class Candidate:
    """Two detections that one worker explains: ``(view a, index i)``, ``(view b, index j)``.

    ``chi2`` is the pair's fit; ``support`` the number of other views holding a detection that
    the same worker explains too (a three-view fit within the gate).
    """

    a: str
    i: int
    b: str
    j: int
    chi2: float
    support: int


def _fit(
    views: Sequence[CameraView], uv: NDArray, sigma: NDArray
) -> tuple[NDArray, NDArray, NDArray]:
    """Triangulate B workers seen in all ``views``: uv (B, n, 2 points, 2), sigma (B, n).

    Returns chi2 (B,) of feet + head, the smallest depth (B,) and the head-minus-feet height (B,).
    """
    B, n = uv.shape[:2]
    pts = uv.transpose(0, 2, 1, 3).reshape(2 * B, n, 2)  # feet and head as separate points
    sig = np.repeat(sigma, 2, axis=0)
    T = np.stack([v.cam_from_world for v in views])
    K = np.stack([v.K for v in views])
    x0, _ = dlt(T, K, pts)
    cov = pixel_covariances(views, x0, sig)
    xyz, chi2, _, depth = refine(T, K, pts, cov, x0)
    chi2 = np.where(np.isfinite(chi2), chi2, np.inf).reshape(B, 2).sum(axis=1)
    depth = np.where(np.isfinite(depth), depth, -np.inf).reshape(B, 2 * n).min(axis=1)
    xyz = xyz.reshape(B, 2, 3)
    return chi2, depth, xyz[:, 1, 2] - xyz[:, 0, 2]


def _consistent(
    chi2: NDArray, depth: NDArray, height: NDArray, n_views: int, probability: float,
    height_range: tuple[float, float] | None,
) -> NDArray:
    ok = (chi2 <= gate(probability, 4 * n_views - 6)) & (depth > 0)
    if height_range is not None:
        ok &= (height >= height_range[0]) & (height <= height_range[1])
    return ok


def candidates(
    views: Mapping[str, CameraView],
    uv: Mapping[str, NDArray],
    sigma: Mapping[str, NDArray],
    *,
    probability: float,
    min_ray_angle_deg: float,
    height_range: tuple[float, float] | None,
) -> list[Candidate]:
    """Every consistent pair of detections in two cameras, best first.

    Best is most supported by the other views, then lowest chi-square. On a flat site two rays
    from two cameras often meet by chance (a "ghost" worker that fits two views better than a true
    pair does); a ghost is rarely confirmed by a third view, a true pair usually is.

    Args:
        views: camera views by name.
        uv: per view name, (N, 2, 2) undistorted feet / head pixels of its N detections.
        sigma: per view name, (N,) detector sigma.
        probability: gate quantile.
        min_ray_angle_deg: smallest accepted angle between the two viewing rays.
        height_range: accepted head-above-feet heights, m, or None.
    """
    out: list[Candidate] = []
    names = [name for name in views if len(uv[name])]
    for a, b in combinations(names, 2):
        ii, jj = np.meshgrid(np.arange(len(uv[a])), np.arange(len(uv[b])), indexing="ij")
        ii, jj = ii.ravel(), jj.ravel()
        pair = (views[a], views[b])
        obs = np.stack([uv[a][ii], uv[b][jj]], axis=1)  # (B, 2 views, 2 points, 2)
        sig = np.stack([sigma[a][ii], sigma[b][jj]], axis=1)
        chi2, depth, height = _fit(pair, obs, sig)
        ok = _consistent(chi2, depth, height, 2, probability, height_range)
        angle = np.minimum(
            max_ray_angle_deg(pair, obs[:, :, 0]), max_ray_angle_deg(pair, obs[:, :, 1])
        )
        ok &= angle >= min_ray_angle_deg
        ii, jj, chi2 = ii[ok], jj[ok], chi2[ok]
        support = np.zeros(len(ii), dtype=int)
        for c in names:
            if c in (a, b) or not len(ii):
                continue
            kk = np.arange(len(uv[c]))
            obs3 = np.concatenate(
                [np.repeat(obs[ok], len(kk), axis=0), np.tile(uv[c][kk], (len(ii), 1, 1))[:, None]], axis=1
            )  # (B * K, 3 views, 2 points, 2)
            sig3 = np.column_stack([np.repeat(sig[ok], len(kk), axis=0), np.tile(sigma[c][kk], len(ii))])
            fit = _consistent(*_fit((*pair, views[c]), obs3, sig3), 3, probability, height_range)
            support += np.any(fit.reshape(len(ii), len(kk)), axis=1)
        keep = zip(ii, jj, chi2, support, strict=True)
        out.extend(Candidate(a, int(i), b, int(j), float(c), int(s)) for i, j, c, s in keep)
    out.sort(key=lambda c: (-c.support, c.chi2))
    return out


def associate(
    views: Mapping[str, CameraView],
    uv: Mapping[str, NDArray],
    sigma: Mapping[str, NDArray],
    *,
    probability: float,
    min_ray_angle_deg: float,
    height_range: tuple[float, float] | None,
) -> list[dict[str, int]]:
    """Groups of detections, one per worker: ``{view name: detection index}``, >= 2 views each.

    Detections in no group (seen by one camera, or inconsistent with every other) are left out;
    arguments as :func:`candidates`.
    """
    groups: dict[int, dict[str, int]] = {}
    member: dict[tuple[str, int], int] = {}
    next_id = 0

    def passes(group: dict[str, int]) -> bool:
        names = list(group)
        obs = np.stack([uv[n][group[n]] for n in names])[None]
        sig = np.array([[sigma[n][group[n]] for n in names]])
        chi2, depth, height = _fit([views[n] for n in names], obs, sig)
        return bool(_consistent(chi2, depth, height, len(names), probability, height_range)[0])

    for c in candidates(
        views, uv, sigma, probability=probability, min_ray_angle_deg=min_ray_angle_deg,
        height_range=height_range,
    ):
        ga, gb = member.get((c.a, c.i)), member.get((c.b, c.j))
        if ga is None and gb is None:
            groups[next_id] = {c.a: c.i, c.b: c.j}
            member[(c.a, c.i)] = member[(c.b, c.j)] = next_id
            next_id += 1
            continue
        if ga == gb:
            continue
        first = groups[ga] if ga is not None else {c.a: c.i}
        second = groups[gb] if gb is not None else {c.b: c.j}
        if set(first) & set(second):
            continue  # one detection per camera and worker
        merged = {**first, **second}
        if not passes(merged):
            continue
        keep = ga if ga is not None else gb
        for gid in (ga, gb):
            if gid is not None and gid != keep:
                del groups[gid]
        groups[keep] = merged
        for name, idx in merged.items():
            member[(name, idx)] = keep
    return list(groups.values())
