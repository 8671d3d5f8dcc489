"""Clutter: things on the tables that are not mugs (boxes, books, bowls, bottles).

Why: a real table holds more than the objects of interest. Clutter tests that perception and the
detector do not take every object for a mug and do not report objects that did not change. It
stands still between the sessions, carries instance ids of its own (from `CLUTTER_FIRST_ID`, far
above any mug's), and the ground truth lists it apart from the mugs: it is never an object to
score and never a change.

Every shape is procedural, drawn from a seeded generator, in the same frame as a mug: z up,
base at z = 0, metres. Boxes, bowls and bottles are single closed meshes; a stack of books is
closed books touching each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.geometry import make_pose, rotation_z
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.mug_body import revolve_profile
from ndfa.sim.scene import Table

CLUTTER_KINDS = ("box", "books", "bowl", "bottle")
CLUTTER_FIRST_ID = 1001  # instance ids of clutter start here; mug ids stay below
_REVOLVE_SEGMENTS = 32


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
    def footprint_radius(self) -> float:
        """Radius of the circle about the object's axis that contains it seen from above."""
        return footprint_radius(self.mesh)

    def pose_world_object(self, table: Table) -> np.ndarray:
        return table.pose_world_top @ make_pose(rotation_z(self.yaw), np.array([*self.xy, 0.0]))


def footprint_radius(mesh: Mesh) -> float:
    return float(np.linalg.norm(mesh.vertices[:, :2], axis=1).max())


def make_clutter_mesh(kind: str, rng: np.random.Generator) -> Mesh:
    """A random object of `kind` (one of CLUTTER_KINDS), at most about 12 cm from its axis."""
    if kind == "box":
        size = rng.uniform([0.06, 0.06, 0.04], [0.16, 0.12, 0.2])
        return box_mesh(tuple(size), (0.0, 0.0, size[2] / 2))
    if kind == "books":
        return _book_stack(rng)
    if kind == "bowl":
        return revolve_profile(_bowl_profile(rng), _REVOLVE_SEGMENTS)
    if kind == "bottle":
        return revolve_profile(_bottle_profile(rng), _REVOLVE_SEGMENTS)
    raise ValueError(f"unknown clutter kind {kind!r}; expected one of {CLUTTER_KINDS}")


def _book_stack(rng: np.random.Generator) -> Mesh:
    """One to three books lying flat, each a little turned against the one below."""
    books, z = [], 0.0
    for _ in range(int(rng.integers(1, 4))):
        length, width, thickness = rng.uniform(0.13, 0.2), rng.uniform(0.1, 0.14), rng.uniform(0.015, 0.045)
        book = box_mesh((length, width, thickness), (0.0, 0.0, z + thickness / 2))
        books.append(book.transformed(make_pose(rotation_z(rng.uniform(-0.25, 0.25)), np.zeros(3))))
        z += thickness
    return Mesh.concatenate(books)


def _bowl_profile(rng: np.random.Generator) -> np.ndarray:
    """Closed (r, z) profile of a bowl, bottom pole to top pole (the centre of the inner floor),
    counter-clockwise around the material as `revolve_profile` wants it."""
    rim_r, height = rng.uniform(0.06, 0.09), rng.uniform(0.04, 0.07)
    foot_r, wall, floor = rim_r * rng.uniform(0.45, 0.6), 0.006, 0.008
    z_out = np.linspace(0.0, height, 10)[1:]
    outer = foot_r + (rim_r - foot_r) * np.sqrt(z_out / height)  # a rounded flare
    z_in = np.linspace(height, floor, 10)[1:]
    inner = foot_r - wall + (rim_r - foot_r) * np.sqrt((z_in - floor) / (height - floor))
    return np.concatenate([[[0.0, 0.0], [foot_r, 0.0]], np.c_[outer, z_out], [[rim_r - wall, height]],
                           np.c_[inner, z_in], [[0.0, floor]]])


def _bottle_profile(rng: np.random.Generator) -> np.ndarray:
    """Closed (r, z) profile of a bottle: body, shoulder, neck and cap, bottom pole to top pole."""
    body_r, height = rng.uniform(0.03, 0.045), rng.uniform(0.18, 0.3)
    neck_r = rng.uniform(0.011, 0.016)
    shoulder_z, neck_z = height * rng.uniform(0.55, 0.7), height * rng.uniform(0.8, 0.88)
    angles = np.linspace(0, np.pi / 2, 6)[1:]
    shoulder = np.c_[neck_r + (body_r - neck_r) * np.cos(angles), shoulder_z + (neck_z - shoulder_z) * np.sin(angles)]
    return np.concatenate([[[0.0, 0.0], [body_r - 0.004, 0.0], [body_r, 0.004], [body_r, shoulder_z]], shoulder,
                           [[neck_r, height - 0.01], [neck_r + 0.002, height - 0.01], [neck_r + 0.002, height],
                            [0.0, height]]])
