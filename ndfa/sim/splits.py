"""Which procedural mugs are for training and which for testing: the only place that decides.

A mug is its seed (`ndfa.sim.mug.make_mug`), so a split is a range of seeds. The ranges are
disjoint, so no test mug is ever seen in training.
"""

from __future__ import annotations

from ndfa.core.errors import SimError
from ndfa.sim.mug import Mug, make_mug

TRAIN_SEEDS = range(0, 1_000_000)
TEST_SEEDS = range(1_000_000, 2_000_000)

SPLITS = {"train": TRAIN_SEEDS, "test": TEST_SEEDS}


def mug_seed(split: str, index: int) -> int:
    """Seed of the `index`-th mug of `split` ("train" or "test")."""
    if split not in SPLITS:
        raise SimError(f"unknown mug split {split!r}; expected one of {sorted(SPLITS)}")
    seeds = SPLITS[split]
    if not 0 <= index < len(seeds):
        raise SimError(f"mug index {index} is out of range for the {split!r} split (0 to {len(seeds) - 1})")
    return seeds[index]


def make_split_mug(split: str, index: int) -> Mug:
    """The `index`-th mug of `split`."""
    return make_mug(mug_seed(split, index))
