"""Whether a session's estimated poses make its depth images agree: the evidence of pose error that
needs no ground truth.

Two frames that see the same surface must put it at the same place. Carry the points of frame i
into frame j's camera with the estimated poses and compare their depth with the depth j measured
along the same rays:

- **consistent**: within `tau` of j's depth; the mean |difference| is the pair's residual, which
  grows with any error of the relative pose normal to the surfaces (a wall seen twice, doubled);
- **free-space violation**: nearer than j's depth by more than `tau` at every pixel around it: j
  looked straight through the place where i saw a surface. In one static session that cannot
  happen with right poses; with drift it does wholesale (a wall of the first pass standing in the
  open room of the second);
- farther than j's depth: hidden behind what j saw (an occlusion), says nothing.

Pairs: **revisits** (frames far apart along the path whose cameras look at the same place in the
estimate: what drift separates) and **neighbours** (frames a short way apart: the noise and the
local registration, the floor under the revisits' residual). Depth is kept per frame as a small
sketch (`DepthSketch`, at most `SKETCH_WIDTH` pixels wide), so a session of 500 frames holds a few
tens of MB and a pair costs about a millisecond.

Pure: depth and poses in, numbers out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ndfa.core.conventions import depth_in_range
from ndfa.core.frame import Frame
from ndfa.core.geometry import backproject

SKETCH_WIDTH = 160


@dataclass(frozen=True)
class ConsistencyConfig:
    """Pair selection and thresholds (docs/pose_quality.md).

    tau_m: depth differences up to this are the same surface (the sensor's noise at 4 m and a few
        centimetres of pose error); beyond, nearer is a free-space violation.
    revisit_travel_m: a revisit pair's frames are at least this far apart along the estimated path.
    revisit_radius_m, revisit_angle_deg: and their view centres (the point each camera looks at, at
        its median depth) are within this distance, their optical axes within this angle.
    neighbour_travel_m: a neighbour pair's frames are this far apart along the path (the first frame
        after at least this much travel).
    max_pairs: at most this many pairs of each kind are checked, spread evenly over the candidates.
    min_overlap: a pair counts when at least this fraction of i's points lands on j's valid depth.
        (consecutive frames below it are "unlinked" in `ndfa.trajectory.quality`).
    shared_share: a pair's shared conflict (`PairCheck.shared_conflict_m`) is the depth at least this
        share of its overlap reaches into the space the other frame saw empty. A wrong relative pose
        moves every surface: a translation towards them all of the overlap, a turn about a line
        through the view half of it (the other half moves away, hidden); one surface that disagrees
        alone (a screen's reflection, a moved object) is a small part (docs/pose_quality.md).
    """

    tau_m: float = 0.10
    revisit_travel_m: float = 1.0
    revisit_radius_m: float = 0.75
    revisit_angle_deg: float = 30.0
    neighbour_travel_m: float = 0.2
    max_pairs: int = 200
    min_overlap: float = 0.2
    shared_share: float = 0.25


@dataclass(frozen=True)
class DepthSketch:
    """A frame's depth subsampled to at most SKETCH_WIDTH pixels wide (NaN where out of range), its
    intrinsics at that size, its valid points in the camera frame, and per pixel the nearest valid
    depth of the 3x3 pixels around it (inf where none): what `check_pair` compares with, made once
    per frame instead of once per pair."""

    depth: np.ndarray  # (rows, cols) float32 metres, NaN invalid
    K: np.ndarray  # (3, 3)
    points: np.ndarray  # (M, 3) float32, camera frame
    nearest: np.ndarray  # (rows, cols) float32 metres, inf where no valid depth around

    @property
    def median_depth_m(self) -> float:
        return float(np.median(self.points[:, 2])) if len(self.points) else 1.0


def sketch_depth(frame: Frame) -> DepthSketch:
    """The frame's `DepthSketch` (nearest samples, not block means: a mean across a silhouette is a
    surface neither frame saw)."""
    step = max(1, math.ceil(frame.depth.shape[1] / SKETCH_WIDTH))
    K = frame.K.astype(np.float64).copy()
    K[:2] /= step
    return make_sketch(frame.depth[::step, ::step], K)


def make_sketch(depth: np.ndarray, K: np.ndarray) -> DepthSketch:
    """The `DepthSketch` of a depth image already at sketch size, with its intrinsics."""
    depth = np.where(depth_in_range(depth), depth, np.nan).astype(np.float32)
    rows, cols = np.nonzero(np.isfinite(depth))
    z = depth[rows, cols]
    points = backproject(K, rows, cols, z).astype(np.float32)
    return DepthSketch(depth=depth, K=K, points=points, nearest=_nearest_around(depth))


def _nearest_around(depth: np.ndarray) -> np.ndarray:
    """The smallest valid depth of each pixel's 3x3 neighbourhood (inf where none; the border
    pixels, which `check_pair` never reads, as if outside were invalid)."""
    import cv2

    valid = np.where(np.isfinite(depth), depth, np.inf).astype(np.float32)
    return cv2.erode(valid, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)


@dataclass(frozen=True)
class PairCheck:
    """One ordered pair's agreement: i's points seen from j.

    overlap: i's points landing on j's valid depth. violating: of them, those nearer than j's depth
    by more than tau at every pixel around (free-space violations). conflict_m: the 95th percentile
    over the overlap of how far a point stands in front of j's depth (0 where it is not): how deep
    i's surfaces reach into the space j saw empty, a few millimetres of noise with right poses.
    shared_conflict_m: the same at the share `ConsistencyConfig.shared_share` of the overlap (the
    75th percentile): how deep the bulk of i's surfaces reach, not one surface of them.
    """

    i: int
    j: int
    overlap: int
    violating: int
    conflict_m: float
    shared_conflict_m: float = 0.0


def check_pair(sketch_i: DepthSketch, sketch_j: DepthSketch, j_from_i: np.ndarray, tau_m: float,
               shared_share: float = ConsistencyConfig.shared_share) -> PairCheck | None:
    """i's points in j's camera (`j_from_i` = T_j_i, (4, 4)) against j's depth; None when none land."""
    points = sketch_i.points @ j_from_i[:3, :3].T.astype(np.float32) + j_from_i[:3, 3].astype(np.float32)
    z = points[:, 2]
    K = sketch_j.K
    height, width = sketch_j.depth.shape
    # Every point projected, then one selection: those ahead of the camera (the others' pixels are
    # never read) and inside the image.
    with np.errstate(divide="ignore", invalid="ignore"):
        cols = np.rint(K[0, 0] * points[:, 0] / z + K[0, 2])
        rows = np.rint(K[1, 1] * points[:, 1] / z + K[1, 2])
    keep = (z > 0.05) & (cols >= 1) & (cols < width - 1) & (rows >= 1) & (rows < height - 1)
    cols, rows, z = cols[keep].astype(np.int64), rows[keep].astype(np.int64), z[keep]
    valid = np.isfinite(sketch_j.depth[rows, cols])
    if not valid.any():
        return None
    cols, rows, z = cols[valid], rows[valid], z[valid]
    # The nearest of the 3x3 pixels around: a point by a silhouette may land one pixel off it.
    in_front = np.maximum(sketch_j.nearest[rows, cols] - z, 0.0)
    conflict, shared = np.quantile(in_front, [0.95, 1.0 - shared_share])
    return PairCheck(0, 0, overlap=int(len(z)), violating=int((in_front > tau_m).sum()),
                     conflict_m=float(conflict), shared_conflict_m=float(shared))


def revisit_pairs(poses: np.ndarray, median_depths: np.ndarray, config: ConsistencyConfig) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, far apart along the path and looking at the same place (see the module
    docstring); at most `max_pairs`, spread evenly."""
    positions, axes = poses[:, :3, 3], poses[:, :3, 2]
    centres = positions + median_depths[:, None] * axes
    travelled = _travelled(positions)
    far = (travelled[None, :] - travelled[:, None]) >= config.revisit_travel_m
    near = np.linalg.norm(centres[:, None] - centres[None, :], axis=-1) <= config.revisit_radius_m
    aligned = axes @ axes.T >= math.cos(math.radians(config.revisit_angle_deg))
    first, second = np.nonzero(np.triu(far & near & aligned, k=1))
    return _spread(list(zip(first.tolist(), second.tolist(), strict=True)), config.max_pairs)


def neighbour_pairs(poses: np.ndarray, config: ConsistencyConfig) -> list[tuple[int, int]]:
    """Pairs (i, j): j the first frame at least `neighbour_travel_m` along the path after i."""
    travelled = _travelled(poses[:, :3, 3])
    ends = np.searchsorted(travelled, travelled + config.neighbour_travel_m, side="left")
    pairs = [(i, int(j)) for i, j in enumerate(ends) if j < len(poses)]
    return _spread(pairs, config.max_pairs)


def step_pairs(count: int) -> list[tuple[int, int]]:
    """Every pair of consecutive frames: a jump of the estimate between two frames shows there."""
    return [(k, k + 1) for k in range(count - 1)]


def check_pairs(sketches: list[DepthSketch], poses: np.ndarray, pairs: list[tuple[int, int]],
                config: ConsistencyConfig) -> list[PairCheck]:
    """Each pair checked both ways (i seen from j, j seen from i); those that overlap enough."""
    checks = []
    inverse = np.linalg.inv(poses)
    for i, j in pairs:
        for a, b in ((i, j), (j, i)):
            check = check_pair(sketches[a], sketches[b], inverse[b] @ poses[a], config.tau_m, config.shared_share)
            if check is not None and check.overlap >= config.min_overlap * max(1, len(sketches[a].points)):
                checks.append(replace(check, i=a, j=b))
    return checks


def _travelled(positions: np.ndarray) -> np.ndarray:
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _spread(pairs: list[tuple[int, int]], limit: int) -> list[tuple[int, int]]:
    if len(pairs) <= limit:
        return pairs
    return [pairs[k] for k in np.linspace(0, len(pairs) - 1, limit).round().astype(int)]
