"""The shape parameters of a procedural mug (`MugParams`), the wall radius they define, and how
they are drawn from a seed (`sample_mug_params`): the mug category ndfa trains and tests on.

Lengths in metres, in the mug frame (see `ndfa.sim.mug`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

PROFILES = ("straight", "tapered", "bulged", "flared")
BASE_STYLES = ("flat", "recessed", "foot_ring")
HANDLE_SHAPES = ("round", "d_shaped", "squarish", "ear", "none")


@dataclass(frozen=True)
class MugParams:
    """Every shape parameter of one mug. Lengths in metres, in the mug frame; the defaults are a
    plain straight mug with a round handle. Fields marked "fraction" are unitless ratios."""

    # --- Body: the outer wall radius at height z is
    #     rim_radius * (bottom_radius_ratio + (1 - bottom_radius_ratio) * t**flare_exponent
    #                   + belly * sin(pi * t**q) + lip_flare * smoothstep(lip))
    #     with t = z / height and q chosen so the belly is widest at t = belly_height.
    profile: str = "straight"  # sub-type tag: a mug's one of PROFILES (cups, bowls: ndfa.sim.vessels)
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


def rim_cap_height(params: MugParams) -> float:
    """Height of the rounded rim cap above where the walls end."""
    return params.rim_roundness * params.wall_thickness / 2


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
    top_edge = body.height - rim_cap_height(body) - 0.003 - (body.lip_height if body.lip_flare > 0 else 0.0)
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
