"""What bounds the NDF's IoU and retrieval on the test mugs, independent of any model, plus where
a model's wrong retrievals land. The figures the model card's "Why the IoU and retrieval targets
are out of this model's reach" quotes.

    python studies/ndf_limits.py [out/ndf-eval/views-1.parquet]
    # 2026-12-01: true shape shifted 1/2/3/5 mm -> IoU 0.82/0.65/0.54/0.36; 14/20 test mugs have a
    # twin within 1 cm in every box dimension; shipped weights: 22 % of wrong retrievals land on such
    # a mug (4 % of all pairs are), median largest box difference 2.0 cm (3.0 over all pairs)

1. IoU of each test mug's exact occupancy with itself shifted by 1-8 mm (3 random directions per
   mug), on `ndfa ndf-eval`'s grid: 32^3 over the mug's box enlarged by 10 %.
2. How many test mugs have another within 1 cm in all three box dimensions (a far view sees little
   more than the box).
3. Given an `ndfa ndf-eval` per-view table: how alike (by box) the mugs of the wrong retrievals are.
"""

import sys

import numpy as np
import polars as pl

from ndfa.sim.splits import make_split_mug
from ndfa.training.metrics import iou

MUGS, GRID = 20, 32


def main() -> None:
    mugs = [make_split_mug("test", index) for index in range(MUGS)]
    boxes = np.array([np.subtract(*mug.mesh.bounds[::-1]) for mug in mugs])  # [MUGS, 3] extents, metres
    rng = np.random.default_rng(0)
    grids = []
    for mug in mugs:
        lo, hi = mug.mesh.bounds
        axes = [np.linspace(a, b, GRID) for a, b in zip(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        grids.append((grid, mug.occupancy(grid)))
    for shift_mm in (1, 2, 3, 5, 8):
        values = []
        for mug, (grid, truth) in zip(mugs, grids):
            for _ in range(3):
                direction = rng.standard_normal(3)
                values.append(iou(mug.occupancy(grid + direction / np.linalg.norm(direction) * shift_mm * 1e-3), truth))
        print(f"true shape shifted {shift_mm} mm: IoU {np.mean(values):.3f}")

    largest_difference = np.abs(boxes[:, None] - boxes[None]).max(axis=2)  # [MUGS, MUGS], metres
    np.fill_diagonal(largest_difference, np.inf)
    print(f"test mugs with a twin within 1 cm in every box dimension: {(largest_difference.min(axis=1) < 0.01).sum()}/{MUGS}")
    pairs = largest_difference[np.triu_indices(MUGS, 1)]

    if len(sys.argv) > 1:
        views = pl.read_parquet(sys.argv[1]).filter(~pl.col("retrieved_same_object"))
        wrong = largest_difference[views["object_id"].to_numpy(), views["retrieved_object_id"].to_numpy()]
        print(f"{len(views)} wrong retrievals: {np.mean(wrong < 0.01):.0%} found a mug within 1 cm in every box "
              f"dimension ({np.mean(pairs < 0.01):.0%} of all pairs are); median largest box difference "
              f"{np.median(wrong) * 100:.1f} cm ({np.median(pairs) * 100:.1f} over all pairs)")


if __name__ == "__main__":
    main()
