"""The object categories the simulator makes beside mugs: bowls, cups without handles, bottles,
cans and boxes (docs/categories.md), each drawn from a seed as the mugs are.

`make_object(category, seed)` samples the category's shape parameters with a generator seeded by
(seed, the category's number) and builds its closed meshes (`parts`, which may overlap, as a mug's
body and handle do), so the same seed gives the same object on every machine and the categories'
seeds are independent. Object frame as the mug's: z up, metres, the base at z = 0, centred on the z
axis. A mug comes from `ndfa.sim.mug.make_mug(seed)`, unchanged ("mug" here wraps it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ndfa.sim.bottle import bottle_parts, can_parts, sample_bottle_params, sample_can_params
from ndfa.sim.box import box_parts, sample_box_params
from ndfa.sim.mesh import Mesh
from ndfa.sim.mug import Mug, make_mug
from ndfa.sim.solid import PartsSolid
from ndfa.sim.vessels import sample_bowl_params, sample_cup_params, vessel_parts

CATEGORIES = ("mug", "bowl", "cup", "bottle", "can", "box")

# The extents every object of a category falls within, from the real objects each kind stands for
# (the modules' docstrings): (widest horizontal extent, height), metres. A mug's width includes its handle.
SIZE_RANGES: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "mug": ((0.06, 0.16), (0.06, 0.13)),
    "bowl": ((0.08, 0.30), (0.035, 0.12)),
    "cup": ((0.044, 0.11), (0.045, 0.2)),
    "bottle": ((0.05, 0.10), (0.12, 0.35)),
    "can": ((0.052, 0.10), (0.035, 0.18)),
    "box": ((0.04, 0.46), (0.02, 0.35)),
}

# category: (shape parameters from a generator, closed meshes from the parameters)
_MAKERS: dict[str, tuple[Callable[[np.random.Generator], Any], Callable[[Any], list[Mesh]]]] = {
    "bowl": (sample_bowl_params, vessel_parts),
    "cup": (sample_cup_params, vessel_parts),
    "bottle": (sample_bottle_params, bottle_parts),
    "can": (sample_can_params, can_parts),
    "box": (sample_box_params, box_parts),
}


@dataclass
class CategoryObject(PartsSolid):
    """One object model of a category: its shape parameters and closed meshes in the object frame
    (`mesh` to render it, `occupancy` of the union of its parts: `PartsSolid`)."""

    category: str
    model_id: str
    seed: int
    params: Any  # VesselParams (bowl, cup), BottleParams, CanParams, BoxParams, MugParams
    parts: list[Mesh]


# What a scene places: a mug (procedural or a mesh from a file) or an object of another category.
SceneModel = Mug | CategoryObject


def make_object(category: str, seed: int) -> CategoryObject:
    """The object of `category` drawn from `seed`: the same seed always gives the same object."""
    if category == "mug":
        mug = make_mug(seed)
        return CategoryObject("mug", mug.model_id, seed, mug.params, mug.parts)
    if category not in _MAKERS:
        raise ValueError(f"unknown object category {category!r}; one of {', '.join(CATEGORIES)}")
    sample, build = _MAKERS[category]
    params = sample(np.random.default_rng([seed, CATEGORIES.index(category)]))
    return CategoryObject(category, f"{category}-{seed:07d}", seed, params, build(params))
