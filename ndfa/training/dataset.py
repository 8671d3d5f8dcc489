"""Training datasets of the NDF: many rendered views (`ndfa.training.views`) of the objects of one
split, of one category (the mugs) or several (`ndfa.sim.categories`), stacked into arrays
(`DATASET_ARRAYS`), and their .npz files.

An object is (category, index within the category's split); `object_ids` numbers the objects of a
dataset 0, 1, ... for the identity losses and the metrics.

Determinism: a view depends only on (seed, category, object index, view number) and the set of
objects that may lend it occluders, never on the order of generation or on the number of worker
processes. A mug's view draws from `default_rng([seed, index, view])`, as before there were
other categories; another category's appends its number (`CATEGORIES`), so a mugs-only dataset
is what it always was.
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
from ndfa.sim.categories import CATEGORIES, CategoryObject
from ndfa.sim.splits import make_split_object
from ndfa.training.views import ViewConfig, render_view

# Per-view arrays of a dataset (`generate_views`, `load_dataset`): name -> dtype. V views.
DATASET_ARRAYS = {
    "points": np.float32,              # (V, n_points, 3) camera frame
    "n_visible": np.int32,             # (V,) object points seen before resampling
    "pose_camera_object": np.float32,  # (V, 4, 4) object frame -> camera frame
    "center": np.float32,              # (V, 3) View.center_camera
    "queries": np.float32,             # (V, n_queries, 3) camera frame
    "occupancy": np.bool_,             # (V, n_queries)
    "object_index": np.int32,          # (V,) index of the object within its category's split
    "category": np.int32,              # (V,) its category, an index into `CATEGORIES`
    "view_id": np.int32,               # (V,) view number of that object: (seed, category, object_index, view_id) redraws it
}
# Occluders come from at most this many of a dataset's objects, an equal share of each category
# (the first indices): each worker keeps them built (`_split_object`), and 4 occluders a view
# drawn from all of 6,000 objects would rebuild them over and over (a box takes 38 ms).
OCCLUDER_POOL = 2048


def generate_views(split: str, object_indices: list[int], views_per_object: int, seed: int,
                   config: ViewConfig = ViewConfig(), workers: int = 2,
                   categories: tuple[str, ...] = ("mug",)) -> dict[str, np.ndarray]:
    """`views_per_object` views of each object `object_indices` of `split` in each of `categories`,
    stacked (`DATASET_ARRAYS`, category by category and object by object in the given order, plus
    "split" and "seed" as 0-d arrays).

    Occluder objects come from the same objects (`OCCLUDER_POOL`; the target itself excluded), of
    any of the categories, so no other split leaks in. The result does not depend on the order
    of `object_indices` or on `workers` (processes; 1 = this process). Workers are spawned, so a
    script that calls this with workers > 1 needs the `if __name__ == "__main__":` guard.
    """
    object_indices = [int(i) for i in object_indices]
    if not object_indices or len(set(object_indices)) != len(object_indices):
        raise DataError(f"object_indices must be a non-empty list of distinct indices, got {object_indices[:10]}")
    if views_per_object < 1 or seed < 0:
        raise DataError(f"need views_per_object >= 1 and seed >= 0, got {views_per_object} and {seed}")
    unknown = [c for c in categories if c not in CATEGORIES]
    if not categories or unknown or len(set(categories)) != len(categories):
        raise DataError(f"categories must be distinct ones of {', '.join(CATEGORIES)}, got {', '.join(categories) or 'none'}")
    share = OCCLUDER_POOL // len(categories)
    pool = [(category, index) for category in categories for index in sorted(object_indices)[:share]]
    tasks = [(split, category, index, pool, views_per_object, seed, config) for category in categories for index in object_indices]
    if workers <= 1 or len(tasks) == 1:
        parts = [_views_of_object(*task) for task in tasks]
    else:
        # Fresh interpreters: forking a process whose Open3D (TBB) threads have run can deadlock.
        with multiprocessing.get_context("spawn").Pool(min(workers, len(tasks))) as processes:
            parts = processes.starmap(_views_of_object, tasks, chunksize=1)
    dataset = {name: np.concatenate([part[name] for part in parts]) for name in DATASET_ARRAYS}
    return dataset | {"split": np.array(split), "seed": np.array(seed)}


def object_ids(dataset: dict[str, np.ndarray]) -> np.ndarray:
    """(V,) int64: each view's object numbered 0, 1, ... in (category, object index) order; for
    the training objects of one category (indices 0 to N - 1) that is the object index."""
    key = dataset["category"].astype(np.int64) << 32 | dataset["object_index"].astype(np.int64)
    ids: np.ndarray = np.unique(key, return_inverse=True)[1].reshape(-1)
    return ids


def _views_of_object(split: str, category: str, index: int, pool: list[tuple[str, int]], views_per_object: int,
                     seed: int, config: ViewConfig) -> dict[str, np.ndarray]:
    """All views of one object, stacked: one task, so that the object's cached samples are reused."""
    target = _split_object(category, split, index)
    candidates = [entry for entry in pool if entry != (category, index)]
    category_key = [] if category == "mug" else [CATEGORIES.index(category)]
    views = []
    for view_id in range(views_per_object):
        rng = np.random.default_rng([seed, index, view_id, *category_key])
        # As many candidate occluders as there can be occluders: only those get built.
        picked = rng.choice(len(candidates), min(config.occluder_count_range[1], len(candidates)), replace=False)
        others = [_split_object(candidates[i][0], split, candidates[i][1]) for i in picked]
        views.append(render_view(target, others, rng, config, object_index=index, view_id=view_id))
    stacked = {
        "points": [v.points for v in views],
        "n_visible": [v.n_visible for v in views],
        "pose_camera_object": [v.pose_camera_object for v in views],
        "center": [v.center_camera for v in views],
        "queries": [v.queries for v in views],
        "occupancy": [v.occupancy for v in views],
        "object_index": [v.object_index for v in views],
        "category": [CATEGORIES.index(category)] * len(views),
        "view_id": [v.view_id for v in views],
    }
    return {name: np.asarray(values, dtype=DATASET_ARRAYS[name]) for name, values in stacked.items()}


@functools.lru_cache(maxsize=OCCLUDER_POOL)
def _split_object(category: str, split: str, index: int) -> CategoryObject:
    # Building a mug takes ~4 ms, a box ~38 ms, and a worker reuses the same ones as occluders.
    return make_split_object(category, split, index)


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
    if "mug_index" in dataset and "object_index" not in dataset:  # written before there were categories: mugs
        dataset["object_index"] = dataset.pop("mug_index")
        dataset["category"] = np.full(len(dataset["object_index"]), CATEGORIES.index("mug"), dtype=np.int32)
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
