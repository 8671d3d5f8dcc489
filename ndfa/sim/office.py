"""What turns the simulator's room of tables into an open-plan office (the `office` preset):
monitors at the desks whose screens return no depth (a black, light-absorbing panel) or wrong
depth (a glossy one: the stereo matcher locks onto the reflection, metres behind the glass), and a
ceiling with strip lights. The desks' clutter and mugs are the simulator's own (`clutter_per_table`).

Each desk gets its monitors at its outer long edge (the side away from the room's middle, where
the walkway between the rows runs), screens facing the walkway, tilted back 10 degrees, on a post
within the desk's edge margin (where no mug or clutter stands). Screens carry instance ids from
`SCREEN_FIRST_ID` while rendering, so that their pixels can be found; `OfficeFixtures.sensor`
then changes their depth and clears the ids (a screen is neither an object nor a change).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.geometry import axis_angle_to_matrix, make_pose
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.scene import Room, Table

SCREEN_FIRST_ID = 60000  # instance ids of screens while rendering (mugs < 1001 <= clutter < this)
SCREEN_SIZE_M = (0.54, 0.32)
TILT_BACK_DEG = 10.0
LIGHT_SPACING_M = 2.0  # strip lights on a grid this far apart
LIGHT_SIZE_M = (1.2, 0.12, 0.04)


@dataclass(frozen=True)
class Monitor:
    """One monitor: its desk, where along the desk's length, its screen's instance id while
    rendering, and what the sensor reads on the screen: "none" (no depth) or "wrong" (the
    reflection: `wrong_offset_m` behind the glass)."""

    table_id: int
    x: float
    screen_id: int
    reading: str
    wrong_offset_m: float


@dataclass(frozen=True)
class OfficeFixtures:
    monitors: list[Monitor]
    ceiling: bool

    def render_parts(self, tables: list[Table], room: Room) -> list[tuple[Mesh, int, tuple[float, float, float]]]:
        """(mesh, instance id, colour) of every fixture in the level world: housings and posts
        (id 0), screens (their ids), the ceiling and its lights (id 0)."""
        parts: list[tuple[Mesh, int, tuple[float, float, float]]] = []
        for monitor in self.monitors:
            housing, screen = _monitor_meshes(monitor, tables[monitor.table_id - 1])
            parts += [(housing, 0, (0.12, 0.12, 0.13)), (screen, monitor.screen_id, (0.03, 0.03, 0.05))]
        if self.ceiling:
            parts += [(mesh, 0, colour) for mesh, colour in _ceiling(room)]
        return parts

    def sensor(self, depth: np.ndarray, instance: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """What the depth camera reads on the screens (see `Monitor`), and the instance image with
        the screens cleared."""
        if not self.monitors:
            return depth, instance
        depth, instance = depth.copy(), instance.copy()
        for monitor in self.monitors:
            screen = instance == monitor.screen_id
            if not screen.any():
                continue
            if monitor.reading == "none":
                depth[screen] = 0.0
            else:  # the reflection, with the speckle of a matcher on a mirror; some pixels find nothing
                reflected = depth[screen] + monitor.wrong_offset_m + rng.normal(0.0, 0.05, int(screen.sum()))
                depth[screen] = np.where(rng.random(reflected.shape) < 0.3, 0.0, reflected).astype(depth.dtype)
            instance[screen] = 0
        return depth, instance


def office_fixtures(tables: list[Table], monitors_per_table: int, ceiling: bool, rng: np.random.Generator) -> OfficeFixtures:
    """`monitors_per_table` monitors spread along each desk, each screen's reading drawn (half
    without depth, half with a reflection 0.5-1.5 m behind the glass)."""
    monitors = []
    for table in tables:
        length = table.size_xy[0]
        slots = (np.arange(monitors_per_table) + 0.5) / max(monitors_per_table, 1) * length - length / 2
        for x in slots:
            reading = "none" if rng.random() < 0.5 else "wrong"
            monitors.append(Monitor(table.table_id, float(x + rng.uniform(-0.05, 0.05)),
                                    SCREEN_FIRST_ID + len(monitors), reading, float(rng.uniform(0.5, 1.5))))
    return OfficeFixtures(monitors, ceiling)


def _monitor_meshes(monitor: Monitor, table: Table) -> tuple[Mesh, Mesh]:
    """Housing with its post, and the screen, in the world frame."""
    width, height = SCREEN_SIZE_M
    # The outer long edge: away from the room's middle (y = 0 between the rows).
    outward = 1.0 if table.center_xy[1] >= 0.0 else -1.0
    edge = outward * (table.size_xy[1] / 2 - 0.015)
    post = box_mesh((0.04, 0.025, 0.18), (monitor.x, edge, 0.09))
    # Built facing -y (screen on the -y face) with the panel's bottom edge as the tilt axis, then
    # turned to face the room's middle.
    tilt = make_pose(axis_angle_to_matrix(np.radians(TILT_BACK_DEG) * np.array([-1.0, 0.0, 0.0])), np.zeros(3))
    panel = box_mesh((width + 0.02, 0.03, height + 0.02), (0.0, 0.015, height / 2)).transformed(tilt)
    screen = box_mesh((width, 0.004, height), (0.0, -0.002, height / 2 + 0.01)).transformed(tilt)
    facing = make_pose(axis_angle_to_matrix(np.array([0.0, 0.0, 0.0 if outward > 0 else np.pi])),
                       np.array([monitor.x, edge + outward * 0.03, 0.12]))
    to_world = table.pose_world_top
    housing = Mesh.concatenate([post, panel.transformed(facing)]).transformed(to_world)
    return housing, screen.transformed(facing).transformed(to_world)


def _ceiling(room: Room) -> list[tuple[Mesh, tuple[float, float, float]]]:
    """The ceiling slab on the walls and strip lights on a grid below it."""
    lx, ly = room.size_xy
    t, h = room.wall_thickness, room.wall_height
    parts = [(box_mesh((lx + 2 * t, ly + 2 * t, t), (0.0, 0.0, h + t / 2)), (0.92, 0.92, 0.9))]
    xs = np.arange(-lx / 2 + LIGHT_SPACING_M / 2, lx / 2, LIGHT_SPACING_M)
    ys = np.arange(-ly / 2 + LIGHT_SPACING_M / 2, ly / 2, LIGHT_SPACING_M)
    for x in xs:
        for y in ys:
            parts.append((box_mesh(LIGHT_SIZE_M, (float(x), float(y), h - LIGHT_SIZE_M[2] / 2)), (1.0, 1.0, 1.0)))
    return parts
