"""Training batches drawn from a dataset (`ndfa.training.dataset`): the views of distinct objects
(of one category or several), two of each, as torch tensors, for the batch-hard shape loss."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ndfa.core.errors import DataError
from ndfa.training.dataset import object_ids

if TYPE_CHECKING:
    import torch


def sample_batch(dataset: dict[str, np.ndarray], n_mugs: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """A batch for the batch-hard shape loss: `n_mugs` distinct objects, two different views of each.

    Returns float32 tensors in the camera frame (the trainer centres them): points [2B, N, 3],
    queries [2B, Q, 3], occupancy [2B, Q] (0/1), center [2B, 3], rotation [2B, 3, 3] (object frame
    -> camera), and int64 object_id [2B] (`object_ids`) and category [2B] (into `CATEGORIES`); rows
    b and b + B are the two views of the same object. Only objects with two or more views are drawn.
    """
    return sample_rows(dataset, batch_rows(dataset, n_mugs, rng))


def sample_rows(dataset: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, torch.Tensor]:
    """The views `rows` of `dataset` as `sample_batch`'s tensors."""
    import torch  # here, so that generation workers do not load torch

    return {
        "points": torch.from_numpy(dataset["points"][rows].astype(np.float32)),
        "queries": torch.from_numpy(dataset["queries"][rows].astype(np.float32)),
        "occupancy": torch.from_numpy(dataset["occupancy"][rows].astype(np.float32)),
        "center": torch.from_numpy(dataset["center"][rows].astype(np.float32)),
        "rotation": torch.from_numpy(dataset["pose_camera_object"][rows, :3, :3].astype(np.float32)),
    } | batch_labels(dataset, rows)


def batch_labels(dataset: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, torch.Tensor]:
    """The views `rows`' int64 object_id (`object_ids`) and category (into `CATEGORIES`) `[len(rows)]`."""
    import torch

    return {"object_id": torch.from_numpy(object_ids(dataset)[rows]),
            "category": torch.from_numpy(dataset["category"][rows].astype(np.int64))}


def batch_rows(dataset: dict[str, np.ndarray], n_mugs: int, rng: np.random.Generator) -> np.ndarray:
    """Rows of `sample_batch`'s views `[2 * n_mugs]`: rows b and b + n_mugs are two views of one object."""
    ids = object_ids(dataset)
    order = np.argsort(ids, kind="stable")  # rows of each object side by side
    _, starts, counts = np.unique(ids[order], return_index=True, return_counts=True)
    eligible = np.flatnonzero(counts >= 2)
    if len(eligible) < n_mugs:
        raise DataError(f"a batch of {n_mugs} objects needs {n_mugs} objects with two views; the dataset has {len(eligible)}")
    chosen = rng.choice(eligible, size=n_mugs, replace=False)
    first = rng.integers(counts[chosen])
    second = (first + rng.integers(1, counts[chosen])) % counts[chosen]  # never equal to first
    return order[np.concatenate([starts[chosen] + first, starts[chosen] + second])]
