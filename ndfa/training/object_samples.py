"""Per-object quantities that labelling training views needs: the object's center, its bounding
box and points on its surface, computed once per object and cached. An object is any
`ndfa.sim.solid.PartsSolid`: a mug, or an object of another category (`ndfa.sim.categories`).

The center of an object (`object_center`) is the centroid of its solid volume (the union of its
parts). The first part (a mug's body, a bottle's body, a box without its lid) is integrated
exactly over its closed mesh; what the other parts (a handle, a cap, a lid) add outside it is
estimated with one random point per cell of a 1 mm grid: within 0.05 mm of the exact centroid.
Not the mean of the visible points, not the centre of the bounding box: the detector's center
error is measured against it.

Everything here is in the object frame, metres.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ndfa.sim.mesh import Mesh
from ndfa.sim.solid import PartsSolid

CENTER_GRID_M = 0.001  # cell size of the grid that adds the other parts to an object's center
SURFACE_SAMPLES = 8192  # surface points cached per object, the seeds of the near-surface queries


@dataclass(frozen=True)
class ObjectSamples:
    """What labelling views of one object needs, computed once per object. Object frame, metres."""

    center: np.ndarray   # (3,) centroid of the solid volume
    box_min: np.ndarray  # (3,) corners of the mesh's axis-aligned bounding box
    box_max: np.ndarray  # (3,)
    surface: np.ndarray  # (S, 3) points on the surface of the solid


# Keyed by id(object); the entry holds the object itself, so the id cannot be reused while cached.
_SAMPLES_CACHE: OrderedDict[int, tuple[PartsSolid, ObjectSamples]] = OrderedDict()
_SAMPLES_CACHE_SIZE = 256


def object_center(solid: PartsSolid) -> np.ndarray:
    """(3,) the object's center in its frame: the centroid of its solid volume (cached)."""
    return object_samples(solid).center.copy()


def object_samples(solid: PartsSolid) -> ObjectSamples:
    """The object's cached `ObjectSamples` (computed on first use; the 256 most recent objects are kept)."""
    if id(solid) in _SAMPLES_CACHE:
        _SAMPLES_CACHE.move_to_end(id(solid))
        return _SAMPLES_CACHE[id(solid)][1]
    box_min, box_max = solid.mesh.bounds
    rng = np.random.default_rng(0)  # a fixed seed: the samples are part of the object, not of a view
    samples = ObjectSamples(
        center=_solid_centroid(solid, CENTER_GRID_M, rng),
        box_min=box_min,
        box_max=box_max,
        surface=_surface_samples(solid, SURFACE_SAMPLES, rng),
    )
    _SAMPLES_CACHE[id(solid)] = (solid, samples)
    if len(_SAMPLES_CACHE) > _SAMPLES_CACHE_SIZE:
        _SAMPLES_CACHE.popitem(last=False)
    return samples


def _solid_centroid(solid: PartsSolid, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """(3,) centroid of the union of the object's parts. The first part is integrated exactly over
    its closed mesh; the rest adds the points inside the object but not inside the first part,
    among one random point per cell of a grid over the other parts' box (random, not the cell
    centres: thin walls alias on a regular grid)."""
    volume, moment = _volume_and_moment(solid.parts[0])
    if len(solid.parts) > 1:
        low, high = Mesh.concatenate(solid.parts[1:]).bounds
        axes = [np.arange(a + spacing / 2, b, spacing) for a, b in zip(low, high)]
        cells = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        points = cells + rng.uniform(-spacing / 2, spacing / 2, size=cells.shape)
        inside = solid.part_occupancy(points)
        added = points[inside[1:].any(axis=0) & ~inside[0]]
        volume += len(added) * spacing**3
        moment = moment + added.sum(axis=0) * spacing**3
    return moment / volume


def _volume_and_moment(mesh: Mesh) -> tuple[float, np.ndarray]:
    """Volume (m^3) and first moment (3,) of the solid inside a closed mesh: the sum over the
    tetrahedra spanned by the origin and each triangle (divergence theorem)."""
    a, b, c = (mesh.vertices[mesh.triangles[:, i]] for i in range(3))
    signed_volumes = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6
    volume, moment = signed_volumes.sum(), signed_volumes @ ((a + b + c) / 4)
    return (volume, moment) if volume > 0 else (-volume, -moment)  # inward winding flips both signs


def _surface_samples(solid: PartsSolid, count: int, rng: np.random.Generator) -> np.ndarray:
    """Up to `count` points (S, 3) spread uniformly by area over the surface of the solid."""
    corners = solid.mesh.vertices[solid.mesh.triangles]  # (F, 3, 3)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    faces = rng.choice(len(corners), size=count, p=double_area / double_area.sum())
    a, b = rng.random((2, count, 1))
    outside_triangle = a + b > 1  # fold the far half of the parallelogram back into the triangle
    a[outside_triangle], b[outside_triangle] = 1 - a[outside_triangle], 1 - b[outside_triangle]
    c = corners[faces]
    points = c[:, 0] + a * (c[:, 1] - c[:, 0]) + b * (c[:, 2] - c[:, 0])
    # The parts overlap (a handle's ends are buried in the wall, a lid over a box's top): keep the
    # points with air half a millimetre outside them (the thinnest walls, a paper cup's, are
    # 1.5 mm), the surface of the union.
    normals = cross[faces] / double_area[faces, None]
    return points[~solid.occupancy(points + 0.0005 * normals)]
