"""Procedural boxes: a cuboid with rounded edges, and a lid that fits over its top on some.

Object frame: z up, metres, the base at z = 0, centred on the z axis, the longest side along x.
The kinds and their ranges (length x depth x height) follow real boxes: "carton" (shipping and
storage boxes: 15-45 cm, the depth 60-100% of the length, 10-35 cm high), "shoebox" (28-36 x
17-22 x 10-14 cm, a lid on 80%), "cereal" (cereal, tissue and detergent boxes standing upright:
19-30 x 5-9 x 25-33 cm), "small" (tea, jewellery, match and pill boxes: 4-15 cm long, 2-10 cm
high, more rounded, a lid on 40%), "flat" (pizza boxes, board games, books lying down: 15-40 cm,
2-6 cm high).

A rounded cuboid is the convex hull of a small sphere in each of its eight corners (its Minkowski
sum with a ball), made by trimesh: closed and convex. The lid is a second closed part overlapping
the body's top, as a lid does (occupancy is the union of the parts, as for a mug's handle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.sim.mesh import Mesh

BOX_KINDS = ("carton", "shoebox", "cereal", "small", "flat")

# kind: (length m, depth as a fraction of the length, height m, edge radius m, share with a lid)
_BOX_RANGES = {
    "carton": ((0.15, 0.45), (0.6, 1.0), (0.1, 0.35), (0.0005, 0.004), 0.0),
    "shoebox": ((0.28, 0.36), (0.55, 0.65), (0.1, 0.14), (0.0005, 0.003), 0.8),
    "cereal": ((0.19, 0.3), (0.2, 0.35), (0.25, 0.33), (0.0005, 0.003), 0.0),
    "small": ((0.04, 0.15), (0.5, 1.0), (0.02, 0.1), (0.001, 0.008), 0.4),
    "flat": ((0.15, 0.4), (0.6, 1.0), (0.02, 0.06), (0.0005, 0.004), 0.3),
}


@dataclass(frozen=True)
class BoxParams:
    kind: str = "carton"  # one of BOX_KINDS
    length: float = 0.3  # along x, the longest side
    depth: float = 0.2  # along y
    height: float = 0.2  # base to the top (of the lid, if any)
    edge_radius: float = 0.002  # the rounding of every edge and corner
    lid_height: float = 0.0  # how far the lid reaches down the sides (0: no lid)
    lid_overhang: float = 0.0  # how far the lid stands out from the sides
    lid_thickness: float = 0.0  # the lid's top


def sample_box_params(rng: np.random.Generator) -> BoxParams:
    kind = str(rng.choice(BOX_KINDS, p=[0.3, 0.15, 0.2, 0.2, 0.15]))
    length_range, depth_ratio, height_range, edge_range, lid_share = _BOX_RANGES[kind]
    length = rng.uniform(*length_range)
    depth = length * rng.uniform(*depth_ratio)
    if kind == "cereal":  # its depth is 5-9 cm whatever its width
        depth = float(np.clip(depth, 0.05, 0.09))
    height = rng.uniform(*height_range)
    edge = min(rng.uniform(*edge_range), 0.2 * min(length, depth, height))
    lid = dict(lid_height=0.0, lid_overhang=0.0, lid_thickness=0.0)
    if rng.random() < lid_share:
        lid = dict(lid_height=rng.uniform(0.25, 0.5) * min(height, 0.1), lid_overhang=rng.uniform(0.001, 0.004),
                   lid_thickness=rng.uniform(0.0015, 0.004))
    values = dict(kind=kind, length=length, depth=depth, height=height, edge_radius=edge, **lid)
    return BoxParams(**{k: float(v) if isinstance(v, np.floating) else v for k, v in values.items()})


def rounded_cuboid(size: tuple[float, float, float], radius: float, bottom: float) -> Mesh:
    """A closed cuboid of full extents `size`, centred on the z axis, its base at z = `bottom`, every
    edge rounded by `radius` (0: sharp)."""
    import trimesh

    half = np.asarray(size, dtype=float) / 2 - radius
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    ball = trimesh.creation.icosphere(subdivisions=2, radius=radius).vertices if radius > 0 else np.zeros((1, 3))
    points = (corners[:, None, :] + ball[None, :, :]).reshape(-1, 3) + [0.0, 0.0, bottom + size[2] / 2]
    hull = trimesh.convex.convex_hull(points)
    return Mesh(np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int32))


def box_parts(p: BoxParams) -> list[Mesh]:
    """The body, and the lid over its top where it has one."""
    if p.lid_height <= 0:
        return [rounded_cuboid((p.length, p.depth, p.height), p.edge_radius, 0.0)]
    body_height = p.height - p.lid_thickness
    lid = (p.length + 2 * p.lid_overhang, p.depth + 2 * p.lid_overhang, p.lid_height)
    return [rounded_cuboid((p.length, p.depth, body_height), p.edge_radius, 0.0),
            rounded_cuboid(lid, min(p.edge_radius + p.lid_overhang, 0.45 * min(lid)), p.height - p.lid_height)]
