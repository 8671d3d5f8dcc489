"""`ndfa ndf-eval`: the model-quality report on held-out test-split mugs (or objects of several
categories, `ndfa.sim.categories`; "mug" below is whatever object a view shows).

Each held-out view (test-split mugs, never seen in training, with occluders and depth noise) is
encoded; the report gives

- the center error against the true center of the full mug (three ways of recovering it:
  the equivariant center head, the paper's mean of the reconstructed points, and the
  occupancy-weighted mean),
- shape-code retrieval (is the most similar other view of the same mug?), the fraction of
  same-mug and different-mug pairs above delta_s, and the ROC AUC over all pairs,
- reconstruction IoU on a regular grid over the mug's bounding box, from exact occupancy, at the
  encoder's v0 and at a few other thresholds; and, for reference, the IoU that the true shape
  itself scores when it is displaced by the view's center error (how much of the IoU a mug's
  3-8 mm walls lose to localisation alone, whatever the decoder);
- the headline: the same figures for the views in the detector's regime, the mug within 2 m of
  the camera and at least `VISIBLE_PIXELS` points seen (the detector encodes no smaller mask):
  the head's center error and retrieval among those views, both by mug and with box twins
  (mugs within 1 cm in every box dimension, which a view cannot tell apart by size) merged;
- with several categories, the same headline per category (prefixed by its name): center
  median and p90, retrieval top-1 (the nearest other view among all categories' views in the
  regime shows the same object), and for a model with a category head its accuracy;
- the same per category for *tracks*, as the detector holds an object: `TRACK_VIEWS` of an
  object's regime views fused (the mean of their unit codes, the category its views' votes name,
  as `ndfa.change.associate.SessionObject` does), two disjoint tracks per object drawn
  `TRACK_DRAWS` times; a track's retrieval hit is its nearest other track being the same
  object's. One view of a mug with its handle hidden has a cup's or a can's shape; a pass sees
  an object from several sides, and the track figures say what that gives.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import torch

from ndfa.change.associate import likeliest
from ndfa.core.conventions import VISIBLE_PIXELS
from ndfa.core.geometry import invert_pose, transform_points
from ndfa.ndf.encoder import CENTER_METHODS, FINE_GRID_RESOLUTION, EncoderConfig, NDFEncoder
from ndfa.sim.categories import CATEGORIES, CategoryObject
from ndfa.sim.splits import make_split_object
from ndfa.training.dataset import generate_views, object_ids
from ndfa.training.metrics import center_errors_mm, iou, nearest_other, pair_separation
from ndfa.training.validate import predicted_categories
from ndfa.training.views import ViewConfig

NEAR_M = 2.0  # views with the mug this close to the camera (and VISIBLE_PIXELS points) make the headline
TWIN_M = 0.01  # two mugs whose boxes differ by less than this in every dimension are box twins
IOU_THRESHOLDS = (0.3, 0.4, 0.5, 0.6)  # occupancy thresholds of the IoU sweep
TRACK_VIEWS = 5  # views fused into a track (an object's views in a pass are many more, from fewer sides)
TRACK_DRAWS = 10  # random draws of two disjoint tracks per object


def evaluate_ndf(
    weights: Path | None = None,
    mugs: int = 20,
    views_per_mug: int = 50,
    seed: int = 0,
    shape_threshold: float = 0.9,
    iou_grid: int = 32,
    views: dict[str, np.ndarray] | None = None,
    v0: float = EncoderConfig.v0,
    categories: tuple[str, ...] = ("mug",),
) -> tuple[dict[str, float], pl.DataFrame]:
    """Summary figures and a per-view table for the model at `weights` (default: shipped), with
    occupancy threshold `v0` for the reconstruction.

    `views` replaces the rendered test views of `categories` (e.g. a cached set, or a small one in tests).
    `iou_grid` 0 skips the reconstruction IoU (most of the time of an evaluation).
    """
    if views is None:
        views = generate_views("test", list(range(mugs)), views_per_mug, seed, ViewConfig(), categories=categories)
    clouds = list(views["points"])
    # World = each view's mug frame, whose z is up (the mug stands on a level table): models with
    # the up cue get it from these poses, as the detector's from its camera poses.
    poses = [invert_pose(pose.astype(np.float64)) for pose in views["pose_camera_object"]]
    true_centers = np.stack([transform_points(pose, center[None])[0] for pose, center in zip(poses, views["center"])])
    # Torch, the reference runtime: the model card's figures are the model's, not a runtime's.
    encoders = {method: NDFEncoder(weights, EncoderConfig(center=method, v0=v0, grid_resolution=FINE_GRID_RESOLUTION,
                                                          runtime="torch"))
                for method in CENTER_METHODS}
    codes = {method: encoder.encode_batch(clouds, poses) for method, encoder in encoders.items()}
    shape_codes = np.stack([c.shape_code for c in codes["head"]])
    labels = object_ids(views)

    summary: dict[str, float] = {"views": float(len(clouds)), "mugs": float(len(np.unique(labels)))}
    per_view = {"category": np.array(CATEGORIES)[views["category"]], "object_index": views["object_index"],
                "object_id": labels, "view_id": views["view_id"], "n_visible": views["n_visible"]}
    centers = {method: np.stack([c.center_world for c in codes[method]]) for method in CENTER_METHODS}
    for method in CENTER_METHODS:
        errors = center_errors_mm(centers[method], true_centers)
        summary |= {f"{key}_{method}": value for key, value in errors.items()}
        per_view[f"center_error_mm_{method}"] = np.linalg.norm(centers[method] - true_centers, axis=1) * 1e3
    # The views' cameras stand up to 5 m from the table, where a mug is ~80 points with ~4 cm of
    # depth noise; the detector encodes only masks of >= 300 pixels (a mug within ~2.5 m). The
    # head's center error on the near views is closer to what the detector sees (the headline
    # figures above are over all views).
    distance = np.linalg.norm(views["center"], axis=1)
    per_view["distance_m"] = distance
    near = (distance <= NEAR_M) & (views["n_visible"] >= VISIBLE_PIXELS)
    per_view["detector_regime"] = near
    summary["views_within_2m"] = float(near.sum())
    summary |= {f"{key}_head_within_2m": value
                for key, value in center_errors_mm(centers["head"][near], true_centers[near]).items()}
    split = str(views.get("split", "test"))
    twins = box_twins(split, views)
    if near.sum() > 1:
        near_retrieved = labels[near][nearest_other(shape_codes[near])]
        summary["retrieval_top1_within_2m"] = float(np.mean(near_retrieved == labels[near]))
        summary["retrieval_top1_within_2m_twins_merged"] = float(np.mean(
            [twins[a, b] for a, b in zip(near_retrieved, labels[near])]))
    retrieved = labels[nearest_other(shape_codes)]
    per_view["retrieved_object_id"] = retrieved  # which object the nearest other view shows
    per_view["retrieved_same_object"] = hits = retrieved == labels
    summary["retrieval_top1"] = float(hits.mean())
    summary |= pair_separation(shape_codes, labels, shape_threshold)
    if iou_grid > 0:
        # World is each view's mug frame, so the center error is a displacement in the mug frame.
        ious, swept, shifted = reconstruction_iou(encoders["head"], views, iou_grid, centers["head"] - true_centers)
        summary["iou_mean"] = float(np.nanmean(ious))
        summary["iou_median"] = float(np.nanmedian(ious))
        summary |= {f"iou_mean_v0_{threshold}": float(np.nanmean(values)) for threshold, values in swept.items()}
        summary["iou_mean_true_shape_displaced"] = float(np.nanmean(shifted))
        per_view["iou"] = ious
        per_view["iou_true_shape_displaced"] = shifted
    per_view["mean_occupancy"] = np.array([c.mean_occupancy for c in codes["head"]])
    model = encoders["head"].model
    if model.category_head is not None:
        with torch.inference_mode():
            logits = model.category_logits(torch.from_numpy(shape_codes.astype(np.float32)))
            per_view["predicted_category"] = np.array(CATEGORIES)[predicted_categories(model, logits)]
            per_view["category_probability"] = torch.softmax(logits, dim=1).max(dim=1).values.numpy()
    if len(np.unique(views["category"])) > 1 or model.category_head is not None:
        summary |= per_category(per_view, centers["head"], true_centers, shape_codes)
        summary |= per_track(per_view, shape_codes)
    return summary, pl.DataFrame(per_view)


def per_category(per_view: dict[str, np.ndarray], centers: np.ndarray, true_centers: np.ndarray,
                 shape_codes: np.ndarray) -> dict[str, float]:
    """The detector-regime headline of each category among the views (`per_view`'s category,
    object_id, detector_regime and predicted_category), keys prefixed by the category's name, and
    the category accuracy over all categories. Retrieval is among the regime's views of every
    category: a bowl's view retrieving a cup's is a miss."""
    near = per_view["detector_regime"]
    labels = per_view["object_id"]
    summary: dict[str, float] = {}
    retrieved = labels[near][nearest_other(shape_codes[near])] if near.sum() > 1 else None
    if "predicted_category" in per_view:
        summary["category_accuracy_within_2m"] = float(np.mean(per_view["predicted_category"][near] == per_view["category"][near]))
    for category in CATEGORIES:
        mine = per_view["category"] == category
        if not mine.any():
            continue
        regime = mine & near
        summary[f"{category}_views_within_2m"] = float(regime.sum())
        if not regime.any():
            continue
        summary |= {f"{category}_{key}_within_2m": value
                    for key, value in center_errors_mm(centers[regime], true_centers[regime]).items()}
        if retrieved is not None:
            summary[f"{category}_retrieval_top1_within_2m"] = float(np.mean((retrieved == labels[near])[mine[near]]))
        if "predicted_category" in per_view:
            summary[f"{category}_category_accuracy_within_2m"] = float(np.mean(per_view["predicted_category"][regime] == category))
    return summary


def per_track(per_view: dict[str, np.ndarray], shape_codes: np.ndarray, views_per_track: int = TRACK_VIEWS,
              draws: int = TRACK_DRAWS, seed: int = 0) -> dict[str, float]:
    """Retrieval top-1 and category accuracy of tracks (`views_per_track` regime views of one
    object fused), over all categories and per category (`{category}_track_...`). Objects with
    fewer than two tracks' worth of regime views are left out (their count: `track_objects`)."""
    near = per_view["detector_regime"]
    labels, truth = per_view["object_id"], per_view["category"]
    rng = np.random.default_rng(seed)
    units = shape_codes / np.maximum(np.linalg.norm(shape_codes, axis=1, keepdims=True), 1e-12)
    objects = [o for o in np.unique(labels[near]) if np.sum(near & (labels == o)) >= 2 * views_per_track]
    codes, track_labels, named, track_truth = [], [], [], []
    for _ in range(draws):
        for o in objects:
            rows = rng.permutation(np.flatnonzero(near & (labels == o)))[:2 * views_per_track]
            for track in (rows[:views_per_track], rows[views_per_track:]):
                codes.append(units[track].mean(axis=0))
                track_labels.append(o)
                track_truth.append(truth[track[0]])
                if "predicted_category" in per_view:
                    named.append(voted_category(per_view["predicted_category"][track], per_view["category_probability"][track]))
    summary: dict[str, float] = {"track_objects": float(len(objects))}
    if len(objects) < 2:
        return summary
    # Nearest other track within the same draw: each draw is its own gallery.
    per_draw = 2 * len(objects)
    track_labels_array, truth_array = np.array(track_labels), np.array(track_truth)
    hits = np.concatenate([track_labels_array[d:d + per_draw][nearest_other(np.array(codes[d:d + per_draw]))]
                           == track_labels_array[d:d + per_draw] for d in range(0, len(codes), per_draw)])
    right = np.array(named) == truth_array if named else None
    summary["track_retrieval_top1"] = float(hits.mean())
    if right is not None:
        summary["track_category_accuracy"] = float(right.mean())
    for category in CATEGORIES:
        mine = truth_array == category
        if mine.any():
            summary[f"{category}_track_retrieval_top1"] = float(hits[mine].mean())
            if right is not None:
                summary[f"{category}_track_category_accuracy"] = float(right[mine].mean())
    return summary


def voted_category(categories: np.ndarray, probabilities: np.ndarray) -> str:
    """The category a track's views name: each view's probability summed on its likeliest category,
    the largest sum (`SessionObject.vote` and `.category`)."""
    votes: dict[str, float] = {}
    for category, probability in zip(categories.tolist(), probabilities.tolist()):
        votes[category] = votes.get(category, 0.0) + probability
    return likeliest(votes)


def box_twins(split: str, views: dict[str, np.ndarray]) -> np.ndarray:
    """[O, O] bool over the views' objects (`object_ids`): same object, or of one category with
    boxes within `TWIN_M` in every dimension (a view then shows the same size; `studies/ndf_limits.py`)."""
    ids = object_ids(views)
    extents, category = np.zeros((ids.max() + 1, 3)), np.zeros(ids.max() + 1, dtype=np.int64)
    for object_id in np.unique(ids):
        row = int(np.argmax(ids == object_id))
        category[object_id] = views["category"][row]
        low, high = _split_object(split, views, row).mesh.bounds
        extents[object_id] = high - low
    difference = np.abs(extents[:, None] - extents[None]).max(axis=2)
    twins: np.ndarray = (difference < TWIN_M) & (category[:, None] == category[None])
    np.fill_diagonal(twins, True)
    return twins


@torch.inference_mode()
def reconstruction_iou(encoder: NDFEncoder, views: dict[str, np.ndarray], resolution: int,
                       center_errors: np.ndarray) -> tuple[np.ndarray, dict[float, np.ndarray], np.ndarray]:
    """Per view, on a `resolution`^3 grid spanning the mug's bounding box enlarged by 10%: the IoU
    of predicted (> the encoder's v0) and exact occupancy; the same at each of `IOU_THRESHOLDS`;
    and the IoU of the exact occupancy with itself displaced by the view's `center_errors` [V, 3]
    (mug frame, metres): what a perfect reconstruction placed at the predicted center would score."""
    mugs: dict[int, tuple[CategoryObject, np.ndarray, np.ndarray]] = {}
    ids = object_ids(views)
    result, shifted = np.empty(len(views["points"])), np.empty(len(views["points"]))
    swept = {threshold: np.empty(len(views["points"])) for threshold in IOU_THRESHOLDS}
    for i, (points, pose) in enumerate(zip(views["points"], views["pose_camera_object"])):
        index = int(ids[i])
        if index not in mugs:
            mug = _split_object(str(views.get("split", "test")), views, i)
            lo, hi = mug.mesh.bounds
            pad = 0.05 * (hi - lo)
            axes = [np.linspace(a, b, resolution) for a, b in zip(lo - pad, hi + pad)]
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            mugs[index] = (mug, grid, mug.occupancy(grid))
        mug, grid, truth = mugs[index]
        cloud = encoder.resample(points)
        z, centred, centroid = encoder.latent(cloud[None], [invert_pose(pose.astype(np.float64))])
        queries = transform_points(pose, grid) - centroid[0, 0]
        logits = encoder.model.occupancy_logits(z, torch.from_numpy(queries.astype(np.float32))[None], centred)[0]
        occupancy = torch.sigmoid(logits).numpy()
        result[i] = iou(occupancy > encoder.config.v0, truth)
        for threshold, values in swept.items():
            values[i] = iou(occupancy > threshold, truth)
        shifted[i] = iou(mug.occupancy(grid - center_errors[i]), truth)
    return result, swept, shifted


def _split_object(split: str, views: dict[str, np.ndarray], row: int) -> CategoryObject:
    """The object view `row` of `views` shows."""
    return make_split_object(CATEGORIES[int(views["category"][row])], split, int(views["object_index"][row]))
