"""Clutter: what stands on the tables beside the scene's objects, and does not change.

Why: a real table holds more than the objects a scene changes. Clutter is of two sorts:

- **objects** of the categories beside the mugs (`CLUTTER_CATEGORIES`: bowls, cups, bottles, cans,
  boxes; `ndfa.sim.categories.make_object`), rigid things standing on the table that a detector of
  every category should find, and never report changed;
- **non-objects** (`NON_OBJECTS`): papers lying flat (a sheet to a magazine's stack) and cables
  lying in curves, which the segmentation's objectness gate must turn away.

It stands still between the sessions, carries instance ids of its own (from `CLUTTER_FIRST_ID`, far
above any object's), and the ground truth lists it apart from the scene's objects, each item with
its `category` (None for a non-object): never an object to score as changed and never a change.

Every shape is procedural, drawn from a seeded generator, in the same frame as a mug: z up,
base at z = 0, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.geometry import make_pose, rotation_z
from ndfa.sim.categories import make_object
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.mug_handle import sweep_tube
from ndfa.sim.scene import Table
from ndfa.sim.splits import TEST_SEEDS

CLUTTER_CATEGORIES = ("bowl", "cup", "bottle", "can", "box")
NON_OBJECTS = ("paper", "cable")
CLUTTER_KINDS = CLUTTER_CATEGORIES + NON_OBJECTS
CLUTTER_FIRST_ID = 1001  # instance ids of clutter start here; mug ids stay below
# The widest clutter object, from its axis: a table keeps room for the scene's objects.
MAX_CLUTTER_RADIUS_M = 0.12


@dataclass(frozen=True, eq=False)
class ClutterItem:
    """One piece of clutter standing on a table at `xy`, turned by `yaw` (table-top frame)."""

    instance_id: int
    kind: str
    table_id: int
    xy: tuple[float, float]
    yaw: float
    mesh: Mesh                      # in the object's own frame (z up, base at z = 0)
    color: tuple[float, float, float]

    @property
    def category(self) -> str | None:
        """The object category of an object (`CLUTTER_CATEGORIES`), None for a non-object."""
        return self.kind if self.kind in CLUTTER_CATEGORIES else None

    @property
    def footprint_radius(self) -> float:
        """Radius of the circle about the object's axis that contains it seen from above."""
        return footprint_radius(self.mesh)

    def pose_world_object(self, table: Table) -> np.ndarray:
        return table.pose_world_top @ make_pose(rotation_z(self.yaw), np.array([*self.xy, 0.0]))


def footprint_radius(mesh: Mesh) -> float:
    return float(np.linalg.norm(mesh.vertices[:, :2], axis=1).max())


def make_clutter_mesh(kind: str, rng: np.random.Generator) -> Mesh:
    """A random object or non-object of `kind` (one of CLUTTER_KINDS), at most about 18 cm from its
    axis (an object: `MAX_CLUTTER_RADIUS_M`)."""
    if kind in CLUTTER_CATEGORIES:
        for _ in range(100):  # a test-split object of the category narrow enough
            mesh = make_object(kind, int(rng.integers(TEST_SEEDS.start, TEST_SEEDS.stop))).mesh
            if footprint_radius(mesh) <= MAX_CLUTTER_RADIUS_M:
                return mesh
        return mesh
    if kind == "paper":
        return _paper(rng)
    if kind == "cable":
        return _cable(rng)
    raise ValueError(f"unknown clutter kind {kind!r}; expected one of {CLUTTER_KINDS}")


def _paper(rng: np.random.Generator) -> Mesh:
    """Paper lying flat: an A5 to A4 sheet, a notepad or a magazine, 1 mm to 1.2 cm thick."""
    length, width = rng.uniform(0.15, 0.3), rng.uniform(0.1, 0.21)
    thickness = rng.uniform(0.001, 0.012)
    return box_mesh((length, width, thickness), (0.0, 0.0, thickness / 2))


def _cable(rng: np.random.Generator) -> Mesh:
    """A cable lying on the table in a wave: 3-8 mm thick, 20-32 cm end to end."""
    length, amplitude = rng.uniform(0.2, 0.32), rng.uniform(0.01, 0.05)
    waves, phase, radius = rng.uniform(0.5, 2.0), rng.uniform(0, 2 * np.pi), rng.uniform(0.0015, 0.004)
    x = np.linspace(-length / 2, length / 2, 40)
    angle = 2 * np.pi * waves * x / length + phase
    # In the xz plane as `sweep_tube` takes it, then laid down: z becomes the table's y.
    points = np.c_[x, np.zeros_like(x), amplitude * np.sin(angle)]
    tangents = np.c_[np.ones_like(x), np.zeros_like(x), amplitude * 2 * np.pi * waves / length * np.cos(angle)]
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    lay_down = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, radius], [0.0, 0.0, 0.0, 1.0]])
    return sweep_tube(points, tangents, radius, radius).transformed(lay_down)
