"""Furniture along the walls: cabinets, shelves and sideboards that stand still between sessions.

Why: the simulator's room is a box with identical tables on a centred grid, so it nearly fits
itself turned half a turn or shifted by a table's pitch. A registration by the static scene
(`ndfa.run.scene_evidence`, docs/registration.md) rightly refuses such a room when the mugs, which
alone tell its copies apart, have changed; a real room is seldom so symmetric. Pieces of drawn
kinds and sizes at drawn places along the walls break the symmetry as a real room's furniture
does. They are part of the room (instance id 0): never an object, never a change.

A shelf is open: side panels, a back and boards, so that a sensor sees into it; cabinets and
sideboards are closed boxes. Each piece stands on the floor with its back against a wall, clear
of the corners and of the other pieces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.core.geometry import make_pose, rotation_z
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.scene import Room

# kind -> (width range, depth range, height range), metres
FURNITURE_SIZES = {
    "cabinet": ((0.5, 1.0), (0.4, 0.55), (1.4, 2.0)),
    "shelf": ((0.7, 1.2), (0.3, 0.4), (1.0, 1.9)),
    "sideboard": ((1.0, 1.8), (0.4, 0.5), (0.7, 0.95)),
}
CORNER_CLEARANCE_M = 0.15  # free wall next to a corner, and between two pieces
PANEL_M = 0.02             # a shelf's panel and board thickness
MAX_FURNITURE = 40         # more cannot stand along the walls of any room the simulator builds


@dataclass(frozen=True, eq=False)
class FurniturePiece:
    """One piece: its kind, which wall (0: y-, 1: x+, 2: y+, 3: x-), its center along that wall
    (metres from the wall's middle), its size (width along the wall, depth, height), its colour
    and its mesh in the world frame."""

    kind: str
    wall: int
    along_m: float
    size: tuple[float, float, float]
    color: tuple[float, float, float]
    mesh: Mesh

    def as_dict(self) -> dict:
        return {"kind": self.kind, "wall": self.wall, "along_m": round(self.along_m, 4),
                "size": [round(s, 4) for s in self.size]}


def wall_furniture(room: Room, count: int, rng: np.random.Generator) -> list[FurniturePiece]:
    """`count` pieces of drawn kinds and sizes at drawn places along the walls of `room`."""
    if not 0 <= count <= MAX_FURNITURE:
        raise SimError(f"furniture pieces must be in [0, {MAX_FURNITURE}], got {count}")
    lx, ly = room.size_xy
    lengths = (lx, ly, lx, ly)  # wall i runs along x (0, 2) or y (1, 3)
    taken: dict[int, list[tuple[float, float]]] = {wall: [] for wall in range(4)}
    pieces: list[FurniturePiece] = []
    kinds = sorted(FURNITURE_SIZES)
    for _ in range(count):
        for _attempt in range(100):
            kind = kinds[int(rng.integers(len(kinds)))]
            (w_lo, w_hi), (d_lo, d_hi), (h_lo, h_hi) = FURNITURE_SIZES[kind]
            size = (float(rng.uniform(w_lo, w_hi)), float(rng.uniform(d_lo, d_hi)), float(rng.uniform(h_lo, h_hi)))
            wall = int(rng.integers(4))
            free = lengths[wall] / 2 - CORNER_CLEARANCE_M - size[0] / 2
            if free <= 0:
                continue
            along = float(rng.uniform(-free, free))
            if any(abs(along - other) < (size[0] + width) / 2 + CORNER_CLEARANCE_M for other, width in taken[wall]):
                continue
            taken[wall].append((along, size[0]))
            red, green, blue = (float(c) for c in rng.uniform(0.2, 0.85, size=3))
            pieces.append(FurniturePiece(kind, wall, along, size, (red, green, blue), _mesh(kind, size, wall, along, room)))
            break
    return pieces


def _mesh(kind: str, size: tuple[float, float, float], wall: int, along: float, room: Room) -> Mesh:
    """The piece built with its back on the local y = 0 plane, facing +y, then put against `wall`."""
    width, depth, height = size
    if kind == "shelf":
        boards = max(2, int(height / 0.35))
        parts = [box_mesh((PANEL_M, depth, height), (sx * (width - PANEL_M) / 2, depth / 2, height / 2)) for sx in (-1, 1)]
        parts.append(box_mesh((width, PANEL_M, height), (0.0, PANEL_M / 2, height / 2)))
        parts += [box_mesh((width - 2 * PANEL_M, depth, PANEL_M), (0.0, depth / 2, z))
                  for z in np.linspace(PANEL_M / 2, height - PANEL_M / 2, boards + 1)]
        local = Mesh.concatenate(parts)
    else:
        local = box_mesh((width, depth, height), (0.0, depth / 2, height / 2))
    lx, ly = room.size_xy
    # Wall i's inner face and the turn that makes the piece face the room's middle.
    wall_pose = {0: (np.array([along, -ly / 2, 0.0]), 0.0), 1: (np.array([lx / 2, along, 0.0]), np.pi / 2),
                 2: (np.array([-along, ly / 2, 0.0]), np.pi), 3: (np.array([-lx / 2, -along, 0.0]), -np.pi / 2)}
    position, yaw = wall_pose[wall]
    return local.transformed(make_pose(rotation_z(yaw), position))
