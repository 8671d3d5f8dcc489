"""Shelf units: surfaces above one another (the `shelves` preset; issue 33, item 4).

A unit is an open shelf standing free in the room: two side panels, a top and 3-4 boards 25-35 cm
apart, with no back, so that it is seen from the front and from behind, as the tables are seen from
both sides. Each board is a `ShelfLevel`, a `Table` without legs, so everything that places objects
on tables, changes them and scores them works on shelves unchanged (a level's `table_id` is its
number in the scene, from 1). The units stand in a row along x, fronts towards -y.

The camera (`shelf_camera_poses`) passes along the row once per level, along each unit at that
unit's level's height plus `TrajectoryConfig.height_above_table_m`, looking at that level: from the front (`front`, the bottom
level first) or from behind (`back`, the top level first). From outside the unit, the board above
a level never hides it from a camera that looks down at it; the level below and above show at the
edges of the view, partly hidden by their boards.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.core.geometry import look_at
from ndfa.sim.handheld import handheld_poses
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.scene import Table
from ndfa.sim.trajectory import TrajectoryConfig, _gaussian_smooth, limit_turns, smooth_resample

SHELF_ROUTES = ("front", "back")
BOARD_M = 0.02      # board and panel thickness
OVERRUN_M = 0.3     # a pass runs this far past the row's ends, so the end units are seen from the side too


@dataclass(frozen=True)
class ShelfConfig:
    """The drawn shape of a scene's shelf units: inclusive ranges, each drawn per unit (spacing per gap)."""

    units: tuple[int, int] = (2, 3)
    levels: tuple[int, int] = (3, 4)                  # boards that hold objects, per unit
    spacing_m: tuple[float, float] = (0.25, 0.35)     # between two boards' top surfaces
    bottom_m: tuple[float, float] = (0.15, 0.35)      # the lowest board's top above the floor
    width_m: tuple[float, float] = (0.8, 1.0)
    depth_m: tuple[float, float] = (0.35, 0.4)
    gap_m: tuple[float, float] = (0.3, 0.6)           # between two units of the row

    def __post_init__(self) -> None:
        for name in ("units", "levels", "spacing_m", "bottom_m", "width_m", "depth_m", "gap_m"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise SimError(f"shelf {name} range {lo}-{hi} is empty")
        if self.units[0] < 1 or self.levels[0] < 1:
            raise SimError("a shelf scene needs at least one unit with one level")
        if self.spacing_m[0] < 0.15:
            raise SimError(f"shelf spacing from {self.spacing_m[0]:g} m leaves no room for a mug between two boards")


@dataclass(frozen=True)
class ShelfLevel(Table):
    """One board of a shelf unit as a surface to place objects on: a `Table` whose mesh is the
    board alone (the unit holds it). `unit` and `level` number the unit in the row and the board
    in the unit, from 1 at the bottom."""

    unit: int = 0
    level: int = 0
    top_thickness: float = BOARD_M

    def mesh(self) -> Mesh:
        length, width = self.size_xy
        return box_mesh((length, width, self.top_thickness), (0.0, 0.0, -self.top_thickness / 2)).transformed(
            self.pose_world_top)


@dataclass(frozen=True)
class ShelfUnit:
    """A unit's frame: two side panels and a top; its boards are `ShelfLevel`s."""

    unit_id: int
    center_xy: tuple[float, float]
    width: float
    depth: float
    level_heights: tuple[float, ...]   # the boards' top surfaces, bottom first
    height: float                      # the top's upper surface

    def mesh(self) -> Mesh:
        cx, cy = self.center_xy
        sides = [box_mesh((BOARD_M, self.depth, self.height), (cx + sx * (self.width - BOARD_M) / 2, cy, self.height / 2))
                 for sx in (-1, 1)]
        top = box_mesh((self.width, self.depth, BOARD_M), (cx, cy, self.height - BOARD_M / 2))
        return Mesh.concatenate([*sides, top])

    def as_dict(self) -> dict:
        return {"unit_id": self.unit_id, "center_xy": [round(c, 4) for c in self.center_xy],
                "width": round(self.width, 4), "depth": round(self.depth, 4),
                "level_heights": [round(h, 4) for h in self.level_heights], "height": round(self.height, 4)}


def shelf_units(config: ShelfConfig, rng: np.random.Generator) -> tuple[list[ShelfUnit], list[ShelfLevel]]:
    """The row of units drawn from `config`, centred on the origin, and their levels numbered as tables."""
    n_units = int(rng.integers(config.units[0], config.units[1], endpoint=True))
    widths = rng.uniform(*config.width_m, size=n_units)
    depths = rng.uniform(*config.depth_m, size=n_units)
    gaps = rng.uniform(*config.gap_m, size=max(n_units - 1, 0))
    starts = np.r_[0.0, np.cumsum(widths[:-1] + gaps)]
    centers_x = starts + widths / 2 - (starts[-1] + widths[-1]) / 2
    units: list[ShelfUnit] = []
    levels: list[ShelfLevel] = []
    for k in range(n_units):
        n_levels = int(rng.integers(config.levels[0], config.levels[1], endpoint=True))
        heights = float(rng.uniform(*config.bottom_m)) + np.r_[0.0, np.cumsum(rng.uniform(*config.spacing_m, size=n_levels))]
        unit = ShelfUnit(k + 1, (float(centers_x[k]), 0.0), float(widths[k]), float(depths[k]),
                         tuple(float(h) for h in heights[:-1]), float(heights[-1]))
        units.append(unit)
        for level, height in enumerate(unit.level_heights, start=1):
            levels.append(ShelfLevel(len(levels) + 1, unit.center_xy, (unit.width - 2 * BOARD_M, unit.depth), 0.0, height,
                                     unit=unit.unit_id, level=level))
    return units, levels


def shelf_camera_poses(units: list[ShelfUnit], route: str, config: TrajectoryConfig, rng: np.random.Generator,
                       fps: float = 5.0) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) along `route` past the row of `units` (the module docstring)."""
    if route not in SHELF_ROUTES:
        raise SimError(f"unknown shelf camera route {route!r}; expected one of {SHELF_ROUTES}")
    n_tiers = max(len(u.level_heights) for u in units)
    side = -1.0 if route == "front" else 1.0
    y = side * (max(u.depth for u in units) / 2 + config.clearance_m)
    row = sorted(units, key=lambda u: u.center_xy[0])
    order = range(n_tiers) if route == "front" else range(n_tiers - 1, -1, -1)
    waypoints = []
    for i, tier in enumerate(order):
        # Along each unit at its own level's height (a unit without this level: its top one), so
        # that the camera looks down at every level from the same height over it.
        ahead = [[x, y, _level(u, tier) + config.height_above_table_m]
                 for u in row for x in (u.center_xy[0] - u.width / 2, u.center_xy[0] + u.width / 2)]
        ahead[0][0] -= OVERRUN_M
        ahead[-1][0] += OVERRUN_M
        waypoints += ahead if i % 2 == 0 else ahead[::-1]
    eyes = smooth_resample(np.array(waypoints), config.step_m, config.smoothing_m, closed=False)
    wobble = _gaussian_smooth(rng.normal(size=(len(eyes), 1)), 1.0 / config.step_m, closed=False)[:, 0]
    eyes[:, 2] += wobble * config.height_wobble_m / max(float(np.abs(wobble).max()), 1e-9)
    targets = np.array([_gaze_target(units, eye, config) for eye in eyes])
    targets = _gaussian_smooth(targets, config.smoothing_m / config.step_m, closed=False)
    if config.motion == "handheld":
        return handheld_poses(eyes, targets, fps, config.handheld, rng)
    if config.max_turn_deg > 0:
        targets = eyes + limit_turns(targets - eyes, config.max_turn_deg)
    return np.stack([look_at(eye, target) for eye, target in zip(eyes, targets)])


def _level(unit: ShelfUnit, tier: int) -> float:
    return unit.level_heights[min(tier, len(unit.level_heights) - 1)]


def _gaze_target(units: list[ShelfUnit], eye: np.ndarray, config: TrajectoryConfig) -> np.ndarray:
    """The middle of the board the camera passes: on the unit nearest along x, the level the camera
    is nearest to looking down at."""
    unit = min(units, key=lambda u: max(abs(eye[0] - u.center_xy[0]) - u.width / 2, 0.0))
    height = min(unit.level_heights, key=lambda h: abs(eye[2] - config.height_above_table_m - h))
    half = unit.width / 2 - 0.1
    x = float(np.clip(eye[0], unit.center_xy[0] - half, unit.center_xy[0] + half))
    return np.array([x, unit.center_xy[1], height + config.look_height_m])
