"""Procedural bowls and cups without handles: open vessels of revolution, the mug's body
(`ndfa.sim.mug_body.body_profile`, the same `MugParams`) drawn from other ranges, and a
takeaway cup's lid.

Object frame as the mug's: z up, metres, the base at z = 0, the axis on the z axis. The kinds and
their ranges (widest diameter x height) follow real objects:

- bowls: "rounded" (cereal, soup, rice bowls: 11-26 cm x 4-11 cm, a curved wall, often a foot
  ring), "conical" (salad and noodle bowls: 14-30 cm x 5-12 cm, a straight slanted wall),
  "straight" (ramekins, dessert bowls: 8-13 cm x 3.5-7 cm);
- cups: "tumbler" (water glasses, plastic tumblers: 6-9 cm x 8-15 cm, thick base), "paper"
  (takeaway cups: 7-10 cm x 8-18 cm, steep taper, rolled rim, recessed base, a lid on 40%),
  "teacup" (handleless tea cups: 7-10 cm x 5-9 cm, flared or bellied, a foot ring), "small"
  (espresso, shot glasses: 4.4-6.4 cm x 4.5-7 cm).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from ndfa.sim.mesh import Mesh
from ndfa.sim.mug_body import body_profile, revolve_profile
from ndfa.sim.mug_params import MugParams, outer_radius

BOWL_KINDS = ("rounded", "conical", "straight")
CUP_KINDS = ("tumbler", "paper", "teacup", "small")
# Points per wall of the revolved profile: a bowl's curved wall needs more than a mug's 12.
WALL_POINTS = 32

# kind: (widest radius m, height m, bottom radius ratio, flare exponent, wall m)
_BOWL_RANGES = {
    "rounded": ((0.055, 0.13), (0.04, 0.11), (0.3, 0.55), (0.35, 0.65), (0.003, 0.007)),
    "conical": ((0.07, 0.15), (0.05, 0.12), (0.3, 0.5), (1.0, 1.0), (0.003, 0.007)),
    "straight": ((0.04, 0.065), (0.035, 0.07), (0.88, 1.0), (1.0, 1.0), (0.003, 0.006)),
}
_CUP_RANGES = {
    "tumbler": ((0.03, 0.045), (0.08, 0.15), (0.75, 1.0), (1.0, 1.0), (0.002, 0.004)),
    "paper": ((0.035, 0.05), (0.08, 0.18), (0.62, 0.8), (1.0, 1.0), (0.0015, 0.0025)),
    "teacup": ((0.035, 0.05), (0.05, 0.09), (0.6, 0.8), (1.4, 2.5), (0.003, 0.006)),
    "small": ((0.022, 0.032), (0.045, 0.07), (0.75, 1.0), (1.0, 1.0), (0.002, 0.004)),
}


@dataclass(frozen=True)
class VesselParams:
    """A bowl or a cup: its kind, the body (a mug's body parameters, `handle_shape="none"`), and a
    lid (takeaway cups only; `lid_height` 0 = open)."""

    category: str  # "bowl" or "cup"
    kind: str  # one of BOWL_KINDS or CUP_KINDS
    body: MugParams
    lid_height: float = 0.0  # from the lid's underside (inside the rim) to its top
    lid_overhang: float = 0.0  # how far the lid stands out beyond the rim


def sample_bowl_params(rng: np.random.Generator) -> VesselParams:
    kind = str(rng.choice(BOWL_KINDS, p=[0.5, 0.3, 0.2]))
    widest, height, ratio, exponent, wall = (rng.uniform(*bounds) for bounds in _BOWL_RANGES[kind])
    height = min(height, 0.8 * 2 * widest)  # a bowl is wider than tall
    body = _body(rng, kind, widest, height, ratio, exponent, wall, belly=0.0,
                 lip=rng.uniform(0.015, 0.035) if rng.random() < 0.25 else 0.0,
                 base_style=str(rng.choice(["flat", "foot_ring"], p=[0.4, 0.6])))
    return VesselParams("bowl", kind, body)


def sample_cup_params(rng: np.random.Generator) -> VesselParams:
    kind = str(rng.choice(CUP_KINDS, p=[0.3, 0.3, 0.25, 0.15]))
    widest, height, ratio, exponent, wall = (rng.uniform(*bounds) for bounds in _CUP_RANGES[kind])
    belly = rng.uniform(0.04, 0.1) if kind == "teacup" and rng.random() < 0.4 else 0.0
    lip = rng.uniform(0.03, 0.06) if kind == "paper" else 0.0  # the rolled rim
    base_style = {"paper": "recessed", "teacup": "foot_ring"}.get(kind, "flat")
    body = _body(rng, kind, widest, height, ratio, exponent, wall, belly, lip, base_style)
    if kind == "paper" and rng.random() < 0.4:
        return VesselParams("cup", kind, body, lid_height=rng.uniform(0.01, 0.022), lid_overhang=rng.uniform(0.001, 0.003))
    return VesselParams("cup", kind, body)


def _body(rng: np.random.Generator, kind: str, widest: float, height: float, ratio: float, exponent: float,
          wall: float, belly: float, lip: float, base_style: str) -> MugParams:
    """A handleless body whose widest outer radius is `widest`, with a base fitting its underside."""
    params = MugParams(profile=kind, height=height, rim_radius=1.0, bottom_radius_ratio=ratio, flare_exponent=exponent,
                       belly=belly, belly_height=rng.uniform(0.35, 0.6), rim_roundness=rng.uniform(0.6, 1.0),
                       lip_flare=lip, lip_height=rng.uniform(0.003, 0.006) if kind == "paper" else rng.uniform(0.005, 0.01),
                       handle_shape="none")
    z = np.linspace(0.0, height, 257)
    params = replace(params, rim_radius=float(widest / outer_radius(params, z).max()))
    narrowest = float(outer_radius(params, z).min())
    wall = min(wall, 0.15 * narrowest)
    base = dict(base_style=base_style, recess_depth=0.0, foot_height=0.0, foot_inset=0.0,
                bottom_fillet=rng.uniform(0.001, 0.004), contact_ring_width=rng.uniform(0.004, 0.008))
    if base_style == "recessed":
        base["recess_depth"] = rng.uniform(0.002, 0.006)
    elif base_style == "foot_ring":
        base.update(recess_depth=rng.uniform(0.001, 0.003), foot_height=rng.uniform(0.003, 0.008),
                    foot_inset=rng.uniform(0.002, 0.006) * (1 + narrowest / 0.05), bottom_fillet=0.001)
    # The recessed centre needs room inside the ring the vessel stands on; else the base is flat.
    ring_outer = float(outer_radius(params, np.array([max(base["foot_height"], base["bottom_fillet"])]))[0])
    if ring_outer - base["foot_inset"] - base["bottom_fillet"] - base["contact_ring_width"] - base["recess_depth"] < 0.004:
        base.update(base_style="flat", recess_depth=0.0, foot_height=0.0, foot_inset=0.0)
    floor_lo = max(0.004, base["recess_depth"] + 0.002, base["foot_height"] + 0.002)
    thick_base = kind in ("tumbler", "small")  # glasses stand on a heavy bottom
    base_thickness = rng.uniform(floor_lo, max(floor_lo + 0.002, 0.015 if thick_base else 0.009))
    inner_at_floor = float(outer_radius(params, np.array([base_thickness]))[0]) - wall
    params = replace(params, wall_thickness=wall, base_thickness=base_thickness,
                     inner_fillet=min(rng.uniform(0.003, 0.012), 0.4 * inner_at_floor), **base)
    # A wall that leaves the base at a shallow slope (a bowl's) would let the cavity floor's corner
    # poke through it: the walls are `wall` apart horizontally, not along their normal.
    while not _floor_inside(params) and params.base_thickness < 0.3 * height:
        fillet = max(0.0005, 0.8 * params.inner_fillet)
        params = replace(params, inner_fillet=fillet,
                         base_thickness=params.base_thickness + (0.001 if fillet == params.inner_fillet else 0.0))
    values = {f.name: getattr(params, f.name) for f in fields(params)}  # plain floats: readable, JSON-ready
    return MugParams(**{name: float(v) if isinstance(v, np.floating) else v for name, v in values.items()})


def _floor_inside(params: MugParams, margin: float = 0.001) -> bool:
    """Whether the cavity floor's rounded corner stays `margin` inside the outer wall."""
    corner_z = params.base_thickness + params.inner_fillet
    center = float(outer_radius(params, np.array([corner_z]))[0]) - params.wall_thickness - params.inner_fillet
    angles = np.linspace(-np.pi / 2, 0.0, 9)
    r, z = center + params.inner_fillet * np.cos(angles), corner_z + params.inner_fillet * np.sin(angles)
    return bool(np.all(r < outer_radius(params, z) - margin))


def vessel_parts(params: VesselParams) -> list[Mesh]:
    """The closed meshes of a bowl or cup: the body, and the lid where it has one (overlapping the
    rim, as a pressed-on lid does)."""
    parts = [revolve_profile(body_profile(params.body, wall_points=WALL_POINTS))]
    if params.lid_height > 0:
        parts.append(_lid(params))
    return parts


def _lid(params: VesselParams) -> Mesh:
    """A takeaway lid: a disc from inside the rim to above it, standing out by the overhang, with a
    raised centre (its sip area)."""
    body = params.body
    rim = float(outer_radius(body, np.array([body.height]))[0])
    radius = rim + params.lid_overhang
    bottom, top = body.height - 0.4 * params.lid_height, body.height + 0.6 * params.lid_height
    dome = 0.25 * params.lid_height
    profile = np.array([
        [0.0, bottom], [radius - 0.001, bottom], [radius, bottom + 0.001], [radius, top - 0.001],
        [radius - 0.001, top], [0.8 * radius, top], [0.65 * radius, top + dome], [0.0, top + dome],
    ])
    return revolve_profile(profile)
