"""Intra-session update (paper Sec. IV-A): measurements (shape code, center) -> objects of one session.

A measurement joins the object of its neighbourhood that is within `distance_m` and whose shape
code is more cosine-similar than `shape_similarity` (the closest such object when several
qualify); the object then takes the measurement's code and center if the measurement's mean
occupancy (the NDF's confidence in its reconstruction) is higher than the object's. Otherwise the
measurement starts a new object.

ndfa changes two things (`ViewsConfig`; why: `docs/detector.md`): with `fusion="mean"` an
object keeps the mean of its measurements' unit codes and the median of their centers instead of
the most confident measurement's, and a measurement within `same_place_m` of an object (measured
horizontally; with the height tree T_z, `LevelsConfig`, also within half its interval in height, so
that a mug never joins the one on the shelf above) joins it whatever the codes say. A measurement that joins no object by these rules
joins the nearest object within `revisit_m` that was not measured in the same frame: the odometry
drifts between two visits of a place, more than `distance_m` on real sequences. And with
`follow_latest`, the distances of the first two rules are also measured to where the object was
last measured: the odometry drifts little from one frame to the next, so an object followed frame
after frame while the drift carries its views away from their median stays one object.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ndfa.change.config import DetectorConfig
from ndfa.change.tree import ObjectTree
from ndfa.core.conventions import UNKNOWN_CATEGORY, UP_AXIS, horizontal
from ndfa.core.events import ObservationEvent


def likeliest(category_votes: dict[str, float]) -> str:
    """The category with the largest summed vote (ties: the later name); `UNKNOWN_CATEGORY` when
    there are no votes."""
    return max(category_votes, key=lambda name: (category_votes[name], name)) if category_votes else UNKNOWN_CATEGORY


@dataclass(frozen=True)
class Measurement:
    """One encoded observation, in the session's world frame."""

    frame_index: int
    instance_id: int          # the mask's id (kept for analysis; the method does not use it)
    shape_code: np.ndarray    # (D,)
    center_world: np.ndarray  # (3,)
    mean_occupancy: float
    heading_rad: float = float("nan")  # the handle's azimuth about up, and how sure (`ndfa.ndf.heading`)
    heading_strength: float = 0.0
    category: str = UNKNOWN_CATEGORY  # the NDF's likeliest category, and its probability
    category_probability: float = float("nan")
    n_pixels: int = 0  # the view's pixels (perception's count, `ObservationEvent.n_pixels`); 0: not known
    # the height of the view's lowest points (their 5th percentile along up): where the object
    # stands, as this view shows it (segments lose a centimetre or so to the support); NaN: not known
    base_height: float = float("nan")
    # ... and of its highest (their 95th percentile): how high the object reaches, as far as this view shows it
    top_height: float = float("nan")

    @classmethod
    def of(cls, observation: ObservationEvent) -> Measurement:
        """The measurement of an encoded observation: the one way the pipeline, a replayed table
        and a many-session run turn what the NDF saw into what the detector takes."""
        if observation.skipped is not None or observation.shape_code is None or observation.center_world is None:
            raise ValueError(f"frame {observation.frame_index}, instance {observation.instance_id}: "
                             f"a skipped or unencoded observation is no measurement ({observation.skipped})")
        return cls(observation.frame_index, observation.instance_id, observation.shape_code,
                   observation.center_world, observation.mean_occupancy, observation.heading_rad,
                   observation.heading_strength, observation.category, observation.category_probability,
                   observation.n_pixels, *height_extent(observation.points_world))


def height_extent(points_world: np.ndarray | None) -> tuple[float, float]:
    """The heights of a view's lowest and highest points (the 5th and 95th percentiles along up: a
    stray point below the support or above the object does not set them); NaN without points."""
    if points_world is None or not len(points_world):
        return float("nan"), float("nan")
    low, high = np.percentile(np.asarray(points_world)[:, UP_AXIS], [5, 95])
    return float(low), float(high)


@dataclass
class SessionObject:
    """An object of a session's map: the best measurement so far and its history."""

    object_id: int
    shape_code: np.ndarray
    center_world: np.ndarray
    mean_occupancy: float
    first_frame: int
    last_frame: int
    n_measurements: int = 1
    instance_ids: tuple[int, ...] = ()  # mask ids of the measurements it took, in order of first use
    code_sum: np.ndarray | None = None   # sum of the unit codes of its measurements ("mean" fusion)
    centers: list[np.ndarray] | None = None  # centers of its measurements ("mean" fusion)
    # (heading, strength) of every measurement it took: `ndfa.change.rotation` fuses the reliable ones
    headings: list[tuple[float, float]] = field(default_factory=list)
    # the frame of each measurement in `headings` (and in `centers`): which frames saw it
    frames: list[int] = field(default_factory=list)
    # ... and its pixels (`Measurement.n_pixels`): how large the object showed in each
    pixels: list[int] = field(default_factory=list)
    # `centers`, `headings`, `frames` and `pixels` keep every `history_stride`-th measurement (`keep_in_history`)
    history_stride: int = 1
    latest_center: np.ndarray | None = None  # its latest measurement's center (None: its center)
    # category -> the summed probability of its measurements that found it the likeliest (`category`)
    category_votes: dict[str, float] = field(default_factory=dict)
    # the lowest of its measurements' `base_height`s: where it stands (inf: none known); and the
    # highest of their `top_height`s: how high it reaches (-inf: none known)
    base_height: float = float("inf")
    top_height: float = float("-inf")

    @property
    def category(self) -> str:
        """The category most of its measurements' probability went to; `UNKNOWN_CATEGORY` when none
        had one (a model without a category head)."""
        return likeliest(self.category_votes)

    @property
    def category_share(self) -> float:
        """How much of its measurements' category probability went to `category` (0..1; NaN: none)."""
        total = sum(self.category_votes.values())
        return self.category_votes[self.category] / total if total else float("nan")

    def vote(self, m: Measurement) -> None:
        """Count a measurement's category (one without any counts nothing)."""
        if m.category != UNKNOWN_CATEGORY and np.isfinite(m.category_probability):
            self.category_votes[m.category] = self.category_votes.get(m.category, 0.0) + m.category_probability

    def extend(self, m: Measurement) -> None:
        """Take a measurement's base where it lies lower and its top where it reaches higher (one
        without points changes nothing)."""
        if np.isfinite(m.base_height):
            self.base_height = min(self.base_height, m.base_height)
        if np.isfinite(m.top_height):
            self.top_height = max(self.top_height, m.top_height)

    @property
    def center_scatter_m(self) -> float:
        """RMS horizontal distance of its measurements' centers from its center: how far its position
        wandered while it was seen (the odometry's drift, a real object's view-dependent center);
        0 when the measurements are not kept ("best" fusion)."""
        if not self.centers:
            return 0.0
        offsets = horizontal(np.array(self.centers)) - horizontal(self.center_world)
        return float(np.sqrt(np.mean(np.sum(offsets**2, axis=-1))))


@dataclass(frozen=True)
class Association:
    """What the update did with one measurement."""

    object_id: int
    created: bool           # a new object was started
    replaced: bool          # the object took the measurement's code and center
    distance_m: float       # to the object's center before the update (nan when created)
    similarity: float       # shape cosine similarity to it (nan when created)
    candidates: int         # objects in the measurement's neighbourhood


def cosine_similarity(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cosine similarity of code `a` (D,) with each row of `b` (M, D) or with a single code `b` (D,)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    denominator = np.linalg.norm(a) * np.linalg.norm(b, axis=-1)
    similarity: np.ndarray = (b @ a) / np.maximum(denominator, 1e-12)
    return similarity


class SessionMap:
    """The objects of one session and their spatial object tree."""

    def __init__(self, config: DetectorConfig = DetectorConfig()) -> None:
        self.config = config  # its association (the paper's), views and drift parts
        self.tree = ObjectTree(config.association.tree_length_m, config.levels.tree_height_m)
        self.objects: dict[int, SessionObject] = {}

    def __len__(self) -> int:
        return len(self.objects)

    def neighbourhood(self, point: np.ndarray, margin: float = 0.0) -> list[int]:
        """Object ids around `point` (`ObjectTree.neighbourhood`), sorted (so that everything
        downstream is deterministic)."""
        return sorted(self.tree.neighbourhood(point, margin))

    def _same_place(self, offsets: np.ndarray) -> np.ndarray:
        """Which (N, 3) offsets from a measurement are within `same_place_m` horizontally (and, on
        shelves, within the same level: `LevelsConfig`)."""
        same_place: np.ndarray = np.linalg.norm(horizontal(offsets), axis=1) < self.config.views.same_place_m
        if self.config.levels.tree_height_m is not None:  # on shelves, one place is one level
            same_place &= np.abs(offsets[:, UP_AXIS]) < self.config.levels.tree_height_m / 2
        return same_place

    def update(self, m: Measurement) -> Association:
        c, views, drift = self.config.association, self.config.views, self.config.drift
        # Every object that could take the measurement, also across a cell's edge.
        reach = max(c.distance_m, views.same_place_m, drift.revisit_m) if drift.across_cells else 0.0
        candidates = self.neighbourhood(m.center_world, reach)
        best, best_distance, best_similarity = None, np.inf, np.nan
        revisit, revisit_distance, revisit_similarity = None, np.inf, np.nan
        if candidates:
            objects = [self.objects[i] for i in candidates]
            centers = np.array([o.center_world for o in objects])
            offsets = centers - m.center_world
            distance = np.linalg.norm(offsets, axis=1)
            similarity = cosine_similarity(m.shape_code, np.array([o.shape_code for o in objects]))
            horizontal_distance = np.linalg.norm(horizontal(offsets), axis=1)
            alike = similarity > c.shape_similarity
            same = self._same_place(offsets) | ((distance < c.distance_m) & alike)
            near = distance
            if drift.follow_latest:  # or near where it was last measured (the drift since is small)
                latest = np.array([o.center_world if o.latest_center is None else o.latest_center for o in objects])
                near = np.minimum(distance, np.linalg.norm(latest - m.center_world, axis=1))
                same |= self._same_place(latest - m.center_world) | ((near < c.distance_m) & alike)
            # The same object seen again after the odometry drifted: near, and not seen in this frame
            # (two objects measured in one frame are two objects). Not "alike": a place seen again
            # is mostly seen from elsewhere, and one mug's codes from opposite sides are 0.0-0.6
            # cosine-similar (docs/detector.md, "Drift"), no evidence of another object.
            seen_again = ((horizontal_distance < drift.revisit_m) & (np.abs(offsets[:, UP_AXIS]) < drift.revisit_m)
                          & np.array([o.last_frame != m.frame_index for o in objects]))
            if same.any():  # the nearest (the first of equals, in id order)
                k = int(np.flatnonzero(same)[np.argmin(near[same])])
                best, best_distance, best_similarity = objects[k], float(distance[k]), float(similarity[k])
            if seen_again.any():
                k = int(np.flatnonzero(seen_again)[np.argmin(distance[seen_again])])
                revisit, revisit_distance, revisit_similarity = objects[k], float(distance[k]), float(similarity[k])
        if best is None and revisit is not None:
            best, best_distance, best_similarity = revisit, revisit_distance, revisit_similarity
        if best is None:
            object_id = len(self.objects)
            self.objects[object_id] = SessionObject(
                object_id, m.shape_code, m.center_world, m.mean_occupancy, m.frame_index, m.frame_index,
                instance_ids=(m.instance_id,), code_sum=_unit(m.shape_code), centers=[m.center_world],
                headings=[(m.heading_rad, m.heading_strength)], frames=[m.frame_index], pixels=[m.n_pixels])
            self.objects[object_id].vote(m)
            self.objects[object_id].extend(m)
            self.tree.insert(object_id, m.center_world)
            return Association(object_id, True, False, float("nan"), float("nan"), len(candidates))
        best.n_measurements += 1
        best.vote(m)
        best.extend(m)
        best.last_frame = m.frame_index
        best.latest_center = m.center_world
        kept = keep_in_history(best)
        if kept:
            best.headings.append((m.heading_rad, m.heading_strength))
            best.frames.append(m.frame_index)
            best.pixels.append(m.n_pixels)
        if m.instance_id not in best.instance_ids:
            best.instance_ids += (m.instance_id,)
        if views.fusion == "mean":
            assert best.code_sum is not None and best.centers is not None  # every object starts with both
            best.code_sum = best.code_sum + _unit(m.shape_code)
            if kept:
                best.centers.append(m.center_world)
            best.shape_code = best.code_sum / best.n_measurements
            best.center_world = np.median(np.array(best.centers), axis=0)
            best.mean_occupancy = max(best.mean_occupancy, m.mean_occupancy)
            self.tree.insert(best.object_id, best.center_world)
            return Association(best.object_id, False, True, best_distance, best_similarity, len(candidates))
        replaced = m.mean_occupancy > best.mean_occupancy
        if replaced:
            best.shape_code, best.center_world, best.mean_occupancy = m.shape_code, m.center_world, m.mean_occupancy
            self.tree.insert(best.object_id, m.center_world)
        return Association(best.object_id, False, replaced, best_distance, best_similarity, len(candidates))


# The most measurements an object's history (`SessionObject.centers`, `headings`) holds: past it,
# every other one is dropped and from then on every other new one is skipped, so that the history
# stays an even sample of all the object's measurements (a median, a circular mean, a scatter) and
# memory and the median's cost stay bounded in the recording's length. No object of the published
# scenes comes near it (paper seed 0: at most ~100 measurements), so they keep every measurement.
MAX_HISTORY = 512


def keep_in_history(obj: SessionObject) -> bool:
    """Whether `obj`'s latest measurement (its `n_measurements`-th) joins its history; thins the
    history first when it is full."""
    if len(obj.headings) >= MAX_HISTORY:
        obj.headings = obj.headings[::2]
        obj.frames = obj.frames[::2]
        obj.pixels = obj.pixels[::2]
        if obj.centers is not None:
            obj.centers = obj.centers[::2]
        obj.history_stride *= 2
    return (obj.n_measurements - 1) % obj.history_stride == 0


def _unit(code: np.ndarray) -> np.ndarray:
    code = np.asarray(code, dtype=np.float64)
    return code / max(float(np.linalg.norm(code)), 1e-12)
