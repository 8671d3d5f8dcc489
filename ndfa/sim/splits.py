"""Which procedural objects are for training and which for testing: the only place that decides.

An object is its category and its seed (`ndfa.sim.categories.make_object`; a mug:
`ndfa.sim.mug.make_mug`), so a split is a range of seeds, the same for every category (each
category draws its parameters from (seed, its number), so equal seeds give unrelated objects).
The ranges are disjoint, so no test object is ever seen in training. Validation objects are
train-split ones after those a run trains on (`ndfa train`'s --train-mugs).
"""

from __future__ import annotations

from ndfa.core.errors import SimError
from ndfa.sim.categories import CATEGORIES, CategoryObject, make_object
from ndfa.sim.mug import Mug, make_mug

TRAIN_SEEDS = range(0, 1_000_000)
TEST_SEEDS = range(1_000_000, 2_000_000)

SPLITS = {"train": TRAIN_SEEDS, "test": TEST_SEEDS}


def split_seed(split: str, index: int) -> int:
    """Seed of the `index`-th object of `split` ("train" or "test"), whatever its category."""
    if split not in SPLITS:
        raise SimError(f"unknown split {split!r}; expected one of {sorted(SPLITS)}")
    seeds = SPLITS[split]
    if not 0 <= index < len(seeds):
        raise SimError(f"object index {index} is out of range for the {split!r} split (0 to {len(seeds) - 1})")
    return seeds[index]


def make_split_mug(split: str, index: int) -> Mug:
    """The `index`-th mug of `split`."""
    return make_mug(split_seed(split, index))


def make_split_object(category: str, split: str, index: int) -> CategoryObject:
    """The `index`-th object of `category` in `split` (a mug is `make_split_mug`'s, as a `CategoryObject`)."""
    if category not in CATEGORIES:
        raise SimError(f"unknown object category {category!r}; one of {', '.join(CATEGORIES)}")
    return make_object(category, split_seed(split, index))
