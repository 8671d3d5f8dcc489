"""The handle of a procedural mug: a tube of elliptic cross-section swept along a planar
centre-line in the xz plane. Both ends are capped and buried in the middle of the body's wall
(never in the cavity), so body and handle together are one solid. Mug frame, metres.
"""

from __future__ import annotations

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.mesh import Mesh
from ndfa.sim.mug_body import capped_rings_triangles
from ndfa.sim.mug_params import MugParams, outer_radius

TUBE_SEGMENTS = 12  # segments around the handle's cross-section


def handle_centerline(params: MugParams) -> tuple[np.ndarray, np.ndarray]:
    """Centre-line of the handle in the mug frame: points (K, 3) from the buried lower end to the
    buried upper end, all at y = 0, and their unit tangents (K, 3).

    The ends are buried mid-wall at `handle_bottom_z` and `handle_top_z` and leave the wall along
    its normal, so the end caps lie parallel to the wall, inside it. The arms and the grip are laid
    out in the handle's own frame: v along the chord between the two ends, u away from the body
    at right angles to it. All corners are rounded into circular bends."""
    p = params
    ends_z = np.array([p.handle_bottom_z, p.handle_top_z])
    ends = np.c_[outer_radius(p, ends_z) - p.wall_thickness / 2, ends_z]  # (2, 2) buried ends (x, z)
    origin = ends.mean(axis=0)
    v = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    u = np.array([v[1], -v[0]])  # v turned clockwise in the xz plane: away from the axis
    half_span = np.linalg.norm(ends[1] - ends[0]) / 2

    # The reach is measured from the outermost point of the wall between the attachments.
    wall_z = np.linspace(p.handle_bottom_z, p.handle_top_z, 33)
    wall_u = (np.c_[outer_radius(p, wall_z), wall_z] - origin) @ u
    top_arm = wall_u.max() + p.handle_reach
    stub = p.wall_thickness / 2 + 0.002  # straight out along the wall normal, through the wall
    normals = _wall_normals(p, ends_z)
    corners = np.array([
        ends[0],
        ends[0] + stub * normals[0],
        origin + top_arm * p.handle_bottom_reach_ratio * u - half_span * v,
        origin + top_arm * u + half_span * v,
        ends[1] + stub * normals[1],
        ends[1],
    ])
    # The stubs stay straight until 0.5 mm outside the outer wall before they bend away.
    radii, turns = _fit_bends(corners, p.handle_bend_radius, straight_ends=p.wall_thickness / 2 + 0.0005)
    bends = turns >= np.radians(1.0)  # smaller turns stay kinks (see `_rounded_polyline`)
    if np.any(radii[bends] < 0.55 * p.handle_thickness):  # a tighter bend would fold the tube's inner side
        raise SimError(
            f"{p.handle_shape!r} handle: bends of radius {radii[bends].min():.4f} m are too tight for a "
            f"tube {p.handle_thickness:.4f} m thick"
        )
    points, tangents = _rounded_polyline(corners, radii, turns)
    lift = lambda xz: np.c_[xz[:, 0], np.zeros(len(xz)), xz[:, 1]]  # noqa: E731 - xz plane into 3D
    return lift(points), lift(tangents)


def _wall_normals(params: MugParams, z: np.ndarray) -> np.ndarray:
    """Outward unit normals (M, 2), as (x, z), of the outer wall at heights `z` (M,) on the +x side."""
    step = 1e-5
    slope = (outer_radius(params, z + step) - outer_radius(params, z - step)) / (2 * step)  # dr/dz
    normals = np.c_[np.ones_like(slope), -slope]
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _fit_bends(corners: np.ndarray, radius: float, straight_ends: float) -> tuple[np.ndarray, np.ndarray]:
    """Bend radius (C-2,) at each inner corner of the polyline `corners` (C, 2), shrunk from
    `radius` where the bends would not fit on their segments, and the angle turned there (C-2,).
    The first and last segments keep `straight_ends` straight at their free ends."""
    directions = np.diff(corners, axis=0)
    lengths = np.linalg.norm(directions, axis=1)
    directions /= lengths[:, None]
    turns = np.arccos(np.clip(np.sum(directions[:-1] * directions[1:], axis=1), -1.0, 1.0))
    setbacks = radius * np.tan(turns / 2)  # distance from a corner to where its bend starts
    scale = np.ones(len(turns))
    for s, length in enumerate(lengths):
        # Segment s runs from inner corner s-1 to inner corner s (indices into `turns`); an inner
        # segment is shared by two bends.
        ends = [c for c in (s - 1, s) if 0 <= c < len(turns)]
        used = sum(setbacks[c] for c in ends)
        room = length - (straight_ends if s in (0, len(lengths) - 1) else 0.0)
        if used > room:
            for c in ends:
                scale[c] = min(scale[c], max(room, 0.0) / used)
    return radius * scale, turns


def _rounded_polyline(corners: np.ndarray, radii: np.ndarray, turns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (K, 2) and unit tangents (K, 2) along the polyline `corners` (C, 2) with each inner
    corner c replaced by a circular bend of radius `radii[c-1]` (tangents stay continuous)."""
    directions = np.diff(corners, axis=0)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    points, tangents = [corners[0]], [directions[0]]
    for c in range(1, len(corners) - 1):
        d_in, d_out, radius, turn = directions[c - 1], directions[c], radii[c - 1], turns[c - 1]
        if turn < np.radians(1.0):  # nearly straight on: a kink this small needs no bend
            _append_line(points, tangents, corners[c], d_in)
            continue
        start = corners[c] - d_in * radius * np.tan(turn / 2)
        _append_line(points, tangents, start, d_in)
        # The bend's centre lies on the inner side of the turn, one radius from the tangent points.
        side = np.sign(d_in[0] * d_out[1] - d_in[1] * d_out[0])  # +1: a left (counter-clockwise) turn
        center = start + side * radius * np.array([-d_in[1], d_in[0]])
        for angle in side * np.linspace(0.0, turn, int(np.ceil(turn / np.radians(10))) + 1)[1:]:
            rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
            points.append(center + rotation @ (start - center))
            tangents.append(rotation @ d_in)
    _append_line(points, tangents, corners[-1], directions[-1])
    return np.array(points), np.array(tangents)


def _append_line(points: list, tangents: list, target: np.ndarray, direction: np.ndarray) -> None:
    """Extend the path in a straight line to `target`, a ring every centimetre or so."""
    start = points[-1]
    length = np.linalg.norm(target - start)
    if length < 1e-9:
        return
    count = max(1, int(np.ceil(length / 0.01)))
    for f in np.linspace(0.0, 1.0, count + 1)[1:]:
        points.append(start + f * (target - start))
        tangents.append(direction)


def sweep_tube(points: np.ndarray, tangents: np.ndarray, half_thickness: float, half_width: float,
               segments: int = TUBE_SEGMENTS) -> Mesh:
    """Closed tube of elliptic cross-section swept along a centre-line in the xz plane.

    `points` (K, 3) and unit `tangents` (K, 3) lie in the xz plane; the cross-section has semi-axes
    `half_thickness` in that plane and `half_width` along y. Both ends are capped by a fan around
    a centre vertex, so the tube is a closed genus-0 surface."""
    across = np.array([0.0, 1.0, 0.0])
    in_plane = np.cross(across, tangents)  # (in_plane, across, tangent) is right-handed
    angles = 2 * np.pi * np.arange(segments) / segments
    rings = (
        points[:, None, :]
        + half_thickness * np.cos(angles)[None, :, None] * in_plane[:, None, :]
        + half_width * np.sin(angles)[None, :, None] * across[None, None, :]
    ).reshape(-1, 3)
    # The cap centres are the "poles": the first and last centre-line points.
    vertices = np.concatenate([points[:1], rings, points[-1:]])
    return Mesh(vertices, capped_rings_triangles(len(points), segments))


def handle_mesh(params: MugParams) -> Mesh:
    """Closed mesh of the handle, ends buried in the body's wall."""
    points, tangents = handle_centerline(params)
    return sweep_tube(points, tangents, params.handle_thickness / 2, params.handle_width / 2)
