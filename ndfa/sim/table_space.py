"""Where a mug stands on a table (`Placement`), and free space on the table tops: where a mug (a
circle seen from above) can stand.

Tables here are any `ndfa.sim.scene.Table`, the boards of a shelf unit included (`ndfa.sim.shelves`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.geometry import make_pose, rotation_z
from ndfa.sim.categories import SceneModel
from ndfa.sim.scene import Table


@dataclass(frozen=True)
class Placement:
    """A mug instance standing on a table: position `xy` and `yaw` in the table-top frame."""

    instance_id: int
    model_id: str
    table_id: int
    xy: tuple[float, float]
    yaw: float

    def pose_world_object(self, table: Table) -> np.ndarray:
        """Object-to-world pose (mug frame: z-up, base at z = 0, axis on z)."""
        return table.pose_world_top @ make_pose(rotation_z(self.yaw), np.array([*self.xy, 0.0]))


def footprint_radius(mug: SceneModel) -> float:
    """Radius of the circle about the mug's axis that contains it seen from above (handle included)."""
    return float(np.linalg.norm(mug.mesh.vertices[:, :2], axis=1).max())


class TableSpace:
    """Free space on table tops, with mugs as circles: finds collision-free spots."""

    def __init__(self, tables: list[Table], mugs: dict[str, SceneModel], clearance: float = 0.01, edge_margin: float = 0.03):
        self.tables = tables
        self.radius = {model_id: footprint_radius(m) for model_id, m in mugs.items()}
        self.clearance = clearance
        self.edge_margin = edge_margin
        # table id -> {key: (xy, radius)}; the key is a mug's instance id (or any other hashable
        # name for things that are not one placement, as the clutter's).
        self.occupied: dict[int, dict[object, tuple[np.ndarray, float]]] = {t.table_id: {} for t in tables}

    def fits(self, table_id: int, xy: np.ndarray, radius: float) -> bool:
        half = np.array(self.tables[table_id - 1].size_xy) / 2 - radius - self.edge_margin
        if np.any(np.abs(xy) > half):
            return False
        return all(
            np.linalg.norm(xy - other_xy) >= radius + other_r + self.clearance
            for other_xy, other_r in self.occupied[table_id].values()
        )

    def add(self, placement: Placement) -> None:
        self.occupied[placement.table_id][placement.instance_id] = (
            np.array(placement.xy),
            self.radius[placement.model_id],
        )

    def find_spot(self, table_id: int, model_id: str, rng: np.random.Generator, tries: int = 300) -> np.ndarray | None:
        """A random collision-free position for `model_id` on the table, or None if none was found."""
        return self.find_spot_for_radius(table_id, self.radius[model_id], rng, tries)

    def find_spot_for_radius(self, table_id: int, radius: float, rng: np.random.Generator,
                             tries: int = 300) -> np.ndarray | None:
        """A random collision-free position for a circle of `radius`, or None if none was found."""
        half = np.array(self.tables[table_id - 1].size_xy) / 2 - radius - self.edge_margin
        if np.any(half <= 0):
            return None
        for _ in range(tries):
            xy = rng.uniform(-half, half)
            if self.fits(table_id, xy, radius):
                return xy
        return None
