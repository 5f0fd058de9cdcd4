"""Buildings the IFC tests share: the real duplex file and a messy synthetic site written as IFC.

Plain functions (a helper module, not a test module), imported by tests/site and tests/study.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import trimesh

from uav_struct_env.site.elements import Beam, Column, Slab, Stage, Storey, TriangleMesh
from uav_struct_env.site.model import Site
from uav_struct_env.site.polygons import rectangle

#: The real IFC file shipped for tests (buildingSMART's Duplex Apartment, CC BY 4.0; NOTICE beside it).
DUPLEX = Path(__file__).resolve().parents[1] / "data" / "ifc" / "duplex.ifc"


def box_mesh(lo, hi, slope: float = 0.0) -> TriangleMesh:
    box = trimesh.creation.box(bounds=[lo, hi])
    v = np.array(box.vertices)
    top = v[:, 2] > (lo[2] + hi[2]) / 2
    v[top, 2] += slope * (v[top, 0] - lo[0])
    return TriangleMesh(v, np.array(box.faces))


def messy_site() -> Site:
    """Duplicates, a finish floor, precast planks, a balcony, a sloped roof and a beam, over 4 storeys."""
    storeys = (Storey("Ground", 0.0), Storey("L1", 3.0), Storey("L2", 6.0), Storey("Top", 9.0))
    cols = [Column(guid=f"c{k}", name=f"c{k}", storey=0, axis=(x, y), z_bottom=0.0, z_top=2.75,
                   outline=rectangle(x - .2, y - .2, x + .2, y + .2))
            for k, (x, y) in enumerate([(0, 0), (8, 0), (8, 6), (0, 6)])]
    up = [dataclasses.replace(c, guid=f"u{c.guid}", name=f"u{c.name}", storey=1, z_bottom=3.0, z_top=5.75)
          for c in cols]
    floor = Slab(guid="s1", name="floor", storey=1, outline=rectangle(-.5, -.5, 8.5, 6.5),
                 z_bottom=2.75, z_top=3.0)
    twin = dataclasses.replace(floor, guid="s1-copy", name="floor copy")
    finish = Slab(guid="fin", name="finish", storey=1, outline=rectangle(0, 0, 4, 4),
                  z_bottom=3.0, z_top=3.015)
    # Level 2: two precast planks with a 2 cm joint -> one slab; a third 1 m away stays separate.
    plank_a = Slab(guid="pa", name="plank a", storey=2, outline=rectangle(-.5, -.5, 4.0, 6.5), z_bottom=5.75,
                   z_top=6.0)
    plank_b = Slab(guid="pb", name="plank b", storey=2, outline=rectangle(4.02, -.5, 8.5, 6.5), z_bottom=5.75,
                   z_top=6.0)
    balcony = Slab(guid="bal", name="balcony", storey=2, outline=rectangle(9.5, 0, 11, 6),
                   z_bottom=5.8, z_top=6.0)
    roof = Slab(guid="roof", name="roof", storey=3, outline=rectangle(-.5, -.5, 8.5, 6.5),
                z_bottom=9.0, z_top=9.3, mesh=box_mesh((-.5, -.5, 9.0), (8.5, 6.5, 9.3), slope=0.1))
    beam = Beam(guid="b0", name="beam", storey=1, outline=rectangle(0, -.1, 8, .1), z_bottom=5.4, z_top=5.75)
    elements = (*cols, *up, floor, twin, finish, plank_a, plank_b, balcony, roof, beam)
    stage = Stage("all", frozenset(e.guid for e in elements), ("s1",))
    return Site(elements=elements, storeys=storeys, stages=(stage,), stage="all", name="messy")
