"""An object made of closed parts that may overlap (a mug's body and handle, a box and its lid):
the one place that says how such an object is rendered (`mesh`) and what lies inside it
(`occupancy`). `ndfa.sim.mug.Mug` and `ndfa.sim.categories.CategoryObject` are such objects.

Occupancy is the union of the parts' occupancies, each from its own Open3D `RaycastingScene`:
ray-parity occupancy over one scene holding overlapping parts would call the overlap "outside".
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.mesh import Mesh


class PartsSolid:
    """Mixin of a dataclass with `model_id: str`, `parts: list[Mesh]` (closed meshes in the
    object's frame) and optionally `watertight: bool` (every part closed, so occupancy is exact)."""

    model_id: str
    parts: list[Mesh]
    watertight: bool = True

    @cached_property
    def mesh(self) -> Mesh:
        """All parts in one mesh, for rendering (overlaps are kept, there is no boolean union)."""
        return Mesh.concatenate(self.parts)

    @cached_property
    def _part_scenes(self) -> list:
        """One `RaycastingScene` per part, built on first use."""
        import open3d as o3d

        scenes = []
        for part in self.parts:
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(part.to_open3d_tensor())
            scenes.append(scene)
        return scenes

    def part_occupancy(self, points: np.ndarray) -> np.ndarray:
        """Whether each of `points` (N, 3), in the object frame, is inside each part: bool (parts, N)."""
        if not self.watertight:
            raise SimError(f"{self.model_id}: exact occupancy is unavailable, its mesh is not watertight")
        import open3d as o3d

        query = o3d.core.Tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3))
        # Three rays per point and a majority vote: a single ray grazing an edge of the mesh
        # would count the crossing twice (or not at all) and flip the answer.
        return np.stack([scene.compute_occupancy(query, nsamples=3).numpy().astype(bool) for scene in self._part_scenes])

    def occupancy(self, points: np.ndarray) -> np.ndarray:
        """Whether each of `points` (N, 3), in the object frame, is inside the object: bool (N,)."""
        inside: np.ndarray = self.part_occupancy(points).any(axis=0)
        return inside
