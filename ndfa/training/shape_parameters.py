"""Shape parameters of the split mugs as numbers, for the optional parameter loss of training."""

from __future__ import annotations

import numpy as np

from ndfa.sim.mug import (
    BASE_STYLES,
    HANDLE_SHAPES,
    PROFILES,
    MugParams,
    sample_mug_params,
)
from ndfa.sim.splits import split_seed

# The MugParams fields that are numbers (metres or fractions), in their order: shape_parameters' first columns.
NUMERIC_PARAMS = [name for name, kind in MugParams.__annotations__.items() if kind == "float"]


def shape_parameters(split: str, mug_indices: list[int]) -> np.ndarray:
    """What makes each mug its shape, as numbers `[len(mug_indices), P]`: every numeric field of
    its `MugParams` (metres or fractions) and one-hot profile, base style and handle shape.

    Regressing these from the shape code (`ndfa train --param-weight`) tells the encoder which
    differences between mugs matter, in units that carry over to mugs it never saw; the identity
    losses only say "this mug, not those". Handle fields of a handle-less mug are zero."""
    rows = []
    for index in mug_indices:
        params = sample_mug_params(np.random.default_rng(split_seed(split, index)))
        has_handle = params.handle_shape != "none"
        numbers = [getattr(params, name) * (has_handle or not name.startswith("handle_")) for name in NUMERIC_PARAMS]
        tags = [params.profile == p for p in PROFILES] + [params.base_style == b for b in BASE_STYLES]
        rows.append(numbers + tags + [params.handle_shape == h for h in HANDLE_SHAPES])
    return np.asarray(rows, dtype=np.float32)
