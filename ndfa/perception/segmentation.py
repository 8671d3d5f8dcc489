"""Object instances without masks: support planes removed, the points above them clustered.

The paper's real-world pipeline segments objects by removing the support plane and clustering the
rest with DBSCAN; this is that, for one frame at a time:

1. Back-project every `stride`-th pixel (in both directions) with valid depth, into the world
   frame with the frame's pose (`pose_world_camera`; the world is z-up, `ndfa.core.conventions`).
2. Find the horizontal planes (`ndfa.perception.planes`): with the up direction known, a
   horizontal plane has one free parameter, its height, so the consensus search is exhaustive
   rather than random: the height window of `plane_distance_m` holding the most points wins, its inliers are refitted by least
   squares (which absorbs a tilt of the pose up to `plane_max_tilt_deg`), and the search repeats
   away from the accepted planes while a level holds enough points. Floor and table tops are
   both found, and a shelf's boards 15-35 cm apart; at the end all planes take the normal of the widest one. With `plane_search_every`
   above 1, a session's pass (`PlaneTracker`) refits the previous frame's planes instead, and
   searches the heights in full every so many frames or where a refitted plane fails the tests.
3. Candidates: points above a support plane by more than `min_height_m` and at most
   `band_height_m`, whose horizontal position lies over (or within `footprint_margin_m` of) that
   plane's own inliers (the nearest plane below a point that two planes' bands reach), and with no
   point higher than `max_object_height_m` within `column_radius_m` horizontally (that column is
   part of something taller: a wall, a table leg; not a board overhanging space seen empty).
   Rule for the floor: none is needed. Every horizontal plane supports objects; what stands on
   the floor (legs) or next to it (walls) reaches above an object's height and is dropped here or
   at step 5. So a frame that sees only a table top, or only the floor with objects on it, needs
   no special case, and the floor's height need not be known.
4. DBSCAN (`dbscan_eps_m`, `dbscan_min_points`) on the candidates' world coordinates, binned in
   voxels of `dbscan_voxel_m` (0: on the points themselves).
5. Clusters kept: enough points; a top between `min_object_height_m` (and a few sigmas of the
   depth noise: far table tops' noise piles up into blobs) and `max_object_height_m`; a bottom
   near the plane (`max_bottom_m`: objects stand on it); a horizontal extent between
   `min_extent_m` and `max_extent_m`; and not hidden above by a nearer surface (`_hidden_above`:
   the foot of a table leg seen under a nearer table top looks like a mug otherwise). Then the
   mug-likeness gate (`ndfa.perception.objectness`: a mug's height, footprint and build), and
   not cut by the border of the depth image (`image_margin_px`). Without these, a real table
   with magazines, a counter and chairs gave ~8 clusters per frame, nearly all clutter
   (docs/segmentation.md).
6. Painted back at full resolution: every pixel with valid depth within one sample block of a
   labelled sample joins the cluster of its nearest kept point in 3D if that point is closer than
   `fill_distance_m` and the pixel lies above the plane; others stay 0. The mask thus follows the
   object's silhouette at full resolution, not the sample grid's blocks.

On the `paper` scene (640x480, stride 2) this recovers 86% of the mug views with >= 200 pixels
of depth as one segment with IoU >= 0.5 (`segmentation_recall` in `segmentation_scoring`, `ndfa bench segment`); 94.7%
without the gate and the border test (the gate's clutter tests cost 3 points: docs/segmentation.md). The other misses are mostly mugs 3+ m away, where the depth
noise (~17 mm) is a fifth of a mug. Known limits:
mugs closer than `dbscan_eps_m` merge; the inside of a mug, cut off from its body by the sensor's
dropout at the rim, can become a segment of its own (small: the pipeline's `min_pixels` skips it).

The ids are labels 1..N within one frame, nothing more: the method never uses an instance id
except to group the pixels of one frame (`ndfa.eval.segmentation` scores them against ground truth).

Pure numpy/scipy; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree

from ndfa.core import conventions
from ndfa.core.frame import Frame
from ndfa.core.geometry import backproject, invert_pose, project, transform_points
from ndfa.perception.dbscan import dbscan, voxel_dbscan
from ndfa.perception.objectness import ClusterShape, cluster_shape, judge
from ndfa.perception.planes import Plane, find_horizontal_planes, plane_axes, track_horizontal_planes
from ndfa.perception.segmentation_config import SegmentationConfig
from ndfa.perception.split import split_in_two

# A point above an object's height overhangs when the depth passes this far beyond the spot this
# far under that height, straight below it (`_overhanging`): the board above a shelf's mugs (25-35
# cm up, the mugs 6-13 cm tall) with the room seen between them.
OVERHANG_PROBE_M, FREE_M = 0.05, 0.05


@dataclass(frozen=True)
class ClusterVerdict:
    """What became of one DBSCAN cluster (`explain_frame`): its shape, and `rejected`, the test it
    failed ("floating", "low", "high", "extent", the gate's reasons of
    `ndfa.perception.objectness.rejection`, "hidden", "cut") or None when kept. `label`: its label in the
    segmentation (0 when rejected). `split`: the cluster was split in two and this is one half."""

    shape: ClusterShape
    rejected: str | None
    label: int = 0
    split: bool = False
    outline: Outline | None = None


@dataclass(frozen=True)
class Outline:
    """What lies around a cluster that stands on a support (`_outline`, `_hanging`). In the image,
    just outside its silhouette, from its top edge (each column's topmost sample) and from its left
    and right sides (each row's outermost samples): of the outline samples whose look outwards
    found depth that is neither the support nor nearer (an occluder), the share where the surface
    goes on (within the gap of the outline's own depth) rather than falling away behind: `top`,
    `left`, `right` (None: fewer than `OUTLINE_MIN_SAMPLES` such samples). In the world, `hanging`:
    the share of its base points (the lowest `base_band_m`) with a point of the frame right below
    them, under the support's level (None: no base points). A standing object is seen free: behind
    its silhouette lies the room, farther, and under its base the support hides everything; a piece
    of something larger goes on past it: a chair's slanted leg above its foot (`top`), a strip of a
    wall or a cabinet's front on both sides (`left` and `right`), a chair's back at a table's edge
    or a table's rim below the support's level (`hanging`)."""

    top: float | None
    left: float | None
    right: float | None
    hanging: float | None

    def goes_on(self) -> float:
        """How far the cluster goes on into something larger: the largest of the top's share, the
        smaller side's (a wall's strip goes on at both, an object against a wall at one) and the
        hanging share; 0 where nothing was measured."""
        sides = None if self.left is None or self.right is None else min(self.left, self.right)
        return max(share for share in (self.top, sides, self.hanging, 0.0) if share is not None)


class PlaneTracker:
    """A session's support planes carried from frame to frame (its frames in order; one tracker
    per session, as its poses share one world frame): a full search of the heights every
    `search_every` frames and wherever a tracked plane fails, else the previous frame's planes
    refitted (`SegmentationConfig.plane_search_every`; docs/speed.md, seg31). `searches`: the
    frames searched in full, of `frames`."""

    def __init__(self, search_every: int) -> None:
        self.search_every = search_every
        self.previous: list[Plane] = []
        self.frames = 0
        self.searches = 0

    def planes(self, points: np.ndarray, up: np.ndarray, config: SegmentationConfig, camera: np.ndarray) -> list[Plane]:
        """The frame's planes (`find_horizontal_planes`' arguments)."""
        found = None
        if self.previous and self.frames % self.search_every:
            found = track_horizontal_planes(points, self.previous, up, config, camera)
        if found is None:
            self.searches += 1
            found = find_horizontal_planes(points, up, config, camera=camera)
        self.frames += 1
        self.previous = found
        return found


def segment_frame(frame: Frame, config: SegmentationConfig = SegmentationConfig(),
                  tracker: PlaneTracker | None = None) -> np.ndarray:
    """The frame's object instances as a (H, W) uint16 image: labels 1..N, 0 = no object.
    `tracker`: the session's `PlaneTracker` (None: the planes searched in full)."""
    return explain_frame(frame, config, tracker)[0]


def explain_frame(frame: Frame, config: SegmentationConfig = SegmentationConfig(), tracker: PlaneTracker | None = None
                  ) -> tuple[np.ndarray, list[ClusterVerdict]]:
    """`segment_frame`'s labels, and a verdict for every cluster of at least `min_cluster_points`
    (why the others were not kept: for studies such as studies/segmentation_study.py)."""
    verdicts: list[ClusterVerdict] = []
    height, width = frame.depth.shape
    labels = np.zeros((height, width), dtype=np.uint16)
    up = conventions.world_up()

    stride = config.stride or max(1, width // 320)
    rows, cols = np.mgrid[0:height:stride, 0:width:stride]
    rows, cols = rows.ravel(), cols.ravel()
    sampled = frame.depth[::stride, ::stride].ravel()
    keep = conventions.depth_in_range(sampled, config.min_depth_m, config.max_depth_m)
    rows, cols, depths = rows[keep], cols[keep], sampled[keep]
    if len(rows) < config.min_plane_points:
        return labels, verdicts
    points = _world_points(frame, rows, cols, depths)

    camera = frame.pose_world_camera[:3, 3]
    planes = (find_horizontal_planes(points, up, config, camera=camera) if tracker is None
              else tracker.planes(points, up, config, camera))
    if not planes:
        return labels, verdicts
    up = planes[0].normal  # the planes' common normal: it corrects a slightly tilted pose
    min_heights = _min_heights(depths, config)
    candidate, plane_of_point = _candidates(points, min_heights, planes, up, config, frame)
    if not candidate.any():
        return labels, verdicts
    cluster_points = points[candidate]
    cluster_planes = plane_of_point[candidate]
    cluster_of_point = (voxel_dbscan(cluster_points, config.dbscan_eps_m, config.dbscan_min_points, config.dbscan_voxel_m)
                        if config.dbscan_voxel_m > 0 else dbscan(cluster_points, config.dbscan_eps_m, config.dbscan_min_points))
    candidate_rows, candidate_cols = rows[candidate], cols[candidate]
    judged = _kept_clusters(cluster_points, depths[candidate], cluster_of_point,
                            cluster_planes, planes, up, frame.pose_world_camera[:3, 3], config)
    kept = []
    depth_box: tuple[int, int, int, int] | None = None  # `_depth_box`, found when first needed
    fragments: np.ndarray | None = None  # `_fragments`, found when first needed
    below: dict[int, cKDTree | None] = {}  # `_below` of each plane (by id), found when first needed
    for cluster, verdict in judged:
        members = cluster_of_point == cluster
        cluster_rows, cluster_cols = candidate_rows[members], candidate_cols[members]
        upper: np.ndarray | slice = slice(None)  # the samples whose top edge the hidden test looks above
        if verdict.rejected is None and config.occluder_upper_half:
            heights = planes[int(np.bincount(cluster_planes[members]).argmax())].height(cluster_points[members])
            upper = heights >= 0.5 * verdict.shape.top_m
        if verdict.rejected is None and _hidden_above(frame.depth, cluster_rows[upper], cluster_cols[upper], config):
            verdict = ClusterVerdict(verdict.shape, "hidden", split=verdict.split)
        if verdict.rejected is None and config.image_margin_px > 0:
            depth_box = _depth_box(frame.depth) if depth_box is None else depth_box
        if verdict.rejected is None and _cut_by_border(cluster_rows, cluster_cols, depth_box, config):
            verdict = ClusterVerdict(verdict.shape, "cut", split=verdict.split)
        outline = None
        if verdict.rejected is None and config.max_outline_goes_on is not None:
            plane = planes[int(np.bincount(cluster_planes[members]).argmax())]
            if fragments is None:
                fragments = _fragments(labels.shape, candidate_rows, candidate_cols, cluster_of_point, stride, config)
            if id(plane) not in below:
                below[id(plane)] = _below(points, depths, plane, config)
            outline = _outline(frame, cluster_rows, cluster_cols, plane, stride, fragments, config,
                               _hanging(below[id(plane)], cluster_points[members], plane, config))
            if outline.goes_on() > config.max_outline_goes_on:
                verdict = ClusterVerdict(verdict.shape, "attached", split=verdict.split, outline=outline)
        if verdict.rejected is None:
            kept.append(cluster)
            verdict = ClusterVerdict(verdict.shape, None, label=len(kept), split=verdict.split, outline=outline)
        verdicts.append(verdict)
    if not kept:
        return labels, verdicts

    # Sample points of kept clusters, relabelled 1..N in the order of `judged` (largest first, a
    # split cluster's halves together).
    label_of_point = np.zeros(len(cluster_points), dtype=np.uint16)
    for label, cluster in enumerate(kept, start=1):
        label_of_point[cluster_of_point == cluster] = label
    labelled = label_of_point > 0
    sample_rows = candidate_rows[labelled]
    sample_cols = candidate_cols[labelled]
    labels[sample_rows, sample_cols] = label_of_point[labelled]
    if stride > 1:
        _fill(frame, labels, cluster_points[labelled], label_of_point[labelled],
              planes, cluster_planes[labelled], stride, config)
    return labels, verdicts


def _min_heights(depth: np.ndarray, config: SegmentationConfig) -> np.ndarray:
    """How far above its plane a point at this depth must be to count as an object (step 3)."""
    if config.noise_sigmas == 0:  # the default: the depths (all in range, finite) do not matter
        return np.full(len(depth), config.min_height_m)
    sigma = _noise_sigma(depth, config)
    return np.maximum(config.min_height_m, config.noise_sigmas * sigma)


def _noise_sigma(depth: np.ndarray | float, config: SegmentationConfig) -> np.ndarray | float:
    return config.noise_base_m + config.noise_quadratic_per_m * np.asarray(depth, dtype=np.float64) ** 2


def _world_points(frame: Frame, rows: np.ndarray, cols: np.ndarray, depth: np.ndarray | None = None) -> np.ndarray:
    """The world points of pixels (rows, cols) whose depths are `depth` (None: read from the frame):
    `backproject`'s camera points moved by the pose, one output column at a time (a (N, 3) @ (3, 3)
    product went through threaded BLAS and took 30 ms on a busy 2-core machine)."""
    camera = backproject(frame.K, rows, cols, frame.depth[rows, cols] if depth is None else depth)
    x, y, z = camera[:, 0], camera[:, 1], camera[:, 2]
    pose = frame.pose_world_camera
    world = np.empty((len(camera), 3))
    for axis in range(3):
        rotation = pose[axis, :3]
        world[:, axis] = x * rotation[0] + y * rotation[1] + z * rotation[2] + pose[axis, 3]
    return world


def _candidates(points: np.ndarray, min_heights: np.ndarray, planes: list[Plane], up: np.ndarray,
                config: SegmentationConfig, frame: Frame | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Which points may belong to objects, and the index of the plane each stands on (step 3);
    `frame`: the points' frame, whose depth tells what overhangs (`_overhanging`; None: nothing)."""
    candidate = np.zeros(len(points), dtype=bool)
    plane_of_point = np.full(len(points), -1, dtype=np.int64)
    axes = plane_axes(up)
    margin = int(np.ceil(config.footprint_margin_m / config.footprint_cell_m))
    # The planes share their normal (`find_horizontal_planes`): one projection gives every height.
    along = points @ up if all(np.array_equal(p.normal, up) for p in planes) else None
    # The highest plane first: a point within the bands of two planes (a shelf's board and the
    # floor under it) stands on the nearer one below it, and the higher plane's own points on none.
    for index in sorted(range(len(planes)), key=lambda i: -planes[i].offset):
        plane = planes[index]
        h = plane.height(points) if along is None else along - plane.offset
        free = ~candidate
        for above in planes:
            if 0 < above.offset - plane.offset <= config.band_height_m:
                free &= ~above.inliers
        band = np.flatnonzero(free & (h >= min_heights) & (h <= config.band_height_m))
        if len(band) == 0:
            continue
        band_flat = points[band] @ axes.T
        over = _over_footprint(points[plane.inliers] @ axes.T, band_flat, config.footprint_cell_m, margin)
        overhangs = None if frame is None else _overhanging(frame, points[band], h[band], up, config)
        over[over] = ~_under_tall(band_flat[over], band_flat, h[band], config, overhangs)
        chosen = band[over]
        candidate[chosen] = True
        plane_of_point[chosen] = index
    return candidate, plane_of_point


def _over_footprint(marked_flat: np.ndarray, flat: np.ndarray, cell: float, margin: int) -> np.ndarray:
    """Which 2-D points (`flat`) lie in a grid cell (of side `cell`) within `margin` cells (a
    square) of a cell holding a point of `marked_flat`. Column by column: numpy's reductions and
    indexing along the short axis of a (N, 2) array cost several times more."""
    if len(marked_flat) == 0:
        return np.zeros(len(flat), dtype=bool)
    marked = [np.floor(marked_flat[:, axis] / cell).astype(np.int64) for axis in (0, 1)]
    low = [int(m.min()) - margin for m in marked]
    size = [int(m.max()) + margin + 1 - lo for m, lo in zip(marked, low)]
    occupied = np.zeros(size[0] * size[1], dtype=bool)
    occupied[(marked[0] - low[0]) * size[1] + (marked[1] - low[1])] = True
    near = maximum_filter(occupied.reshape(size), size=2 * margin + 1, mode="constant")
    cells = [np.floor(flat[:, axis] / cell).astype(np.int64) - lo for axis, lo in zip((0, 1), low)]
    inside = (cells[0] >= 0) & (cells[0] < size[0]) & (cells[1] >= 0) & (cells[1] < size[1])
    over = np.zeros(len(flat), dtype=bool)
    over[inside] = near[cells[0][inside], cells[1][inside]]
    return over


def _under_tall(flat: np.ndarray, band_flat: np.ndarray, band_heights: np.ndarray, config: SegmentationConfig,
                overhangs: np.ndarray | None = None) -> np.ndarray:
    """Which points (horizontal coordinates `flat`) stand in a column that reaches above an
    object's height: a point of the band (`band_flat`, `band_heights`) higher than
    `max_object_height_m` lies within `column_radius_m` of them horizontally. Such columns hold
    parts of taller things (walls, cabinet fronts, legs), dropped before clustering, which they
    would otherwise dominate. A radius, not grid cells: whether a wall's foot shared a cell with
    the wall above it depended on where the cell edges fell, which a tenth of a degree of levelling
    moves by a centimetre a few metres out (docs/segmentation.md, "Columns"). `overhangs`: which
    band points overhang space the camera saw empty (`_overhanging`), no column."""
    tall = band_heights > config.max_object_height_m
    if overhangs is not None:
        tall &= ~overhangs
    return _within(band_flat[tall], flat, config.column_radius_m)


def _overhanging(frame: Frame, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                 config: SegmentationConfig) -> np.ndarray:
    """Which points (world, `heights` above their plane) higher than `max_object_height_m` have
    space under them that the frame saw through: at `OVERHANG_PROBE_M` under an object's height
    straight below each, the depth reaches `FREE_M` past that spot. The board above a shelf's mugs
    is such; a wall's upper part is not (what is under it is more wall, or hidden behind a nearer
    thing: a chair in front of a cabinet's foot), and neither is what the frame cannot tell."""
    free = np.zeros(len(points), dtype=bool)
    tall = np.flatnonzero(heights > config.max_object_height_m)
    if not len(tall):
        return free
    probes = points[tall] - np.outer(heights[tall] - (config.max_object_height_m - OVERHANG_PROBE_M), up)
    camera = transform_points(invert_pose(frame.pose_world_camera), probes)
    z = camera[:, 2]
    pixels = np.rint(project(frame.K, camera))
    height, width = frame.depth.shape
    inside = (z > 1e-6) & (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
    measured = np.zeros(len(tall))
    measured[inside] = frame.depth[pixels[inside, 1].astype(np.int64), pixels[inside, 0].astype(np.int64)]
    free[tall] = np.isfinite(measured) & (measured > z + FREE_M)
    return free


def _within(marked_flat: np.ndarray, flat: np.ndarray, radius: float) -> np.ndarray:
    """Which 2-D points (`flat`) lie within `radius` of a point of `marked_flat`. Exact, with fewer
    searches: a point sharing a cell of side radius / 1.5 with a marked point lies within 0.95 radius
    of it; a marked point within the radius lies in the point's cell of side radius or a
    neighbouring one, so only the points there are searched."""
    if len(marked_flat) == 0 or len(flat) == 0:
        return np.zeros(len(flat), dtype=bool)
    within = _over_footprint(marked_flat, flat, radius / 1.5, 0)
    near = np.flatnonzero(~within & _over_footprint(marked_flat, flat, radius, 1))
    if len(near):
        distance, _ = cKDTree(marked_flat).query(flat[near], distance_upper_bound=radius)
        within[near] = np.isfinite(distance)
    return within


def _kept_clusters(points: np.ndarray, depths: np.ndarray, cluster_of_point: np.ndarray, plane_of_point: np.ndarray,
                   planes: list[Plane], up: np.ndarray, camera: np.ndarray, config: SegmentationConfig
                   ) -> list[tuple[int, ClusterVerdict]]:
    """Step 5: every cluster of `min_cluster_points` with its verdict (kept: `rejected` is None),
    largest first. A cluster's top is its 95th percentile of height (one noisy point does not make
    a blob tall). A cluster split in two (`split_max_length_m`) is renumbered in `cluster_of_point`,
    in place: its second half takes a new cluster index."""
    clusters, sizes = np.unique(cluster_of_point[cluster_of_point >= 0], return_counts=True)
    axes = plane_axes(up)
    camera_flat = camera @ axes.T
    next_cluster = int(clusters.max()) + 1 if len(clusters) else 0
    judged = []
    for cluster, size in sorted(zip(clusters.tolist(), sizes.tolist()), key=lambda c: -c[1]):
        if size < config.min_cluster_points:
            continue
        members = np.flatnonzero(cluster_of_point == cluster)
        plane = planes[np.bincount(plane_of_point[members]).argmax()]
        heights = plane.height(points[members])
        flat = points[members] @ axes.T
        shape = cluster_shape(heights, flat, depths[members])
        reason = _size_rejection(shape, flat, config)
        if reason is None and config.objectness is not None:
            shape, reason = judge(heights, flat, depths[members], config.objectness, camera_flat, shape)
            if reason == "long" and shape.length_m <= config.split_max_length_m:
                halves = _split(heights, flat, depths[members], camera_flat, config)
                if halves is not None:
                    second, shapes = halves
                    cluster_of_point[members[second]] = next_cluster
                    judged += [(cluster, ClusterVerdict(shapes[0], None, split=True)),
                               (next_cluster, ClusterVerdict(shapes[1], None, split=True))]
                    next_cluster += 1
                    continue
        judged.append((cluster, ClusterVerdict(shape, reason)))
    return judged


def _size_rejection(shape: ClusterShape, flat: np.ndarray, config: SegmentationConfig) -> str | None:
    """The coarse size tests of step 5 (before the objectness gate): why the cluster fails, or None."""
    sigma = _noise_sigma(shape.depth_m, config)
    if shape.bottom_m > max(config.max_bottom_m, 3 * sigma):
        return "floating"  # floats above the plane: the lower part of something taller, hidden
    if shape.top_m < max(config.min_object_height_m, config.top_noise_sigmas * sigma):
        return "low"
    if shape.top_m > config.max_object_height_m:
        return "high"
    extent = float(np.linalg.norm(flat.max(axis=0) - flat.min(axis=0)))
    if not config.min_extent_m <= extent <= config.max_extent_m:
        return "extent"
    return None


def _split(heights: np.ndarray, flat: np.ndarray, depths: np.ndarray, camera_flat: np.ndarray,
           config: SegmentationConfig) -> tuple[np.ndarray, tuple[ClusterShape, ClusterShape]] | None:
    """Two touching mugs: the cluster's 2-means halves (second-half mask and both shapes) if both
    have `min_cluster_points` and pass the objectness gate, else None."""
    second = split_in_two(flat)
    if min(second.sum(), (~second).sum()) < config.min_cluster_points:
        return None
    first = ~second
    (shape_first, reason_first), (shape_second, reason_second) = (
        judge(heights[half], flat[half], depths[half], config.objectness, camera_flat) for half in (first, second))
    if reason_first is not None or reason_second is not None:
        return None
    return second, (shape_first, shape_second)


def _hidden_above(depth: np.ndarray, rows: np.ndarray, cols: np.ndarray, config: SegmentationConfig) -> bool:
    """Whether most of the cluster's top edge in the image lies right below a closer surface: then
    what looks like a short object may be the visible foot of a taller one (a table leg below a
    nearer table top). Above a real mug on a table there is background, farther away."""
    order = np.lexsort((rows, cols))                     # by column, then row: each column's top first
    columns, first = np.unique(cols[order], return_index=True)
    tops = rows[order][first]
    own = depth[tops, columns]
    # The nearest of the first few valid depths up the column, past a band without depth: all the
    # steps up at once (step, column).
    steps = np.arange(1, config.occluder_look_px + config.occluder_band_px + 1)
    row = tops[None, :] - steps[:, None]
    values = np.where(row >= 0, depth[np.maximum(row, 0), columns[None, :]], 0.0)
    valid = values > 0
    looked: np.ndarray = np.cumsum(valid, axis=0) - valid  # valid pixels looked at before this step, per column
    counted = valid & (looked < config.occluder_look_px)
    above = np.where(counted, values, np.inf).min(axis=0, initial=np.inf)
    hidden = above < own - config.occluder_gap_m
    return bool(hidden.mean() > 0.5)


OUTLINE_MIN_SAMPLES = 3


def _fragments(shape: tuple[int, int], rows: np.ndarray, cols: np.ndarray, cluster_of_point: np.ndarray,
               stride: int, config: SegmentationConfig) -> np.ndarray:
    """On the sample grid of `stride` (of an image of `shape`), the candidates (`rows`, `cols`,
    their DBSCAN clusters) that DBSCAN left as noise or in a cluster under `min_cluster_points`:
    fringes (an object's rim, its mixed pixels), not surfaces of their own."""
    clusters, sizes = np.unique(cluster_of_point, return_counts=True)
    small = clusters[(clusters < 0) | (sizes < config.min_cluster_points)]
    grid = np.zeros((-(-shape[0] // stride), -(-shape[1] // stride)), dtype=bool)
    fragment = np.isin(cluster_of_point, small)
    grid[rows[fragment] // stride, cols[fragment] // stride] = True
    return grid


def _outline(frame: Frame, rows: np.ndarray, cols: np.ndarray, plane: Plane, stride: int, fragments: np.ndarray,
             config: SegmentationConfig, hanging: float | None) -> Outline:
    """`Outline` of a cluster's samples (`rows`, `cols`: full-resolution pixels on the sample grid of
    `stride`) standing on `plane` (its `hanging` share given). From each outline sample, the next
    `outline_look_samples` samples outwards (up from the top edge, left and right from the sides) not
    in the cluster are looked at; those with depth in range and not `fragments` (`_fragments`) are
    back-projected. Support: any of them
    within the support's tolerance of the plane (max(`min_height_m`, 3 sigma of the depth noise)):
    the table beside a base, nothing to say. Else the farthest of them: nearer than the outline's
    depth by more than the gap (max(`outline_gap_m`, 3 sigma)) is an occluder (nothing to say),
    within the gap the surface goes on, beyond it the room lies behind (free)."""
    grid = frame.depth[::stride, ::stride]
    height, width = grid.shape
    r, c = rows // stride, cols // stride
    inside = np.zeros(grid.shape, dtype=bool)
    inside[r, c] = True
    order = np.lexsort((r, c))  # by column, then row
    columns, first = np.unique(c[order], return_index=True)
    top = (r[order][first], columns)
    order = np.lexsort((c, r))  # by row, then column
    row_values, first, counts = np.unique(r[order], return_index=True, return_counts=True)
    left, right = (row_values, c[order][first]), (row_values, c[order][first + counts - 1])
    steps = np.arange(1, config.outline_look_samples + 1)[:, None]
    shares = []
    for (edge_rows, edge_cols), (d_row, d_col) in ((top, (-1, 0)), (left, (0, -1)), (right, (0, 1))):
        own = grid[edge_rows, edge_cols]
        look_rows, look_cols = edge_rows[None, :] + d_row * steps, edge_cols[None, :] + d_col * steps
        on_grid = (look_rows >= 0) & (look_rows < height) & (look_cols >= 0) & (look_cols < width)
        look_rows, look_cols = np.where(on_grid, look_rows, 0), np.where(on_grid, look_cols, 0)
        depth = np.where(on_grid & ~inside[look_rows, look_cols], grid[look_rows, look_cols], 0.0)
        valid = conventions.depth_in_range(depth, config.min_depth_m, config.max_depth_m)
        valid &= ~fragments[look_rows, look_cols]
        sigma = _noise_sigma(own, config)
        tolerance = np.broadcast_to(np.maximum(config.min_height_m, 3 * sigma), depth.shape)
        world = _world_points(frame, look_rows[valid] * stride, look_cols[valid] * stride, depth[valid])
        on_support = np.zeros(depth.shape, dtype=bool)
        on_support[valid] = np.abs(plane.height(world)) < tolerance[valid]
        farthest = np.where(valid, depth, -np.inf).max(axis=0)
        counted = valid.any(axis=0) & ~on_support.any(axis=0)
        gap = np.maximum(config.outline_gap_m, 3 * sigma)
        goes_on = int((counted & (np.abs(farthest - own) <= gap)).sum())
        total = goes_on + int((counted & (farthest > own + gap)).sum())
        shares.append(goes_on / total if total >= OUTLINE_MIN_SAMPLES else None)
    return Outline(top=shares[0], left=shares[1], right=shares[2], hanging=hanging)


def _below(points: np.ndarray, depths: np.ndarray, plane: Plane, config: SegmentationConfig) -> cKDTree | None:
    """The horizontal positions (in `plane_axes`) of the frame's points (`points`, at `depths` from the
    camera) right under `plane`: below it by at least max(`hanging_min_m`, 3 sigma of their depth
    noise) and at most `hanging_depth_m`, as a tree; None when there are none."""
    height = plane.height(points)
    under = (height <= -np.maximum(config.hanging_min_m, 3 * _noise_sigma(depths, config))) & (height >= -config.hanging_depth_m)
    if not under.any():
        return None
    return cKDTree(points[under] @ plane_axes(plane.normal).T)


def _hanging(below: cKDTree | None, members: np.ndarray, plane: Plane, config: SegmentationConfig) -> float | None:
    """The share of a cluster's base points (`members`' within `base_band_m` of `plane`) within
    `hanging_radius_m` horizontally of a point right under the plane (`below`, `_below`): what goes
    on under the support's level. Under an object standing on a table the table's own top hides the
    first centimetres; under a chair's back beside it, the back goes on down."""
    base = members[plane.height(members) <= config.base_band_m]
    if len(base) == 0:
        return None
    if below is None:
        return 0.0
    distance, _ = below.query(base @ plane_axes(plane.normal).T, distance_upper_bound=config.hanging_radius_m)
    return float(np.isfinite(distance).mean())


def _depth_box(depth: np.ndarray) -> tuple[int, int, int, int]:
    """The first and last rows and columns holding any pixel with depth."""
    valid = depth > 0
    valid_rows, valid_cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    return int(valid_rows[0]), int(valid_rows[-1]), int(valid_cols[0]), int(valid_cols[-1])


def _cut_by_border(rows: np.ndarray, cols: np.ndarray, depth_box: tuple[int, int, int, int] | None,
                   config: SegmentationConfig) -> bool:
    """Whether the cluster reaches within `image_margin_px` of the border of the pixels with depth
    (`depth_box`: the bounding box of the rows and columns holding any)."""
    margin = config.image_margin_px
    if margin <= 0 or depth_box is None:
        return False
    first_row, last_row, first_col, last_col = depth_box
    return bool(rows.min() < first_row + margin or rows.max() > last_row - margin
                or cols.min() < first_col + margin or cols.max() > last_col - margin)


def _fill(frame: Frame, labels: np.ndarray, points: np.ndarray, point_labels: np.ndarray,
          planes: list[Plane], plane_of_point: np.ndarray, s: int, config: SegmentationConfig) -> None:
    """Step 6: label the full-resolution pixels near the labelled samples (every `s`-th), in place."""
    height, width = labels.shape
    sampled = labels[::s, ::s] > 0
    near = sampled.copy()  # the sample blocks next to a labelled sample, in both directions
    near[1:] |= sampled[:-1]
    near[:-1] |= sampled[1:]
    near[:, 1:] |= near[:, :-1].copy()
    near[:, :-1] |= near[:, 1:].copy()
    block_rows, block_cols = np.nonzero(near)
    # Each sample (r, c) stands for the pixels r - s//2 .. r + s - 1 - s//2 (its nearest-sample block).
    d_rows, d_cols = np.mgrid[0:s, 0:s] - s // 2
    rows = (block_rows[:, None] * s + d_rows.ravel()[None]).ravel()
    cols = (block_cols[:, None] * s + d_cols.ravel()[None]).ravel()
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    rows, cols = rows[inside], cols[inside]
    unlabelled = labels[rows, cols] == 0
    rows, cols = rows[unlabelled], cols[unlabelled]
    depth = frame.depth[rows, cols]
    valid = conventions.depth_in_range(depth, config.min_depth_m, config.max_depth_m)
    rows, cols, depth = rows[valid], cols[valid], depth[valid]
    if len(rows) == 0:
        return
    pixel_points = _world_points(frame, rows, cols, depth)
    distance, nearest = cKDTree(points).query(pixel_points, distance_upper_bound=config.fill_distance_m)
    close = np.isfinite(distance)
    nearest = nearest[close]
    plane = plane_of_point[nearest]
    normals = np.stack([p.normal for p in planes])[plane]
    offsets = np.array([p.offset for p in planes])[plane]
    min_heights = _min_heights(depth[close], config)
    above = np.einsum("ij,ij->i", pixel_points[close], normals) - offsets >= min_heights
    labels[rows[close][above], cols[close][above]] = point_labels[nearest[above]]
