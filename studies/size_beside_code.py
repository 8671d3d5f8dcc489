"""How far a view's measured size, beside its shape code, takes instance retrieval (issue 33).

`ndfa ndf-eval`'s retrieval asks of each view in the detector's regime (within 2 m, >= 300 points)
whether its most similar other view shows the same object; NDF v3's shape codes alone give 0.60-0.79
per category, under the issue's 0.85 (MODEL_CARD.md). A view also measures its object's size
directly, whatever the network learnt: how far its points reach up (the visible top less the
lowest visible point) and across the line of sight. This study scores retrieval by the codes'
cosine less a penalty per centimetre of difference in those two sizes, with the two weights chosen
on views of unseen train-split objects and reported on the test split's (the held-out objects ndf-eval
uses), per category. Nothing in the package uses it; it says whether wiring sizes into the
detector's shape test is worth doing.

    python studies/size_beside_code.py [WEIGHTS] [OBJECTS] [VIEWS]    # default: v3, 20 objects, 50 views
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ndfa.core.conventions import VISIBLE_PIXELS
from ndfa.core.geometry import invert_pose, transform_points
from ndfa.ndf.encoder import EncoderConfig, NDFEncoder
from ndfa.sim.categories import CATEGORIES
from ndfa.training.dataset import generate_views, object_ids
from ndfa.training.metrics import cosine_similarity_matrix
from ndfa.training.views import ViewConfig

NEAR_M = 2.0
UNSEEN_TRAIN = 2000  # the first train-split object index the calibration views are of
WEIGHTS = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0)  # cosine taken off per metre of size difference (1 cm: 0.01-0.16)


def measured_sizes(views: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per view, in its object's frame (z up): the points' reach up (97th less 3rd percentile of
    height), across the line of sight (the same, horizontally, perpendicular to the camera's
    horizontal direction to the object), and the world poses (camera -> object frame)."""
    heights, widths, poses = [], [], []
    for points, pose_camera_object, center in zip(views["points"], views["pose_camera_object"], views["center"]):
        pose = invert_pose(pose_camera_object.astype(np.float64))
        world = transform_points(pose, points.astype(np.float64))
        object_center = transform_points(pose, center[None].astype(np.float64))[0]
        heights.append(np.subtract(*np.percentile(world[:, 2], [97, 3])))
        sight = object_center[:2] - pose[:2, 3]
        across = np.array([-sight[1], sight[0]]) / max(np.linalg.norm(sight), 1e-9)
        widths.append(np.subtract(*np.percentile(world[:, :2] @ across, [97, 3])))
        poses.append(pose)
    return np.array(heights), np.array(widths), np.array(poses)


def encode(views: dict[str, np.ndarray], weights: Path | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit codes, heights, widths and the regime mask of the views."""
    heights, widths, poses = measured_sizes(views)
    encoder = NDFEncoder(weights, EncoderConfig())
    codes = np.stack([c.shape_code for c in encoder.encode_batch(list(views["points"]), list(poses))])
    codes /= np.linalg.norm(codes, axis=1, keepdims=True)
    near = (np.linalg.norm(views["center"], axis=1) <= NEAR_M) & (views["n_visible"] >= VISIBLE_PIXELS)
    return codes, heights, widths, near


def top1_per_category(codes, heights, widths, labels, categories, a: float, b: float) -> dict[str, float]:
    """Retrieval top-1 per category with similarity cos - a |dh| - b |dw| (sizes in metres)."""
    similarity = cosine_similarity_matrix(codes)
    similarity -= a * np.abs(heights[:, None] - heights[None]) + b * np.abs(widths[:, None] - widths[None])
    np.fill_diagonal(similarity, -np.inf)
    hits = labels[np.argmax(similarity, axis=1)] == labels
    return {CATEGORIES[c]: float(hits[categories == c].mean()) for c in np.unique(categories)} | {"all": float(hits.mean())}


def main() -> None:
    weights = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("ndfa/ndf/weights/ndf_objects.pt")
    objects = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    per_object = int(sys.argv[3]) if len(sys.argv) > 3 else 50
    results = {}
    # Calibration: train-split objects far past those training and its validation drew (TrainConfig's
    # train_mugs 400, val_mugs 24), never seen; the report: the test split's, as ndf-eval's.
    for split, split_name, first in (("val", "train", UNSEEN_TRAIN), ("test", "test", 0)):
        views = generate_views(split_name, list(range(first, first + objects)), per_object, 0, ViewConfig(),
                               categories=CATEGORIES)
        codes, heights, widths, near = encode(views, weights)
        labels, categories = object_ids(views)[near], views["category"][near]
        results[split] = (codes[near], heights[near], widths[near], labels, categories)
        print(f"{split}: {near.sum()} regime views of {len(near)}", flush=True)
    best = max(((a, b) for a in WEIGHTS for b in WEIGHTS),
               key=lambda ab: top1_per_category(*results["val"], *ab)["all"])
    print(f"weights chosen on val (cosine per metre of height, of width): {best}")
    for split in ("val", "test"):
        alone = top1_per_category(*results[split], 0.0, 0.0)
        sized = top1_per_category(*results[split], *best)
        print(f"{split} top-1, codes alone -> codes and sizes:")
        for name in alone:
            print(f"  {name:7s} {alone[name]:.3f} -> {sized[name]:.3f}")


if __name__ == "__main__":
    main()
