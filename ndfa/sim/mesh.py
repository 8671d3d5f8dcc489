"""A plain triangle mesh as numpy arrays: the one mesh type the simulator passes around."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.geometry import transform_points


@dataclass(frozen=True)
class Mesh:
    """Triangle mesh in metres. `vertices` (V, 3) float64, `triangles` (F, 3) int32, outward
    (counter-clockwise seen from outside) winding."""

    vertices: np.ndarray
    triangles: np.ndarray

    def transformed(self, pose: np.ndarray) -> "Mesh":
        """The mesh moved by a 4x4 pose."""
        return Mesh(transform_points(pose, self.vertices), self.triangles)

    @staticmethod
    def concatenate(meshes: list["Mesh"]) -> "Mesh":
        """One mesh holding all triangles of `meshes` (parts may overlap; no boolean union)."""
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return Mesh(
            np.concatenate([m.vertices for m in meshes]),
            np.concatenate([m.triangles + o for m, o in zip(meshes, offsets)]).astype(np.int32),
        )

    def to_open3d(self):
        """Legacy `open3d.geometry.TriangleMesh` (for I/O and watertightness checks)."""
        import open3d as o3d

        return o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices), o3d.utility.Vector3iVector(self.triangles)
        )

    def to_open3d_tensor(self):
        """Tensor `open3d.t.geometry.TriangleMesh` (float32), as `RaycastingScene` wants it."""
        import open3d as o3d

        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(self.vertices.astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(self.triangles.astype(np.int32))
        return mesh

    def is_watertight(self) -> bool:
        """Closed two-manifold without self-intersections, as Open3D judges it."""
        return bool(self.to_open3d().is_watertight())

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned (min, max) corners."""
        return self.vertices.min(axis=0), self.vertices.max(axis=0)


def box_mesh(size: tuple[float, float, float], center: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Mesh:
    """Closed axis-aligned box with the given full extents, centred at `center`."""
    sx, sy, sz = (s / 2.0 for s in size)
    corners = np.array(
        [[x, y, z] for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)], dtype=float
    ) + np.asarray(center, dtype=float)
    # Corner index = 4*z + 2*y + x with each of x, y, z in {0, 1}; faces wound outward.
    triangles = np.array(
        [
            [0, 2, 1], [1, 2, 3],  # bottom (z-)
            [4, 5, 6], [5, 7, 6],  # top (z+)
            [0, 1, 4], [1, 5, 4],  # y-
            [2, 6, 3], [3, 6, 7],  # y+
            [0, 4, 2], [2, 4, 6],  # x-
            [1, 3, 5], [3, 7, 5],  # x+
        ],
        dtype=np.int32,
    )
    return Mesh(corners, triangles)
