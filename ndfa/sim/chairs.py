"""Chairs pushed in at the tables: static, part of the room (instance id 0), never an object.

Why: a real room's tables have chairs, and a chair pushed in shows the top rail of its back just
outside the table's edge, a few centimetres above the top. On the 7-Scenes kitchen that rail's
segment stood on the table's plane with a small box's size, and the objects' gate kept it (a false
"added"; docs/categories.md, "Objects in real rooms"). The simulator's rooms had no such thing.

A chair: a square seat on four legs, its two back legs going on up as the back's posts, a top rail
between them. Pushed in: the back stands `gap` outside a long side of the table (the seat under the
top), its top `back_above_m` above the table's top. Chairs on a side stand clear of the table's legs
and of each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.scene import Table

SEAT_M = 0.42            # the seat's width and depth
SEAT_HEIGHT_M = 0.45     # its top above the floor
POST_M = 0.03            # legs and posts, square
RAIL_M = 0.05            # the top rail's height
BACK_ABOVE_M = (0.03, 0.15)  # the back's top above the table's top
GAP_M = (0.005, 0.05)        # from the table's edge to the back's inner face
CHAIR_CLEARANCE_M = 0.04     # between two chairs on a side, and from a table's leg
MAX_CHAIRS = 4               # per table


@dataclass(frozen=True, eq=False)
class Chair:
    """One chair: its table, side (+1 / -1: the table's local +y / -y long side), centre along the
    table's length (metres from its middle), the back's height above the table's top and its gap
    to the table's edge, its colour and its mesh in the world frame."""

    table_id: int
    side: int
    along_m: float
    back_above_m: float
    gap_m: float
    color: tuple[float, float, float]
    mesh: Mesh

    def as_dict(self) -> dict:
        return {"table_id": self.table_id, "side": self.side, "along_m": round(self.along_m, 4),
                "back_above_m": round(self.back_above_m, 4), "gap_m": round(self.gap_m, 4)}


def table_chairs(tables: list[Table], per_table: int, rng: np.random.Generator) -> list[Chair]:
    """Up to `per_table` chairs pushed in at each table, on its long sides in turn, as many as fit."""
    chairs: list[Chair] = []
    for table in tables:
        length, width = table.size_xy
        # The chairs' centres stay within `reach` of the middle: clear of the legs (2 leg widths in).
        reach = length / 2 - 2.5 * table.leg_width - CHAIR_CLEARANCE_M - SEAT_M / 2
        if reach < 0:
            continue
        fit = 1 + int(2 * reach // (SEAT_M + CHAIR_CLEARANCE_M))
        wanted = {1: (min(per_table, 2 * fit) + 1) // 2, -1: min(per_table, 2 * fit) // 2}
        for side, count in wanted.items():
            if count == 0:
                continue
            slots = np.linspace(-reach, reach, count) if count > 1 else np.array([rng.uniform(-reach, reach)])
            for along in slots:
                back_above, gap = float(rng.uniform(*BACK_ABOVE_M)), float(rng.uniform(*GAP_M))
                red, green, blue = (float(c) for c in rng.uniform(0.25, 0.7, size=3))
                mesh = _chair_mesh(table, side, float(along), back_above, gap)
                chairs.append(Chair(table.table_id, side, float(along), back_above, gap, (red, green, blue), mesh))
    return chairs


def _chair_mesh(table: Table, side: int, along: float, back_above: float, gap: float) -> Mesh:
    """The chair in the table's top frame (z = 0 the top's surface, the floor at -height), then
    into the world."""
    width = table.size_xy[1]
    floor = -table.height
    seat_top = floor + SEAT_HEIGHT_M
    back_out = width / 2 + gap + POST_M       # the back's outer face (distance from the table's axis)
    back_in = back_out - POST_M
    seat_in = back_out - SEAT_M               # the seat's front, under the table
    parts = [box_mesh((SEAT_M, SEAT_M, 0.03), (along, side * (back_out + seat_in) / 2, seat_top - 0.015))]
    for dx in (-1, 1):
        x = along + dx * (SEAT_M - POST_M) / 2
        front_leg = seat_in + POST_M / 2
        parts.append(box_mesh((POST_M, POST_M, SEAT_HEIGHT_M - 0.03), (x, side * front_leg, floor + (SEAT_HEIGHT_M - 0.03) / 2)))
        post_height = back_above - floor      # the back leg, from the floor up to the back's top
        parts.append(box_mesh((POST_M, POST_M, post_height), (x, side * (back_in + POST_M / 2), floor + post_height / 2)))
    parts.append(box_mesh((SEAT_M - 2 * POST_M, POST_M, RAIL_M), (along, side * (back_in + POST_M / 2), back_above - RAIL_M / 2)))
    return Mesh.concatenate(parts).transformed(table.pose_world_top)

