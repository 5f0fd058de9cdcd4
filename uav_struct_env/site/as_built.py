"""As-built deviations: the building as it stands, moved away from its design within tolerances.

The method localizes against the BIM, the building *as designed*; the concrete stands where the
formwork put it. :class:`AsBuilt` moves each element of a :class:`~uav_struct_env.site.Site` by
a random deviation within a tolerance model, element by element and seeded per element, so that
the environment can render (and report as ground truth) the as-built building while the
localizer keeps the design (``EnvConfig.as_built``; the study's ``--as-built``).

The tolerance model :data:`ACI117` (ACI 117, *Specification for Tolerances for Concrete
Construction and Materials*, cast-in-place members) gives:

=========================  =======  ==========================================================
deviation                  limit    applied as
=========================  =======  ==========================================================
column lateral alignment   25 mm    the whole column (outline, axis, top) moves in plan, x and
                                    y independently
slab-top elevation         19 mm    the whole slab moves vertically (its corners' and openings'
                                    z with it)
opening edge location      13 mm    each edge of each opening moves along its normal, the
                                    corners are the intersections of the moved edges
=========================  =======  ==========================================================

Each deviation is drawn from a normal distribution with the limit as its 2-sigma value and
clipped to the limit (every element conforms, about 5 % sit at the limit), then multiplied by
``scale`` (``scale=4`` is a site four times as sloppy as the specification allows; ``scale=0``
is the design itself). Beams, walls and slab outlines keep their design plan position (the
specification's three named deviations only). An element's deviation depends on ``seed`` and
its guid only, so it is the same at every stage, in every process and whatever other elements
the building has.
"""

from __future__ import annotations

import dataclasses
import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from localization.checks import check_choice, check_number
from uav_struct_env.errors import SiteGeometryError
from uav_struct_env.site.elements import Column, Element, Hole, Slab, TriangleMesh
from uav_struct_env.site.model import Site

__all__ = [
    "ACI117",
    "MAX_SCALE",
    "TOLERANCE_MODELS",
    "AsBuilt",
    "Tolerances",
    "make_as_built",
    "max_landmark_shift",
    "offset_edges",
]


@dataclass(frozen=True)
class Tolerances:
    """Deviation limits of a tolerance model, metres (see the module docstring)."""

    name: str
    column_lateral_m: float
    slab_elevation_m: float
    opening_edge_m: float

    def __post_init__(self) -> None:
        for f in ("column_lateral_m", "slab_elevation_m", "opening_edge_m"):
            check_number(f"tolerance {f}", getattr(self, f), 0.0, 1.0, error=SiteGeometryError,
                         type_error=SiteGeometryError)


#: ACI 117-10 cast-in-place concrete tolerances.
ACI117 = Tolerances("aci117", column_lateral_m=0.025, slab_elevation_m=0.019, opening_edge_m=0.013)

#: Largest accepted ``AsBuilt.scale`` (a site 100 times as sloppy as the tolerances allow).
MAX_SCALE = 100.0

#: Tolerance models by name.
TOLERANCE_MODELS: dict[str, Tolerances] = {ACI117.name: ACI117}


@dataclass(frozen=True)
class AsBuilt:
    """An as-built deviation model: tolerances, a scale factor on all of them and a seed.

    Attributes:
        tolerances: a :class:`Tolerances` or the name of one in :data:`TOLERANCE_MODELS`.
        scale: factor on every limit (``0`` leaves the design; ``4``: four times the limits).
        seed: the deviations' seed (with each element's guid).
    """

    tolerances: Tolerances | str = "aci117"
    scale: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.tolerances, str):
            name = check_choice("as-built tolerance model", self.tolerances, tuple(TOLERANCE_MODELS),
                                error=SiteGeometryError)
            object.__setattr__(self, "tolerances", TOLERANCE_MODELS[name])
        elif not isinstance(self.tolerances, Tolerances):
            raise SiteGeometryError(
                f"as-built tolerances must be a Tolerances or one of {sorted(TOLERANCE_MODELS)}, "
                f"got {self.tolerances!r}"
            )
        scale = check_number("as-built scale", self.scale, 0.0, MAX_SCALE, error=SiteGeometryError,
                             type_error=SiteGeometryError)
        object.__setattr__(self, "scale", scale)
        check_number("as-built seed", self.seed, 0, integer=True, error=SiteGeometryError,
                     type_error=SiteGeometryError)

    @property
    def label(self) -> str:
        """``"aci117 x 4"``, for titles and logs."""
        return f"{self.tolerances.name} x {self.scale:g}"

    def apply(self, site: Site) -> Site:
        """``site`` as built: every element moved by its deviation (the design if ``scale == 0``).

        The result has the design's element guids, stages and landmark ids, so the ids of its
        landmarks match the design's; ``source["as_built"]`` records the model, scale and seed.

        Raises:
            SiteGeometryError: if a deviation this large breaks an element (an opening moved out
                of its slab, an opening whose corners would change order).
        """
        if not isinstance(site, Site):
            raise TypeError(f"site must be a uav_struct_env.site.Site, got {type(site).__name__}")
        if self.scale == 0:
            return site
        elements = tuple(self._move(e) for e in site.elements)
        record = {"tolerances": dataclasses.asdict(self.tolerances), "scale": self.scale, "seed": self.seed}
        return dataclasses.replace(site, elements=elements, building=None,
                                   source={**site.source, "as_built": record})

    # ------------------------------------------------------------------------------- elements
    def _rng(self, guid: str) -> np.random.Generator:
        return np.random.default_rng([self.seed, zlib.crc32(guid.encode())])

    def _deviation(self, rng: np.random.Generator, limit: float, n: int) -> NDArray[np.float64]:
        return np.clip(rng.normal(0.0, 0.5, n), -1.0, 1.0) * limit * self.scale

    def _move(self, e: Element) -> Element:
        rng = self._rng(e.guid)
        tol = self.tolerances
        if isinstance(e, Column):
            d = self._deviation(rng, tol.column_lateral_m, 2)
            return dataclasses.replace(e, outline=e.outline + d, axis=(e.axis[0] + d[0], e.axis[1] + d[1]),
                                       mesh=_translated(e.mesh, (d[0], d[1], 0.0)))
        if isinstance(e, Slab):
            dz = float(self._deviation(rng, tol.slab_elevation_m, 1)[0])
            holes = tuple(self._move_hole(h, e) for h in e.holes)
            # A slab whose openings moved is re-meshed from its outline and openings.
            mesh = None if holes else _translated(e.mesh, (0.0, 0.0, dz))
            return dataclasses.replace(e, z_bottom=e.z_bottom + dz, z_top=e.z_top + dz, holes=holes,
                                       mesh=mesh)
        return e

    def _move_hole(self, hole: Hole, slab: Slab) -> Hole:
        rng = self._rng(f"{slab.guid}/{hole.guid}")
        offsets = self._deviation(rng, self.tolerances.opening_edge_m, len(hole.outline))
        outline = offset_edges(hole.outline, offsets)
        moved = dataclasses.replace(hole, outline=outline)
        if not np.allclose(moved.outline, outline, atol=1e-12):
            raise SiteGeometryError(
                f"as-built deviation x {self.scale:g} reorders the corners of opening {hole.name!r} "
                f"of slab {slab.name!r} (two corners within "
                f"{2 * self.scale * self.tolerances.opening_edge_m:.3f} m of the same lowest y): "
                "use a smaller scale"
            )
        return moved


def offset_edges(outline: NDArray[np.float64], offsets: NDArray[np.float64]) -> NDArray[np.float64]:
    """A counter-clockwise polygon with each edge moved outward along its normal.

    Edge ``i`` runs from corner ``i`` to ``i + 1`` and moves by ``offsets[i]`` metres; each
    corner is where its two moved edges meet. A corner between two parallel edges moves along
    their common normal by the mean offset.
    """
    p = np.asarray(outline, dtype=np.float64)
    d = np.asarray(offsets, dtype=np.float64)
    edge = np.roll(p, -1, axis=0) - p
    normal = np.column_stack([edge[:, 1], -edge[:, 0]]) / np.linalg.norm(edge, axis=1)[:, None]
    prev_n, prev_d = np.roll(normal, 1, axis=0), np.roll(d, 1)
    out = np.empty_like(p)
    for i in range(len(p)):
        A = np.array([prev_n[i], normal[i]])
        if abs(np.linalg.det(A)) < 1e-9:
            out[i] = p[i] + normal[i] * (prev_d[i] + d[i]) / 2
        else:
            out[i] = p[i] + np.linalg.solve(A, [prev_d[i], d[i]])
    return out


def _translated(mesh: TriangleMesh | None, shift: tuple[float, float, float]) -> TriangleMesh | None:
    if mesh is None:
        return None
    return TriangleMesh(mesh.vertices + np.asarray(shift), mesh.faces)


def make_as_built(value: AsBuilt | str | None) -> AsBuilt | None:
    """``None``, an :class:`AsBuilt`, or a tolerance model name (scale 1, seed 0)."""
    if value is None or isinstance(value, AsBuilt):
        return value
    if isinstance(value, str):
        return AsBuilt(value)
    raise SiteGeometryError(
        f"as_built must be None, an AsBuilt or one of {sorted(TOLERANCE_MODELS)}, got {value!r}"
    )


def max_landmark_shift(design: Site, built: Site, name: str = "all") -> float:
    """Largest distance between a landmark of ``design`` and the same-id landmark of ``built``, m."""
    a, b = design.landmarks(name), built.landmarks(name)
    if not np.array_equal(a.ids, b.ids):
        raise SiteGeometryError(f"the two sites expose different {name} landmarks")
    return float(np.linalg.norm(a.xyz - b.xyz, axis=1).max()) if len(a) else 0.0

