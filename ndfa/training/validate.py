"""What a model makes of a dataset's views: their latents z (`encode_views`), each object's mean
shape code (`mean_codes`), and the validation figures of training (`validate`).

Every view is centred on its points' mean and given its true up and view ray, as in training.
"""

from __future__ import annotations

import numpy as np
import torch

from ndfa.ndf.model import NDFModel
from ndfa.sim.categories import CATEGORIES
from ndfa.training.dataset import object_ids
from ndfa.training.metrics import center_errors_mm, pair_separation, retrieval_top1


def view_cues(dataset: dict[str, np.ndarray], rows: slice | np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """The true up (the object's axis: it stands on a level table) and the view ray `[V, 3]` of views `rows`."""
    up = torch.from_numpy(dataset["pose_camera_object"][rows, :3, 2].astype(np.float32))
    return up, torch.from_numpy(dataset["points"][rows].mean(axis=1).astype(np.float32))


@torch.inference_mode()
def encode_views(model: NDFModel, dataset: dict[str, np.ndarray], batch_size: int = 256) -> torch.Tensor:
    """z `[V, k, 3]` of every view of `dataset`, each centred on its points' mean."""
    model.eval()
    out = []
    for start in range(0, len(dataset["points"]), batch_size):
        points = torch.from_numpy(dataset["points"][start:start + batch_size])
        up, view_ray = view_cues(dataset, slice(start, start + batch_size))
        out.append(model.encode(points - points.mean(dim=1, keepdim=True), up, view_ray))
    return torch.cat(out).clone()  # a normal tensor: inference tensors cannot enter autograd


@torch.inference_mode()
def validate(model: NDFModel, dataset: dict[str, np.ndarray], shape_threshold: float, batch_size: int = 64) -> dict[str, float]:
    """Occupancy accuracy on the views' query points, center error, shape-code retrieval and, for a
    model with categories, the category head's accuracy."""
    model.eval()
    codes, centers, correct, axis_cosines, categories = [], [], [], [], []
    for start in range(0, len(dataset["points"]), batch_size):
        points = torch.from_numpy(dataset["points"][start:start + batch_size])
        queries = torch.from_numpy(dataset["queries"][start:start + batch_size])
        centroid = points.mean(dim=1, keepdim=True)
        out = model(points - centroid, queries - centroid, *view_cues(dataset, slice(start, start + batch_size)))
        codes.append(out["shape_code"].numpy())
        centers.append((centroid[:, 0] + out["center_offset"]).numpy())
        labels = dataset["occupancy"][start:start + batch_size]
        correct.append(((out["occupancy_logits"] > 0).numpy() == labels).mean(axis=1))
        if "frame_vectors" in out:
            true_axis = torch.from_numpy(dataset["pose_camera_object"][start:start + batch_size, :3, 2])
            axis_cosines.append(torch.cosine_similarity(out["frame_vectors"][..., 0], true_axis, dim=-1).numpy())
        if "category_logits" in out:
            categories.append(predicted_categories(model, out["category_logits"]))
    codes = np.concatenate(codes)
    # How far the decoder's frame axis is from the mug's true axis, median degrees.
    extra = {"axis_error_deg": float(np.degrees(np.median(np.arccos(np.clip(np.concatenate(axis_cosines), -1, 1)))))} if axis_cosines else {}
    labels = object_ids(dataset)
    if categories:
        extra["category_accuracy"] = float(np.mean(np.concatenate(categories) == dataset["category"]))
    separation = pair_separation(codes, labels, shape_threshold)
    return {
        "occ_accuracy": float(np.concatenate(correct).mean()),
        **center_errors_mm(np.concatenate(centers), dataset["center"]),
        "retrieval_top1": retrieval_top1(codes, labels),
        "auc": separation["auc"],
        "same_above": separation["same_above"],
        "different_above": separation["different_above"],
    } | extra


@torch.inference_mode()
def mean_codes(model: NDFModel, dataset: dict[str, np.ndarray], n_mugs: int, views: int = 4) -> torch.Tensor:
    """The mean unit shape code of each object `[n_mugs, D]` (by `object_ids`) over its first `views` views."""
    rows = np.flatnonzero(dataset["view_id"] < views)
    codes = torch.nn.functional.normalize(model.shape_code(encode_views(model, _subset(dataset, rows))), dim=1)
    labels = torch.from_numpy(object_ids(dataset)[rows])
    return torch.zeros(n_mugs, codes.shape[1]).index_add_(0, labels, codes) / torch.bincount(labels, minlength=n_mugs).clamp_min(1)[:, None]


def _subset(dataset: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    return {name: values[rows] if values.ndim else values for name, values in dataset.items()}


def predicted_categories(model: NDFModel, logits: torch.Tensor) -> np.ndarray:
    """The category head's choice for each row of `logits` `[B, C]`, as indices into `CATEGORIES`."""
    names = model.config.categories
    return np.array([CATEGORIES.index(names[i]) for i in logits.argmax(dim=1).tolist()], dtype=np.int64)
