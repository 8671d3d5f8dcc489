"""Is a cluster above a support plane a mug (or, `ObjectnessConfig.objects`, a rigid object of any
category)? Its shape measured in the plane's frame, and a gate.

The clusters of `ndfa.perception.segmentation` are whatever sticks out of a horizontal plane:
on a real table that is mostly not mugs (magazines and papers lying flat, the edge of a counter
or a shelf seen at the right height, chair backs, slats), and every one that passes becomes an
object the detector tracks and may report. The gate keeps clusters of a mug's scale and build:

- tall enough and not too tall (`min_top_m`..`max_top_m`): a magazine is flat, a chair back tall;
- standing on the plane (`max_bottom_m`): its lowest points touch the support;
- a mug's footprint (`min_length_m`..`max_length_m`, `min_width_m`): a counter edge or a row of
  brochures is long, a bottle or a tap narrow; a single view of a mug sees about half of it,
  which is still a few cm deep;
- not a column (`max_aspect`): a mug is at most about twice as tall as it is wide;
- not squat (`min_aspect`): a mug is at least about two thirds as tall as its footprint is long;
  a bowl, a stack of books or a low box is flatter;
- compact (`min_width_ratio`): not a sliver (the edge of a board seen end-on);
- standing on its lower half (`min_lower_ratio`, objects only): not a wide top on a thin post
  (a monitor's housing);
- no faces at right angles (`max_right_angles`, views closer than `right_angle_max_depth_m`):
  a box or a book seen from the side shows flat faces at right angles to each other, so the
  horizontal directions of its surface normals cluster at multiples of 90 degrees; a mug's wall
  is round and its normals turn through half a circle in one view;
- not flared (`max_lean`): the wall facing the camera of a bowl leans towards it, its rim
  several cm nearer than its foot; a mug's wall stands nearly upright (`lean`).

The last two are measured only on views nearer than `near_view_depth_m`, where the depth noise
leaves normals and a wall's slope meaningful, and only on clusters that pass the other tests.

The footprint is measured along the principal axes of the cluster's horizontal positions, as a
percentile range (`FOOTPRINT_PERCENTILES`) so that a few stray points do not stretch it. Figures
from which the defaults were chosen are in docs/segmentation.md. Pure numpy; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

FOOTPRINT_PERCENTILES = (2.0, 98.0)
# A cluster's lower part (`ClusterShape.lower_length_m`): its points up to this share of its top.
LOWER_SHARE = 0.5


@dataclass(frozen=True)
class ObjectnessConfig:
    """Which clusters count as objects (mugs). Lengths in metres; heights above the support plane.

    The synthetic mugs are 6-13 cm tall and 7-12 cm across with the handle
    (`ndfa.sim.mug_params`); the real ones in 7-Scenes redkitchen ~9-10 cm tall and 8-11 cm across.

    min_top_m, max_top_m: the cluster's top (95th percentile of height) must lie in this range:
        below, a flat thing (magazines, a controller, a table's noise); above, a tall one
        (chair backs, bottles, a wall's foot, a tall box). The synthetic mug views reach 12.7 cm
        (13 cm mugs), tall boxes 13.4-14.1 cm.
    max_bottom_m: its bottom (5th percentile of height) must be at most this: a mug stands on
        the plane, so its lowest sampled points lie within the first centimetres above it
        (the candidates start at `SegmentationConfig.min_height_m`).
    min_length_m, max_length_m: the footprint's longer side (see `FOOTPRINT_PERCENTILES`) lies in
        this range: a mug's diameter at least, and at most a mug with its handle plus depth noise;
        counter edges, rows of brochures and a game controller are longer, taps and bottles
        narrower.
    min_width_m: the footprint's shorter side at least this: one view sees the front half of a
        mug's body, a few cm deep; the edge of a board or a chair's slat is a sliver.
    min_width_ratio: shorter over longer side at least this (compact, not a strip).
    max_aspect: top over the longer side at most this (the `paper` scene's mug views reach 2.1).
    min_aspect: top over the longer side at least this: the synthetic mugs are at least ~0.67 as
        tall as they are wide, their views with the handle 0.66 at the 2nd percentile; bowls
        (4-7 cm tall, 12-18 cm wide), books and low boxes lie below (docs/segmentation.md).
    min_lower_ratio: the footprint of the cluster's lower half (its points up to `LOWER_SHARE` of
        its top: `ClusterShape.lower_length_m`) at least this share of the whole footprint's longer
        side ("top-heavy" below; not tested where the lower half holds fewer than 3 points, as a
        bowl's rim seen alone): a standing object's lower half spans most of it, while a monitor's
        housing on its post or a shade on a stem is a wide top on a thin support. 0 (mugs): off.
    near_view_depth_m: the two tests below apply to clusters whose median depth is at most this;
        farther, the depth noise (~7 mm at 2 m) makes a mug score like a box or a bowl. 0: off.
    max_right_angles, normal_neighbours: "boxy" when `right_angles` (0..1, normals from
        `normal_neighbours` nearest points) exceeds this: near views of boxes and books score
        0.6-0.9 (median 0.76), of mugs 0.1-0.3 (3% above 0.5).
    max_lean: "flared" when `lean` (how far the wall facing the camera leans towards it, metres
        per metre of height) exceeds this: the bowl views that passed every other test lean
        0.26-0.75, mug views 0.19 at the 98th percentile.
    """

    min_top_m: float = 0.05
    max_top_m: float = 0.135
    max_bottom_m: float = 0.05
    min_length_m: float = 0.045
    max_length_m: float = 0.13
    min_width_m: float = 0.02
    min_width_ratio: float = 0.2
    max_aspect: float = 2.2
    min_aspect: float = 0.62
    min_lower_ratio: float = 0.0
    near_view_depth_m: float = 2.0
    max_right_angles: float = 0.5
    normal_neighbours: int = 24
    max_lean: float = 0.25

    @classmethod
    def objects(cls) -> ObjectnessConfig:
        """The gate for a rigid object of any category standing on its support (mugs, bowls, cups,
        bottles, cans, boxes: `ndfa.sim.categories.SIZE_RANGES`), not for a mug: 2.5-36 cm tall, a
        footprint 3.5-32 cm long, as tall as 7.5 times its footprint (a bottle seen from the side)
        and as flat as 0.08 times it (a wide bowl, a flat box); `boxy` and `flared` off (boxes and
        bowls are objects now). What still turns non-objects away: papers and cables lie flat
        (`flat`: under 2.5 cm), counter edges and table rims are long or slivers, a wall's foot is
        a column of the segmentation's `max_object_height_m`, something hidden floats, a monitor's
        housing on its post is top-heavy (docs/categories.md, "The office with v3").
        docs/segmentation.md, "Objects, not mugs", has the figures."""
        return cls(min_top_m=0.025, max_top_m=0.36, max_bottom_m=0.05, min_length_m=0.035, max_length_m=0.32,
                   min_width_m=0.015, min_width_ratio=0.15, max_aspect=7.5, min_aspect=0.08, min_lower_ratio=0.25,
                   near_view_depth_m=0.0)

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_top_m < self.max_top_m:
            raise ValueError("need 0 <= min_top_m < max_top_m")
        if not 0.0 <= self.min_width_m < self.max_length_m:
            raise ValueError("need 0 <= min_width_m < max_length_m")
        if not self.min_length_m < self.max_length_m:
            raise ValueError("need min_length_m < max_length_m")


@dataclass(frozen=True)
class ClusterShape:
    """A cluster's shape relative to its support plane (metres).

    points: sampled points in the cluster. bottom_m, top_m: 5th and 95th percentile of height
    above the plane. length_m >= width_m: the footprint's extents along its principal axes.
    depth_m: median depth from the camera (how noisy the figures are).
    right_angles: how much the surface normals' horizontal directions agree with one set of
    right angles (`right_angles`); lean: how much the wall facing the camera leans towards it
    (`lean`). None: not measured (a far view, no camera given, or the gate is off).
    lower_length_m: the longer side of the footprint of its points up to `LOWER_SHARE` of the top
    (None: fewer than 3 such points): what the cluster stands on.
    """

    points: int
    bottom_m: float
    top_m: float
    length_m: float
    width_m: float
    depth_m: float
    right_angles: float | None = None
    lean: float | None = None
    lower_length_m: float | None = None


def cluster_shape(heights: np.ndarray, flat: np.ndarray, depths: np.ndarray) -> ClusterShape:
    """The shape of a cluster from its points' heights above the plane (N,), horizontal
    coordinates in the plane (N, 2) and depths from the camera (N,)."""
    bottom, top = _percentiles(heights, (0.05, 0.95))
    length, width = footprint(flat)
    lower = heights <= LOWER_SHARE * top
    lower_length = footprint(flat[lower])[0] if lower.sum() >= 3 else None
    return ClusterShape(points=len(heights), bottom_m=float(bottom), top_m=float(top), length_m=length,
                        width_m=width, depth_m=float(np.median(depths)), lower_length_m=lower_length)


def footprint(flat: np.ndarray) -> tuple[float, float]:
    """(longer, shorter) extent of 2-D points along their principal axes, as a percentile range."""
    centred = flat - flat.mean(axis=0)
    if len(flat) < 3:
        extents = np.ptp(centred, axis=0) if len(flat) else np.zeros(2)
        return float(extents.max()), float(extents.min())
    _, vectors = np.linalg.eigh(centred.T @ centred)
    along = centred @ vectors  # columns: minor axis, major axis
    quantiles = tuple(p / 100 for p in FOOTPRINT_PERCENTILES)
    (low_width, high_width), (low_length, high_length) = (_percentiles(along[:, axis], quantiles) for axis in (0, 1))
    return float(high_length - low_length), float(high_width - low_width)


def _percentiles(values: np.ndarray, quantiles: tuple[float, ...]) -> np.ndarray:
    """`np.percentile(values, 100 * quantiles)`, to the bit, from one sort (numpy's own call costs
    ~50 us of overhead, and the gate asks for six per cluster)."""
    ordered = np.sort(values)
    count = np.full(len(quantiles), len(ordered))
    return _sorted_percentile(ordered, np.zeros(len(quantiles), dtype=np.int64), count, np.asarray(quantiles))


def right_angles(heights: np.ndarray, flat: np.ndarray, neighbours: int = 24) -> float | None:
    """0..1: how well the horizontal directions of the surface normals of a cluster (heights (N,),
    horizontal coordinates (N, 2)) fit one set of right angles. Each point's normal is the least
    principal axis of its `neighbours` nearest points; of the normals within ~24 degrees of
    horizontal (the walls, not a top), the azimuths phi give |mean(exp(4 i phi))|: 1 when every
    wall faces one of four directions 90 degrees apart (a box, a book), near 0 when the
    directions spread evenly over half a circle or more (a round wall). None with fewer than
    10 wall points."""
    points = np.column_stack([flat, heights])
    if len(points) <= neighbours:
        return None
    points = points - points.mean(axis=0)  # near the origin: the covariances' sums lose no digits
    _, nearest = cKDTree(points).query(points, neighbours)
    normals = _least_axes(*(points[:, axis][nearest] for axis in range(3)))
    wall = np.abs(normals[:, 2]) < 0.4
    if wall.sum() < 10:
        return None
    azimuth = np.arctan2(normals[wall, 1], normals[wall, 0])
    return float(np.abs(np.mean(np.exp(4j * azimuth))))


def _least_axes(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The least principal axis (unit, sign arbitrary) of each row's points, their coordinates as
    (N, k) arrays: the eigenvector of the smallest eigenvalue of each 3x3 covariance, in closed
    form (the eigenvalues by the trigonometric solution of the characteristic cubic, the vector as
    the largest cross product of two rows of A - lambda I); `np.linalg.eigh` where the smallest
    eigenvalue is (nearly) double and the closed form loses its digits. The same axes as `eigh`
    to ~1e-10 at a third of its cost (docs/speed.md, seg31)."""
    x, y, z = (c - c.mean(axis=1, keepdims=True) for c in (x, y, z))
    a00, a01, a02 = (x * x).sum(axis=1), (x * y).sum(axis=1), (x * z).sum(axis=1)
    a11, a12, a22 = (y * y).sum(axis=1), (y * z).sum(axis=1), (z * z).sum(axis=1)
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0
    p = np.sqrt(p2)
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    with np.errstate(invalid="ignore", divide="ignore"):
        phi = np.arccos(np.clip(det / (2.0 * p * p2), -1.0, 1.0)) / 3.0
    smallest = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    middle = q + 2.0 * p * np.cos(phi - 2.0 * np.pi / 3.0)
    rows = (np.stack([a00 - smallest, a01, a02], axis=1), np.stack([a01, a11 - smallest, a12], axis=1),
            np.stack([a02, a12, a22 - smallest], axis=1))
    crosses = np.stack([np.cross(rows[0], rows[1]), np.cross(rows[0], rows[2]), np.cross(rows[1], rows[2])])
    norms = (crosses * crosses).sum(axis=2)
    best = norms.argmax(axis=0)
    index = np.arange(len(best))
    axes: np.ndarray = crosses[best, index] / np.sqrt(norms[best, index])[:, None]
    doubtful = ~(middle - smallest > 1e-6 * p) | ~np.isfinite(axes).all(axis=1)
    if doubtful.any():
        covariance = np.stack([np.stack([a00, a01, a02], axis=1), np.stack([a01, a11, a12], axis=1),
                               np.stack([a02, a12, a22], axis=1)], axis=1)[doubtful]
        axes[doubtful] = np.linalg.eigh(covariance)[1][:, :, 0]
    return axes


def lean(heights: np.ndarray, flat: np.ndarray, camera_flat: np.ndarray, band_m: float = 0.01) -> float | None:
    """How far the surface facing the camera leans towards it: minus the slope of its horizontal
    distance from the camera (`camera_flat`, in the plane's coordinates) over the height above
    the plane. Per height band of `band_m`, the 10th percentile of the points' horizontal
    distance stands for the near surface; a line fitted through the bands gives the slope. About
    0 for an upright wall; a bowl's, which widens from its foot to its rim, 0.3-0.8. None with
    fewer than three bands of three points."""
    distance = np.linalg.norm(flat - camera_flat, axis=1)
    band = np.floor(heights / band_m).astype(np.int64)
    order = np.lexsort((distance, band))  # by band, then distance
    bands, first, counts = np.unique(band[order], return_index=True, return_counts=True)
    enough = counts >= 3
    if enough.sum() < 3:
        return None
    nearest = _sorted_percentile(distance[order], first[enough], counts[enough], 0.10)
    return float(-np.polyfit((bands[enough] + 0.5) * band_m, nearest, 1)[0])


def _sorted_percentile(values: np.ndarray, first: np.ndarray, counts: np.ndarray, q: float | np.ndarray
                       ) -> np.ndarray:
    """`np.percentile(group, 100 q)` of each group of `values` (sorted within each group, which
    starts at `first` and holds `counts` values; `q` one quantile or one per group), computed as
    numpy's linear method does, to the bit."""
    virtual = (counts - 1) * q
    below = np.floor(virtual)
    gamma = virtual - below
    a = values[first + below.astype(np.int64)]
    b = values[first + np.minimum(below.astype(np.int64) + 1, counts - 1)]
    difference = b - a
    result: np.ndarray = np.where(gamma >= 0.5, b - difference * (1 - gamma), a + difference * gamma)
    return result


def judge(heights: np.ndarray, flat: np.ndarray, depths: np.ndarray,
          config: ObjectnessConfig | None = ObjectnessConfig(),
          camera_flat: np.ndarray | None = None, shape: ClusterShape | None = None) -> tuple[ClusterShape, str | None]:
    """The cluster's shape and the gate's verdict (`rejection`; None: a mug, or no gate).
    `camera_flat`: the camera's position in the plane's coordinates (None: no `lean` test). The
    normals and the lean are measured only for a near view that passed every other test: the
    normals cost a neighbour search. `shape`: `cluster_shape` of these points, when the caller has it."""
    shape = cluster_shape(heights, flat, depths) if shape is None else shape
    if config is None:
        return shape, None
    reason = rejection(shape, config)
    if reason is None and shape.depth_m <= config.near_view_depth_m:
        shape = replace(shape, right_angles=right_angles(heights, flat, config.normal_neighbours),
                        lean=None if camera_flat is None else lean(heights, flat, camera_flat))
        reason = rejection(shape, config)
    return shape, reason


def rejection(shape: ClusterShape, config: ObjectnessConfig = ObjectnessConfig()) -> str | None:
    """Why the cluster is not a mug ("flat", "tall", "floating", "long", "short", "thin", "sliver",
    "column", "squat", "top-heavy", "boxy", "flared"), or None."""
    if shape.top_m < config.min_top_m:
        return "flat"
    if shape.top_m > config.max_top_m:
        return "tall"
    if shape.bottom_m > config.max_bottom_m:
        return "floating"
    if shape.length_m > config.max_length_m:
        return "long"
    if shape.length_m < config.min_length_m:
        return "short"
    if shape.width_m < config.min_width_m:
        return "thin"
    if shape.width_m < config.min_width_ratio * shape.length_m:
        return "sliver"
    if shape.top_m > config.max_aspect * shape.length_m:
        return "column"
    if shape.top_m < config.min_aspect * shape.length_m:
        return "squat"
    if shape.lower_length_m is not None and shape.lower_length_m < config.min_lower_ratio * shape.length_m:
        return "top-heavy"
    if shape.right_angles is not None and shape.right_angles > config.max_right_angles:
        return "boxy"
    if shape.lean is not None and shape.lean > config.max_lean:
        return "flared"
    return None
