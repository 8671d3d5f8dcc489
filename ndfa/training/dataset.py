"""Training datasets of the NDF: many rendered views (`ndfa.training.views`) of the mugs of one
split, stacked into arrays (`DATASET_ARRAYS`), and their .npz files.

Determinism: a view depends only on (seed, mug index, view number) and the set of mugs that may
lend it occluders, never on the order of generation or on the number of worker processes.
"""

from __future__ import annotations

import functools
import multiprocessing
import zipfile
import zlib
from pathlib import Path

import numpy as np

from ndfa.core.errors import DataError
from ndfa.io.atomic import atomic_path
from ndfa.sim.mug import Mug
from ndfa.sim.splits import make_split_mug
from ndfa.training.views import ViewConfig, render_view

# Per-view arrays of a dataset (`generate_views`, `load_dataset`): name -> dtype. V views.
DATASET_ARRAYS = {
    "points": np.float32,              # (V, n_points, 3) camera frame
    "n_visible": np.int32,             # (V,) mug points seen before resampling
    "pose_camera_object": np.float32,  # (V, 4, 4) mug frame -> camera frame
    "center": np.float32,              # (V, 3) View.center_camera
    "queries": np.float32,             # (V, n_queries, 3) camera frame
    "occupancy": np.bool_,             # (V, n_queries)
    "mug_index": np.int32,             # (V,) index of the mug within its split
    "view_id": np.int32,               # (V,) view number of that mug: (seed, mug_index, view_id) redraws it
}


def generate_views(split: str, mug_indices: list[int], views_per_mug: int, seed: int,
                   config: ViewConfig = ViewConfig(), workers: int = 2) -> dict[str, np.ndarray]:
    """`views_per_mug` views of each mug `mug_indices` of `split`, stacked (`DATASET_ARRAYS`, mug
    by mug in the given order, plus "split" and "seed" as 0-d arrays).

    Occluder mugs come from the same list (the target itself excluded), so no other split leaks
    in. View k of mug i draws everything from `default_rng([seed, i, k])`: the result does not
    depend on the order of `mug_indices` or on `workers` (processes; 1 = this process). Workers
    are spawned, so a script that calls this with workers > 1 needs the `if __name__ ==
    "__main__":` guard.
    """
    mug_indices = [int(i) for i in mug_indices]
    if not mug_indices or len(set(mug_indices)) != len(mug_indices):
        raise DataError(f"mug_indices must be a non-empty list of distinct indices, got {mug_indices[:10]}")
    if views_per_mug < 1 or seed < 0:
        raise DataError(f"need views_per_mug >= 1 and seed >= 0, got {views_per_mug} and {seed}")
    pool = sorted(mug_indices)
    tasks = [(split, index, pool, views_per_mug, seed, config) for index in mug_indices]
    if workers <= 1 or len(tasks) == 1:
        parts = [_views_of_mug(*task) for task in tasks]
    else:
        # Fresh interpreters: forking a process whose Open3D (TBB) threads have run can deadlock.
        with multiprocessing.get_context("spawn").Pool(min(workers, len(tasks))) as processes:
            parts = processes.starmap(_views_of_mug, tasks, chunksize=1)
    dataset = {name: np.concatenate([part[name] for part in parts]) for name in DATASET_ARRAYS}
    return dataset | {"split": np.array(split), "seed": np.array(seed)}


def _views_of_mug(split: str, mug_index: int, pool: list[int], views_per_mug: int, seed: int,
                  config: ViewConfig) -> dict[str, np.ndarray]:
    """All views of one mug, stacked: one task, so that the mug's cached samples are reused."""
    mug = _split_mug(split, mug_index)
    candidates = [i for i in pool if i != mug_index]
    views = []
    for view_id in range(views_per_mug):
        rng = np.random.default_rng([seed, mug_index, view_id])
        # As many candidate occluder mugs as there can be occluders: only those get built.
        picked = rng.choice(len(candidates), min(config.occluder_count_range[1], len(candidates)), replace=False)
        others = [_split_mug(split, candidates[i]) for i in picked]
        views.append(render_view(mug, others, rng, config, mug_index=mug_index, view_id=view_id))
    stacked = {
        "points": [v.points for v in views],
        "n_visible": [v.n_visible for v in views],
        "pose_camera_object": [v.pose_camera_object for v in views],
        "center": [v.center_camera for v in views],
        "queries": [v.queries for v in views],
        "occupancy": [v.occupancy for v in views],
        "mug_index": [v.mug_index for v in views],
        "view_id": [v.view_id for v in views],
    }
    return {name: np.asarray(values, dtype=DATASET_ARRAYS[name]) for name, values in stacked.items()}


@functools.lru_cache(maxsize=2048)
def _split_mug(split: str, index: int) -> Mug:
    # Building a mug takes ~7 ms and a worker reuses the same few hundred as occluders.
    return make_split_mug(split, index)


def write_dataset(path: str | Path, dataset: dict[str, np.ndarray]) -> Path:
    """Write `dataset` to `path` as one compressed .npz; a reader never sees a half-written file."""
    path = Path(path)
    with atomic_path(path) as temporary, open(temporary, "wb") as file:  # a file object: np.savez would append ".npz" to a name
        np.savez_compressed(file, **dataset)
    return path


def load_dataset(path: str | Path) -> dict[str, np.ndarray]:
    """The dataset written to `path` by `write_dataset`. DataError, naming the file, if it is
    missing, unreadable, or lacks or mis-shapes any of `DATASET_ARRAYS`."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such dataset file")
    try:
        with np.load(path, allow_pickle=False) as archive:
            dataset = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as error:
        raise DataError(f"{path}: not a readable dataset file ({error})") from error
    _check_dataset(path, dataset)
    return dataset


def _check_dataset(path: Path, dataset: dict[str, np.ndarray]) -> None:
    missing = sorted(set(DATASET_ARRAYS) - set(dataset))
    if missing:
        raise DataError(f"{path}: not a dataset file, it lacks {', '.join(missing)}")
    views = len(dataset["points"])
    points, queries = dataset["points"], dataset["queries"]
    shapes_ok = (
        points.ndim == 3 and points.shape[2] == 3 and queries.ndim == 3 and queries.shape[2] == 3
        and dataset["occupancy"].shape == queries.shape[:2]
        and dataset["pose_camera_object"].shape == (views, 4, 4) and dataset["center"].shape == (views, 3)
        and all(len(dataset[name]) == views for name in DATASET_ARRAYS)
    )
    if not shapes_ok:
        shapes = {name: dataset[name].shape for name in DATASET_ARRAYS}
        raise DataError(f"{path}: dataset arrays have inconsistent shapes {shapes}")
