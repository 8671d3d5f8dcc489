"""Procedural mugs: the object category ndfa trains and tests on (ShapeNet is not available).

Every mug is drawn from a seed: `make_mug(seed)` samples `MugParams` with
`np.random.default_rng(seed)` and builds closed triangle meshes from them, so the same seed gives
the same mug on every machine. Which seeds are for training and which for testing is decided in
`ndfa.sim.splits`, nowhere else.

Mug frame (every array of the mug modules is in it): z up, metres, the base (lowest point) at z = 0,
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

Occupancy is the union of the parts' occupancies (`ndfa.sim.solid.PartsSolid`).

This module holds the mug itself (`Mug`, `make_mug`, `build_mug`) and re-exports the names of its
parts: the parameters and their sampling (`ndfa.sim.mug_params`), the body (`ndfa.sim.mug_body`)
and the handle (`ndfa.sim.mug_handle`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.sim.mesh import Mesh
from ndfa.sim.mug_body import (
    body_mesh,
    body_profile,
    capped_rings_triangles,
    revolve_profile,
)
from ndfa.sim.mug_handle import handle_centerline, handle_mesh, sweep_tube
from ndfa.sim.mug_params import (
    BASE_STYLES,
    HANDLE_SHAPES,
    PROFILES,
    MugParams,
    inner_radius,
    outer_radius,
    sample_mug_params,
)
from ndfa.sim.solid import PartsSolid

__all__ = [
    "BASE_STYLES", "HANDLE_SHAPES", "PROFILES", "Mug", "MugParams", "body_mesh", "body_profile", "build_mug",
    "capped_rings_triangles", "handle_centerline", "handle_mesh", "inner_radius", "make_mug", "outer_radius",
    "revolve_profile", "sample_mug_params", "sweep_tube",
]


@dataclass
class Mug(PartsSolid):
    """One mug model. `parts` are closed meshes in the mug frame (body first, then the handle, if
    any) that may overlap. `params` is None for a mesh loaded from a file, `seed` is -1 then.
    `watertight` says every part is closed, so `occupancy` is exact."""

    model_id: str
    seed: int
    params: MugParams | None
    parts: list[Mesh]
    watertight: bool = True


def make_mug(seed: int) -> Mug:
    """The mug of `seed`: the same seed always gives the same mug."""
    return build_mug(sample_mug_params(np.random.default_rng(seed)), model_id=f"mug-{seed:07d}", seed=seed)


def build_mug(params: MugParams, model_id: str = "mug-custom", seed: int = -1) -> Mug:
    """The mug of given parameters (for hand-made parameters; `make_mug` samples them)."""
    parts = [body_mesh(params)]
    if params.handle_shape != "none":
        parts.append(handle_mesh(params))
    return Mug(model_id=model_id, seed=seed, params=params, parts=parts)
