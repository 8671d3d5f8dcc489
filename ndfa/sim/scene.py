"""The static room: floor, walls and tables, as meshes in the world frame.

World frame: z-up, metres, origin at the room's floor centre. Tables are numbered from 1, as the
paper numbers them, row by row.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.geometry import make_pose, rotation_z, transform_points
from ndfa.sim.mesh import Mesh, box_mesh


@dataclass(frozen=True)
class Table:
    """A rectangular table. `center_xy` is the top's centre, `size_xy` its full length along the
    table's own x axis and width along its y axis, `yaw` its rotation about world z, `height` the
    z of the top surface."""

    table_id: int
    center_xy: tuple[float, float]
    size_xy: tuple[float, float] = (1.2, 0.8)
    yaw: float = 0.0
    height: float = 0.75
    top_thickness: float = 0.03
    leg_width: float = 0.05

    @property
    def pose_world_top(self) -> np.ndarray:
        """Pose of the table-top frame: origin at the top surface centre, z up, x along the length."""
        return make_pose(rotation_z(self.yaw), np.array([*self.center_xy, self.height]))

    def mesh(self) -> Mesh:
        """Top slab and four legs, in the world frame."""
        length, width = self.size_xy
        parts = [box_mesh((length, width, self.top_thickness), (0.0, 0.0, -self.top_thickness / 2))]
        leg_height = self.height - self.top_thickness
        inset_x, inset_y = length / 2 - 2 * self.leg_width, width / 2 - 2 * self.leg_width
        for sx in (-1, 1):
            for sy in (-1, 1):
                parts.append(
                    box_mesh(
                        (self.leg_width, self.leg_width, leg_height),
                        (sx * inset_x, sy * inset_y, -self.top_thickness - leg_height / 2),
                    )
                )
        return Mesh.concatenate(parts).transformed(self.pose_world_top)

    def distance_xy(self, points_xy: np.ndarray) -> np.ndarray:
        """Horizontal distance from points (N, 2) to the table's footprint rectangle (0 inside)."""
        local = transform_points(np.linalg.inv(self.pose_world_top), np.c_[points_xy, np.zeros(len(points_xy))])
        half = np.array(self.size_xy) / 2
        outside = np.maximum(np.abs(local[:, :2]) - half, 0.0)
        return np.linalg.norm(outside, axis=1)


@dataclass(frozen=True)
class Room:
    """A box-shaped room: floor at z = 0 and four walls, centred on the origin."""

    size_xy: tuple[float, float]
    wall_height: float = 2.5
    wall_thickness: float = 0.1

    def meshes(self) -> list[Mesh]:
        """Floor and walls (each a closed box) in the world frame."""
        lx, ly = self.size_xy
        t, h = self.wall_thickness, self.wall_height
        return [
            box_mesh((lx + 2 * t, ly + 2 * t, t), (0.0, 0.0, -t / 2)),
            box_mesh((lx + 2 * t, t, h), (0.0, -(ly + t) / 2, h / 2)),
            box_mesh((lx + 2 * t, t, h), (0.0, (ly + t) / 2, h / 2)),
            box_mesh((t, ly, h), (-(lx + t) / 2, 0.0, h / 2)),
            box_mesh((t, ly, h), ((lx + t) / 2, 0.0, h / 2)),
        ]


def table_grid(
    rows: int,
    cols: int,
    table_size_xy: tuple[float, float] = (1.2, 0.8),
    gap_xy: tuple[float, float] = (1.0, 1.6),
    height: float = 0.75,
) -> list[Table]:
    """Tables on a `rows` x `cols` grid centred on the origin, numbered row by row from 1.
    `gap_xy` is the free space between neighbouring tables (the corridors a camera moves in)."""
    pitch = np.array(table_size_xy) + np.array(gap_xy)
    tables = []
    for row in range(rows):
        for col in range(cols):
            center = (np.array([col, row]) - (np.array([cols, rows]) - 1) / 2) * pitch
            tables.append(Table(len(tables) + 1, (float(center[0]), float(center[1])), table_size_xy, 0.0, height))
    return tables


def room_around(tables: list[Table], margin: float = 1.6) -> Room:
    """The smallest centred room that leaves `margin` metres of floor around every table."""
    corners = np.concatenate(
        [transform_points(t.pose_world_top, np.array([[sx * t.size_xy[0] / 2, sy * t.size_xy[1] / 2, 0.0]
                                                      for sx in (-1, 1) for sy in (-1, 1)])) for t in tables]
    )
    half = np.abs(corners[:, :2]).max(axis=0) + margin
    return Room((float(2 * half[0]), float(2 * half[1])))
