"""Procedural mugs: the object category ndfa trains and tests on (ShapeNet is not available).

Every mug is drawn from a seed: `make_mug(seed)` samples `MugParams` with
`np.random.default_rng(seed)` and builds closed triangle meshes from them, so the same seed gives
the same mug on every machine. Which seeds are for training and which for testing is decided in
`ndfa.sim.splits`, nowhere else.

Mug frame (every array in this module is in it): z up, metres, the base (lowest point) at z = 0,
the body's axis of revolution on the z axis (x = y = 0), the handle (if any) on the +x side,
centred on the xz plane.

A mug is made of parts, each a closed watertight mesh, that may overlap:

- the body: a surface of revolution of one closed (r, z) profile that runs from the bottom pole
  (on the axis, under the base) out along the underside, up the outer wall, over the rounded rim,
  down the inner wall and across the cavity floor to the top pole (on the axis, at the floor).
  Both poles are single vertices, so the revolved mesh is a closed genus-0 surface;
- the handle: a tube of elliptic cross-section swept along a planar centre-line in the xz plane.
  Both ends are capped and buried in the middle of the body's wall (never in the cavity), so
  body and handle together are one solid.

Occupancy is the union of the parts' occupancies, each from its own Open3D `RaycastingScene`:
ray-parity occupancy over one scene holding overlapping parts would call the overlap "outside".
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import cached_property

import numpy as np

from ndfa.core.errors import SimError
from ndfa.sim.mesh import Mesh

PROFILES = ("straight", "tapered", "bulged", "flared")
BASE_STYLES = ("flat", "recessed", "foot_ring")
HANDLE_SHAPES = ("round", "d_shaped", "squarish", "ear", "none")

BODY_SEGMENTS = 48  # angular segments of the body; enough to look round at the renderer's distances
TUBE_SEGMENTS = 12  # segments around the handle's cross-section


@dataclass(frozen=True)
class MugParams:
    """Every shape parameter of one mug. Lengths in metres, in the mug frame; the defaults are a
    plain straight mug with a round handle. Fields marked "fraction" are unitless ratios."""

    # --- Body: the outer wall radius at height z is
    #     rim_radius * (bottom_radius_ratio + (1 - bottom_radius_ratio) * t**flare_exponent
    #                   + belly * sin(pi * t**q) + lip_flare * smoothstep(lip))
    #     with t = z / height and q chosen so the belly is widest at t = belly_height.
    profile: str = "straight"  # sub-type tag: one of PROFILES (the numbers below make the shape)
    height: float = 0.095  # top of the rim above the base
    rim_radius: float = 0.04  # outer wall radius at the rim, before the lip flare
    bottom_radius_ratio: float = 1.0  # fraction: wall radius at z = 0 over rim_radius (< 1: narrower at the bottom)
    flare_exponent: float = 1.0  # 1 = straight cone; > 1 the wall widens late, flaring toward the rim
    belly: float = 0.0  # fraction of rim_radius added at the widest point of the belly ("bulged")
    belly_height: float = 0.5  # fraction of the height where the belly is widest
    wall_thickness: float = 0.005  # horizontal distance between outer and inner wall
    rim_roundness: float = 1.0  # fraction: height of the rounded rim cap over half the wall thickness (1 = semicircle)
    lip_flare: float = 0.0  # fraction of rim_radius the wall bends outward at the rim (0 = no lip)
    lip_height: float = 0.008  # height below the rim over which the lip bends out
    # --- Base
    base_style: str = "flat"  # one of BASE_STYLES
    base_thickness: float = 0.008  # z of the cavity floor
    bottom_fillet: float = 0.004  # radius of the rounded edge where the underside meets the outer wall (or foot)
    inner_fillet: float = 0.006  # radius of the rounded corner between the cavity floor and the inner wall
    recess_depth: float = 0.0  # how far the centre of the underside is raised ("recessed", "foot_ring")
    contact_ring_width: float = 0.006  # width of the flat ring the mug stands on when the underside is recessed
    foot_height: float = 0.0  # height of the foot ring under the body ("foot_ring" only)
    foot_inset: float = 0.0  # how far the foot ring's outer edge sits inside the wall ("foot_ring" only)
    # --- Handle: a centre-line in the xz plane from the lower to the upper attachment, made of
    #     straight arms and a grip joined by circular bends; the ends are buried mid-wall.
    handle_shape: str = "round"  # one of HANDLE_SHAPES ("none": no handle, the other fields are ignored)
    handle_bottom_z: float = 0.03  # height of the lower attachment's centre-line
    handle_top_z: float = 0.07  # height of the upper attachment's centre-line
    handle_reach: float = 0.017  # how far the grip's centre-line stands out from the outer wall
    handle_bottom_reach_ratio: float = 1.0  # fraction: lower arm length over upper arm length (< 1 leans in at the bottom)
    handle_bend_radius: float = 0.02  # bend radius of the centre-line at the corners (shrunk to fit the arms)
    handle_thickness: float = 0.01  # tube extent in the xz plane
    handle_width: float = 0.01  # tube extent along y (= handle_thickness: round cross-section)


@dataclass
class Mug:
    """One mug model. `parts` are closed meshes in the mug frame (body first, then the handle, if
    any) that may overlap. `params` is None for a mesh loaded from a file, `seed` is -1 then.
    `watertight` says every part is closed, so `occupancy` is exact."""

    model_id: str
    seed: int
    params: MugParams | None
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

    def occupancy(self, points: np.ndarray) -> np.ndarray:
        """Whether each of `points` (N, 3), in the mug frame, is inside the mug: bool (N,)."""
        if not self.watertight:
            raise SimError(f"{self.model_id}: exact occupancy is unavailable, its mesh is not watertight")
        import open3d as o3d

        query = o3d.core.Tensor(np.asarray(points, dtype=np.float32).reshape(-1, 3))
        inside = np.zeros(len(query), dtype=bool)
        for scene in self._part_scenes:
            # Three rays per point and a majority vote: a single ray grazing an edge of the
            # mesh would count the crossing twice (or not at all) and flip the answer.
            inside |= scene.compute_occupancy(query, nsamples=3).numpy().astype(bool)
        return inside


def make_mug(seed: int) -> Mug:
    """The mug of `seed`: the same seed always gives the same mug."""
    return build_mug(sample_mug_params(np.random.default_rng(seed)), model_id=f"mug-{seed:07d}", seed=seed)


def build_mug(params: MugParams, model_id: str = "mug-custom", seed: int = -1) -> Mug:
    """The mug of given parameters (for hand-made parameters; `make_mug` samples them)."""
    parts = [body_mesh(params)]
    if params.handle_shape != "none":
        parts.append(handle_mesh(params))
    return Mug(model_id=model_id, seed=seed, params=params, parts=parts)


# ----------------------------------------------------------------------------------------------
# Sampling


def sample_mug_params(rng: np.random.Generator) -> MugParams:
    """Random parameters spanning a real mug category: widest body radius 3-5.5 cm, height
    6-13 cm, walls 3-8 mm, four wall profiles, three base styles, four handle shapes (and about
    5% without a handle, tagged `handle_shape="none"`)."""
    params = _sample_handle(rng, _sample_body(rng))
    # Plain Python floats, not numpy scalars: a readable repr and JSON-ready fields.
    values = {f.name: getattr(params, f.name) for f in fields(params)}
    return MugParams(**{name: float(v) if isinstance(v, np.floating) else v for name, v in values.items()})


def _sample_body(rng: np.random.Generator) -> MugParams:
    """Body and base parameters; the handle is left at `"none"`."""
    height = rng.uniform(0.06, 0.13)
    profile = str(rng.choice(PROFILES, p=[0.35, 0.25, 0.2, 0.2]))
    shape = dict(bottom_radius_ratio=1.0, flare_exponent=1.0, belly=0.0, belly_height=0.5)
    if profile == "tapered":  # most taper toward the base, some toward the rim
        narrow_bottom = rng.random() < 0.7
        shape["bottom_radius_ratio"] = rng.uniform(0.72, 0.9) if narrow_bottom else rng.uniform(1.1, 1.25)
    elif profile == "bulged":
        shape.update(bottom_radius_ratio=rng.uniform(0.85, 1.02), belly=rng.uniform(0.08, 0.18),
                     belly_height=rng.uniform(0.35, 0.6))
    elif profile == "flared":
        shape.update(bottom_radius_ratio=rng.uniform(0.7, 0.85), flare_exponent=rng.uniform(1.8, 3.0))
    has_lip = rng.random() < 0.35
    params = MugParams(
        profile=profile,
        height=height,
        rim_radius=1.0,  # scaled below so the widest point gets the sampled body radius
        rim_roundness=rng.uniform(0.6, 1.0),
        lip_flare=rng.uniform(0.02, 0.05) if has_lip else 0.0,
        lip_height=rng.uniform(0.005, 0.01),
        handle_shape="none",
        **shape,
    )
    # Body radius = widest outer radius; squat and slender extremes are kept to plausible mugs.
    widest = rng.uniform(max(0.03, 0.25 * height), min(0.055, 0.75 * height))
    unit_widest = outer_radius(params, np.linspace(0.0, height, 257)).max()
    params = replace(params, rim_radius=float(widest / unit_widest))
    narrowest = outer_radius(params, np.linspace(0.0, height, 257)).min()

    wall = rng.uniform(0.003, min(0.008, 0.15 * narrowest))
    base_style = str(rng.choice(BASE_STYLES, p=[0.4, 0.3, 0.3]))
    base = dict(recess_depth=0.0, foot_height=0.0, foot_inset=0.0, bottom_fillet=rng.uniform(0.002, 0.006))
    if base_style != "flat":
        base["recess_depth"] = rng.uniform(0.001, 0.003)
    if base_style == "foot_ring":
        base.update(foot_height=rng.uniform(0.003, 0.007), foot_inset=rng.uniform(0.002, 0.005), bottom_fillet=0.001)
    # The cavity floor stays above the recess and the foot, so the base is solid material.
    floor_lo = max(0.005, base["recess_depth"] + 0.003, base["foot_height"] + 0.002)
    base_thickness = rng.uniform(floor_lo, max(floor_lo + 0.002, 0.012))
    inner_radius_at_floor = float(outer_radius(params, np.array([base_thickness]))[0]) - wall
    return replace(
        params,
        wall_thickness=wall,
        base_style=base_style,
        base_thickness=base_thickness,
        inner_fillet=min(rng.uniform(0.003, 0.01), 0.4 * inner_radius_at_floor),
        contact_ring_width=rng.uniform(0.004, 0.008),
        **base,
    )


def _sample_handle(rng: np.random.Generator, body: MugParams) -> MugParams:
    """`body` with a handle (or, rarely, none) that fits its height and wall."""
    shape = str(rng.choice(HANDLE_SHAPES, p=[0.27, 0.26, 0.22, 0.20, 0.05]))
    if shape == "none":
        return body
    is_ear = shape == "ear"
    thickness = rng.uniform(0.006, 0.009) if is_ear else rng.uniform(0.007, 0.013)
    # The lower arm stays above the lowest fifth of the height (the loader finds the axis there)
    # and clear of the base's edge; the upper arm stays below the rim and the lip.
    bottom_edge = max(0.2 * body.height, body.foot_height + body.bottom_fillet) + 0.002
    top_edge = body.height - _rim_cap_height(body) - 0.003 - (body.lip_height if body.lip_flare > 0 else 0.0)
    # Leave a finger hole at least 1.5 cm (an ear: 8 mm) high.
    min_hole = 0.008 if is_ear else 0.015
    thickness = min(thickness, (top_edge - bottom_edge - min_hole) / 2)
    longest_span = top_edge - bottom_edge - thickness
    shortest_span = thickness + min_hole
    if shape == "round":  # its reach is half its span: keep both sensible
        shortest_span = max(shortest_span, thickness + 0.02 + body.wall_thickness)
        longest_span = min(longest_span, 0.065)
    if is_ear:
        span = min(rng.uniform(0.02, 0.032), longest_span)
        top_z = top_edge - thickness / 2 - rng.uniform(0.0, min(0.004, longest_span - span))
    else:
        longest_span = max(longest_span, shortest_span)
        span = min(rng.uniform(max(shortest_span, 0.5 * longest_span), longest_span), top_edge - bottom_edge - thickness)
        bottom_z = bottom_edge + thickness / 2 + rng.random() * (top_edge - bottom_edge - thickness - span)
        top_z = bottom_z + span

    if shape == "round":  # a half circle: the reach follows from the span
        reach = span / 2 * rng.uniform(0.95, 1.15) - body.wall_thickness / 2
        bend, bottom_ratio = span / 2, 1.0
    elif shape == "d_shaped":  # big bends, a straight vertical grip
        reach = rng.uniform(0.018, 0.032)
        bend = rng.uniform(0.6, 0.9) * min(span / 2, reach)
        bottom_ratio = rng.uniform(0.85, 1.05)
    elif shape == "squarish":  # tight bends, straight arms and grip
        reach = rng.uniform(0.018, 0.03)
        bend = rng.uniform(0.2, 0.4) * min(span / 2, reach)
        bottom_ratio = rng.uniform(0.85, 1.05)
    else:  # ear: small, near the rim, leaning in toward the bottom
        reach = rng.uniform(0.012, 0.018)
        bend = span / 2
        bottom_ratio = rng.uniform(0.65, 0.85)
    reach = max(reach, thickness / 2 + (0.007 if is_ear else 0.01))  # room for a finger

    # Elliptic cross-sections are wider across (y) than in the plane, like a flattened strap;
    # the width is capped so the capped ends stay buried in the curved wall.
    width = thickness if rng.random() < 0.5 else thickness * rng.uniform(1.2, 1.8)
    width = min(width, _max_buried_width(body))
    return replace(
        body,
        handle_shape=shape,
        handle_bottom_z=top_z - span,
        handle_top_z=top_z,
        handle_reach=reach,
        handle_bottom_reach_ratio=bottom_ratio,
        handle_bend_radius=max(bend, 0.75 * thickness),
        handle_thickness=thickness,
        handle_width=width,
    )


def _max_buried_width(body: MugParams) -> float:
    """Widest (along y) tube end that fits inside the wall: an end cap centred mid-wall at
    radius r - w/2 on the narrowest part of the wall must stay 0.5 mm inside the outer radius r."""
    narrowest = outer_radius(body, np.linspace(0.0, body.height, 257)).min()
    mid, limit = narrowest - body.wall_thickness / 2, narrowest - 0.0005
    return 2 * 0.9 * float(np.sqrt(limit**2 - mid**2))


# ----------------------------------------------------------------------------------------------
# Body


def outer_radius(params: MugParams, z: np.ndarray) -> np.ndarray:
    """Outer wall radius at heights `z` (M,), ignoring the rounded bottom edge and the rim cap."""
    t = np.clip(np.asarray(z, dtype=float) / params.height, 0.0, 1.0)
    ratio = params.bottom_radius_ratio
    unit = ratio + (1.0 - ratio) * t**params.flare_exponent
    if params.belly > 0:
        q = np.log(0.5) / np.log(params.belly_height)  # t**q = 1/2 where t = belly_height
        unit = unit + params.belly * np.sin(np.pi * t**q)
    if params.lip_flare > 0:
        s = np.clip((z - (params.height - params.lip_height)) / params.lip_height, 0.0, 1.0)
        unit = unit + params.lip_flare * s * s * (3.0 - 2.0 * s)  # smoothstep: the lip ends vertical
    return params.rim_radius * unit


def inner_radius(params: MugParams, z: np.ndarray) -> np.ndarray:
    """Inner (cavity) wall radius at heights `z` (M,)."""
    return outer_radius(params, z) - params.wall_thickness


def _rim_cap_height(params: MugParams) -> float:
    return params.rim_roundness * params.wall_thickness / 2


def _arc(center: tuple[float, float], radii: tuple[float, float], start: float, stop: float, count: int) -> np.ndarray:
    """(count, 2) points on an elliptic arc from angle `start` (excluded) to `stop` (included)."""
    angles = np.linspace(start, stop, count + 1)[1:]
    return np.c_[center[0] + radii[0] * np.cos(angles), center[1] + radii[1] * np.sin(angles)]


def body_profile(params: MugParams) -> np.ndarray:
    """Closed (r, z) profile of the body, (P, 2), from the bottom pole to the top pole, counter-
    clockwise around the material (outward normal on the right), every r > 0 except the poles."""
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
    rim_z = p.height - _rim_cap_height(p)
    z_out = np.linspace(wall_start, rim_z, 13)[1:]
    pieces.append(np.c_[outer_radius(p, z_out), z_out])
    rim_center = radius_at(rim_z) - p.wall_thickness / 2
    pieces.append(_arc((rim_center, rim_z), (p.wall_thickness / 2, _rim_cap_height(p)), 0.0, np.pi, 6))
    corner_z = p.base_thickness + p.inner_fillet
    z_in = np.linspace(rim_z, corner_z, 13)[1:]
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


# ----------------------------------------------------------------------------------------------
# Handle


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
