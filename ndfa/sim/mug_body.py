"""The body of a procedural mug: a surface of revolution of one closed (r, z) profile.

The profile runs from the bottom pole (on the axis, under the base) out along the underside, up
the outer wall, over the rounded rim, down the inner wall and across the cavity floor to the top
pole (on the axis, at the floor). Both poles are single vertices, so the revolved mesh is a
closed genus-0 surface. Mug frame, metres.
"""

from __future__ import annotations

import numpy as np

from ndfa.sim.mesh import Mesh
from ndfa.sim.mug_params import MugParams, inner_radius, outer_radius, rim_cap_height

BODY_SEGMENTS = 48  # angular segments of the body; enough to look round at the renderer's distances


def _arc(center: tuple[float, float], radii: tuple[float, float], start: float, stop: float, count: int) -> np.ndarray:
    """(count, 2) points on an elliptic arc from angle `start` (excluded) to `stop` (included)."""
    angles = np.linspace(start, stop, count + 1)[1:]
    return np.c_[center[0] + radii[0] * np.cos(angles), center[1] + radii[1] * np.sin(angles)]


def body_profile(params: MugParams, wall_points: int = 12) -> np.ndarray:
    """Closed (r, z) profile of the body, (P, 2), from the bottom pole to the top pole, counter-
    clockwise around the material (outward normal on the right), every r > 0 except the poles.
    `wall_points` per wall (outer, inner): a mug's walls are nearly straight; a bowl's curve wants more."""
    p = params
    radius_at = lambda z: float(outer_radius(p, np.array([z]))[0])  # noqa: E731 - local shorthand
    pieces: list[np.ndarray] = [np.array([[0.0, p.recess_depth]])]  # bottom pole

    # Underside: a recessed centre (if any), then the ring the mug stands on, then the rounded edge.
    if p.base_style == "foot_ring":
        wall_start = p.foot_height
        contact_outer = radius_at(wall_start) - p.foot_inset
    else:
        wall_start = p.bottom_fillet
        contact_outer = radius_at(wall_start)
    if p.recess_depth > 0:
        recess_edge = contact_outer - p.bottom_fillet - p.contact_ring_width - p.recess_depth  # 45 degree slope
        pieces.append(np.array([[recess_edge, p.recess_depth], [recess_edge + p.recess_depth, 0.0]]))
    pieces.append(np.array([[contact_outer - p.bottom_fillet, 0.0]]))
    pieces.append(_arc((contact_outer - p.bottom_fillet, p.bottom_fillet), (p.bottom_fillet,) * 2, -np.pi / 2, 0.0, 4))
    if p.base_style == "foot_ring":  # up the foot, then a bevel out to the wall
        pieces.append(np.array([[contact_outer, 0.5 * p.foot_height], [radius_at(wall_start), wall_start]]))

    # Outer wall up to where the rim cap starts, the cap, then down the inner wall.
    rim_z = p.height - rim_cap_height(p)
    z_out = np.linspace(wall_start, rim_z, wall_points + 1)[1:]
    pieces.append(np.c_[outer_radius(p, z_out), z_out])
    rim_center = radius_at(rim_z) - p.wall_thickness / 2
    pieces.append(_arc((rim_center, rim_z), (p.wall_thickness / 2, rim_cap_height(p)), 0.0, np.pi, 6))
    corner_z = p.base_thickness + p.inner_fillet
    z_in = np.linspace(rim_z, corner_z, wall_points + 1)[1:]
    pieces.append(np.c_[inner_radius(p, z_in), z_in])

    # Rounded corner into the cavity floor, then across the floor to the top pole.
    corner_center = (float(inner_radius(p, np.array([corner_z]))[0]) - p.inner_fillet, corner_z)
    pieces.append(_arc(corner_center, (p.inner_fillet,) * 2, 0.0, -np.pi / 2, 4))
    pieces.append(np.array([[corner_center[0] / 2, p.base_thickness], [0.0, p.base_thickness]]))
    return np.concatenate(pieces)


def revolve_profile(profile: np.ndarray, segments: int = BODY_SEGMENTS) -> Mesh:
    """Closed mesh of the surface of revolution of `profile` (P, 2) about the z axis.

    The first and last profile points must lie on the axis (r = 0): each becomes one pole vertex,
    the P - 2 points between become rings of `segments` vertices. Outward winding needs the
    profile counter-clockwise around the material (as `body_profile` makes it)."""
    angles = 2 * np.pi * np.arange(segments) / segments
    ring_r, ring_z = profile[1:-1, 0], profile[1:-1, 1]
    rings = np.stack(
        [np.outer(ring_r, np.cos(angles)), np.outer(ring_r, np.sin(angles)), np.repeat(ring_z[:, None], segments, 1)],
        axis=-1,
    ).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, profile[0, 1]]], rings, [[0.0, 0.0, profile[-1, 1]]]])
    return Mesh(vertices, capped_rings_triangles(len(ring_r), segments))


def capped_rings_triangles(n_rings: int, segments: int) -> np.ndarray:
    """Triangles (F, 3) closing a stack of rings into one genus-0 surface: the shared layout of
    the body and the handle. Vertex 0 is the first pole, then come `n_rings` rings of `segments`
    vertices each, then the last pole. Ring i + 1 follows ring i, and vertex j + 1 follows vertex j
    around each ring, so that (next around) x (next ring) points outward."""
    j = np.arange(segments)
    j_next = (j + 1) % segments
    ring = lambda i, jj: 1 + i * segments + jj  # noqa: E731 - vertex index of ring i, angle jj
    last_pole = 1 + n_rings * segments
    triangles = [np.c_[np.zeros(segments, dtype=int), ring(0, j_next), ring(0, j)]]
    for i in range(n_rings - 1):  # two triangles per quad (i, j), (i, j+1), (i+1, j+1), (i+1, j)
        triangles.append(np.c_[ring(i, j), ring(i, j_next), ring(i + 1, j)])
        triangles.append(np.c_[ring(i, j_next), ring(i + 1, j_next), ring(i + 1, j)])
    triangles.append(np.c_[ring(n_rings - 1, j), ring(n_rings - 1, j_next), np.full(segments, last_pole)])
    return np.concatenate(triangles).astype(np.int32)


def body_mesh(params: MugParams) -> Mesh:
    """Closed mesh of the mug's body (everything but the handle)."""
    return revolve_profile(body_profile(params))
