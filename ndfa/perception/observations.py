"""Frames -> object observations: one partial point cloud per instance in the frame's mask.

For each instance id in the mask: the depth pixels of the instance, within the depth range,
back-projected with K to the camera frame; subsampled to at most `max_points` (the encoder uses
fewer); cleaned by keeping the largest cluster of points linked through occupied voxels of
`cluster_voxel_m` (close to single linkage / DBSCAN, as the paper's real pipeline cleans its
segments: depth noise at mask edges throws some pixels onto the background far behind). A mask
that is too small or falls apart is skipped, with the reason, so that every instance seen in a
frame is accounted for in the tables. A mask skipped only for its size, from `sighting_pixels` up,
still says where something stood: its cleaned points' centroid (a sighting, no shape; what the
detector makes of it: `ndfa.change.sightings`).

Pure numpy/scipy; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M, VISIBLE_PIXELS, depth_in_range
from ndfa.core.frame import Frame
from ndfa.core.geometry import backproject


@dataclass(frozen=True)
class ObservationConfig:
    """How instance masks become point clouds. Lengths in metres.

    min_depth_m, max_depth_m: depth range kept (`ndfa.core.conventions`: beyond ~4 m a mug covers
        a few hundred pixels and the sensor noise, growing with depth squared, is a sizeable
        fraction of its size).
    min_pixels: smaller masks are skipped: too little of the shape to encode reliably
        (`conventions.VISIBLE_PIXELS`, which scoring shares). On the `paper` scene the shipped
        NDF's centers from masks of <= 300 pixels erred by 13 mm (median; 41 mm p90), from larger
        ones by 3 mm (8 mm p90), in the horizontal plane.
    skip_border: skip masks that touch the image border: the object may be cut off, and the
        center of a cut-off view is pulled toward the part in view (median error 2-3x larger).
    max_points: the cloud is subsampled to this before cleaning (the encoder resamples to its own
        count, 400 for the shipped model), which bounds the cost of cleaning per object.
    cluster_voxel_m: points are grouped in voxels of this size, and touching voxels join one
        cluster (see `largest_cluster`). A 640-px-wide 60 degree camera samples a surface 3 m
        away every ~5 mm (every ~11 mm once subsampled to `max_points`), so 1.5 cm voxels join a
        mug's points at any depth in range.
    min_cluster_fraction: the largest cluster must hold at least this share of the points, else
        the mask is skipped as fragmented (e.g. split by an occluder into two unrelated pieces).
    sighting_pixels: a mask skipped only for its size (below `min_pixels`, not on the border, not
        fragmented) of at least this many pixels is a sighting: its cleaned points' centroid is
        kept (`SkippedObservation.center_camera`). Half the bar: a mug at the far end of the depth
        range still fills it, and fewer pixels are mostly a mask's sliver. Off: 0.
    """

    min_depth_m: float = MIN_DEPTH_M
    max_depth_m: float = MAX_DEPTH_M
    min_pixels: int = VISIBLE_PIXELS
    skip_border: bool = True
    max_points: int = 1000
    cluster_voxel_m: float = 0.015
    min_cluster_fraction: float = 0.5
    sighting_pixels: int = VISIBLE_PIXELS // 2
    seed: int = 0


@dataclass(frozen=True)
class Observation:
    """The partial point cloud of one instance in one frame."""

    frame_index: int
    instance_id: int
    points_camera: np.ndarray  # (N, 3) float64, camera frame, metres
    n_pixels: int              # pixels of the instance's mask with valid depth in range
    touches_border: bool       # the mask reaches the image border: the object may be cut off


@dataclass(frozen=True)
class SkippedObservation:
    """An instance that was seen but not turned into an observation, and why."""

    frame_index: int
    instance_id: int
    n_pixels: int
    reason: str
    # a sighting (`ObservationConfig.sighting_pixels`): its cleaned points' centroid, camera frame
    center_camera: np.ndarray | None = None


def extract_observations(frame: Frame, config: ObservationConfig = ObservationConfig()
                         ) -> tuple[list[Observation], list[SkippedObservation]]:
    """Every instance of `frame.instances` as an `Observation`, or a `SkippedObservation` with the reason.

    A frame without an instance mask gives nothing: segmenting it is the caller's choice.
    """
    if frame.instances is None:
        return [], []
    ids = frame.instances
    height, width = ids.shape
    # One pass over the labelled pixels, grouped by id (a scan of the whole image per instance
    # was most of the perception time).
    labelled = np.flatnonzero(ids.ravel())
    labels = ids.ravel()[labelled]
    order = np.argsort(labels, kind="stable")
    labelled, labels = labelled[order], labels[order]
    depth = frame.depth.ravel()[labelled]
    in_range = depth_in_range(depth, config.min_depth_m, config.max_depth_m)
    on_border = set(np.unique(np.concatenate([ids[0], ids[-1], ids[:, 0], ids[:, -1]])).tolist())
    instance_ids, starts, counts = np.unique(labels, return_index=True, return_counts=True)

    observations, skipped = [], []
    for instance_id, start, count in zip(instance_ids.tolist(), starts, counts):
        pixels = labelled[start:start + count][in_range[start:start + count]]
        n_pixels = len(pixels)
        border = instance_id in on_border
        if n_pixels < config.min_pixels:
            reason = "no depth in range" if n_pixels == 0 else f"{n_pixels} pixels < min_pixels {config.min_pixels}"
            sighted = 0 < config.sighting_pixels <= n_pixels and not (border and config.skip_border)
            center = _sighting(frame, pixels, width, config) if sighted else None
            skipped.append(SkippedObservation(frame.index, instance_id, n_pixels, reason, center))
            continue
        if border and config.skip_border:
            skipped.append(SkippedObservation(frame.index, instance_id, n_pixels, "touches the image border"))
            continue
        if n_pixels > config.max_points:
            rng = np.random.default_rng([config.seed, frame.index, instance_id])
            pixels = pixels[np.sort(rng.choice(n_pixels, size=config.max_points, replace=False))]
        rows, cols = np.divmod(pixels, width)
        points = backproject(frame.K, rows, cols, frame.depth[rows, cols])
        cluster = largest_cluster(points, config.cluster_voxel_m)
        if len(cluster) < config.min_cluster_fraction * len(points):
            skipped.append(SkippedObservation(
                frame.index, instance_id, n_pixels,
                f"fragmented: largest cluster holds {len(cluster)} of {len(points)} points"))
            continue
        observations.append(Observation(frame.index, instance_id, points[cluster], n_pixels, border))
    return observations, skipped


def _sighting(frame: Frame, pixels: np.ndarray, width: int, config: ObservationConfig) -> np.ndarray | None:
    """The centroid (camera frame) of a small mask's points, cleaned as an observation's are; None
    when they fall apart (`min_cluster_fraction`)."""
    rows, cols = np.divmod(pixels, width)
    points = backproject(frame.K, rows, cols, frame.depth[rows, cols])
    cluster = largest_cluster(points, config.cluster_voxel_m)
    if len(cluster) < config.min_cluster_fraction * len(points):
        return None
    center: np.ndarray = points[cluster].mean(axis=0)
    return center


def largest_cluster(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Indices of the points of the largest 26-connected group of occupied voxels of size `voxel_m`.

    Points closer than `voxel_m` along every axis always fall in the same or neighbouring voxels,
    so this joins at least what single linkage at `voxel_m` joins (and some pairs up to
    2 sqrt(3) voxel_m apart). Linking points pairwise (a k-d tree's pairs within the radius) found
    the same clusters but cost ~7 ms per 1,000-point object; the voxels are ~50 per mug.
    """
    if len(points) < 2:
        return np.arange(len(points))
    keys = np.floor(points / voxel_m).astype(np.int64)
    keys -= keys.min(axis=0) - 1                 # >= 1, so that every neighbour's key is >= 0
    span = keys.max(axis=0) + 2

    def encode(k: np.ndarray) -> np.ndarray:
        code: np.ndarray = (k[..., 0] * span[1] + k[..., 1]) * span[2] + k[..., 2]
        return code

    cell_codes, cell_of_point = np.unique(encode(keys), return_inverse=True)
    cells = np.stack(np.unravel_index(cell_codes, tuple(span)), axis=1)
    # Half of the 26 neighbour offsets: the graph is undirected.
    offsets = np.array([o for o in np.ndindex(3, 3, 3) if o > (1, 1, 1)]) - 1
    neighbour_codes = encode(cells[:, None, :] + offsets[None])   # (cells, 13)
    position = np.minimum(np.searchsorted(cell_codes, neighbour_codes), len(cell_codes) - 1)
    found = cell_codes[position] == neighbour_codes
    first = np.broadcast_to(np.arange(len(cells))[:, None], found.shape)[found]
    cell_label = _component_labels(len(cells), first, position[found])
    point_label = cell_label[cell_of_point.ravel()]
    return np.flatnonzero(point_label == np.bincount(point_label).argmax())


def _component_labels(count: int, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Per node `count`, the smallest node index of its connected component, from edges
    (first[i], second[i]): labels spread along the edges, then jump to their label's label, until
    they hold. For the few hundred voxels of an object, an order of magnitude less time than a
    sparse graph's connected components (their construction and checks cost the most)."""
    label = np.arange(count)
    while True:
        spread = label.copy()
        np.minimum.at(spread, first, label[second])
        np.minimum.at(spread, second, label[first])
        spread = spread[spread]  # a label's label is no larger: follow it (pointer jumping)
        if np.array_equal(spread, label):
            return label
        label = spread
