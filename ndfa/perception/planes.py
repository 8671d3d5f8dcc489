"""Horizontal support planes (floor, table tops) in the world points of one frame: found by an
exhaustive search over heights along the world's up, refitted by least squares, and made parallel
(step 2 of `ndfa.perception.segmentation`).

With the up direction known, a horizontal plane has one free parameter, its height, so the
consensus search is exhaustive rather than random. Pure numpy; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.perception.segmentation_config import SegmentationConfig

_REFIT_WINDOWS = (2.5, 1.5, 1.0, 1.0)  # inlier windows of the successive refits, in plane_distance_m
_THIN = 4  # the plane search uses every 4th sampled point: its counts only rank levels
# A surface within an accepted plane's band (`_surfaces`): its window holds this many times each of
# the windows this many windows above and below it, and its points spread this far across.
_SURFACE_PEAK, _SURFACE_SHELL, _SURFACE_SPREAD_M = 2.5, 2.0, 0.15
# ... and it lies at least this far from the accepted plane: nearer, it holds nothing the plane does
# not (a far stretch of one table top a pose's tilt set 3 cm lower); a shelf's boards are 15 cm apart or more.
_SURFACE_APART_M = 0.10


@dataclass(frozen=True)
class Plane:
    """A support plane: points p with normal . p = offset; normal points up."""

    normal: np.ndarray
    offset: float
    inliers: np.ndarray  # (N,) bool over the sampled points the plane was found in

    def height(self, points: np.ndarray) -> np.ndarray:
        height: np.ndarray = points @ self.normal - self.offset
        return height


def find_horizontal_planes(points: np.ndarray, up: np.ndarray, config: SegmentationConfig,
                           camera: np.ndarray | None = None) -> list[Plane]:
    """Horizontal planes, most populated first (step 2 of `ndfa.perception.segmentation`).

    The search and the refits use every 4th point (`_THIN`); only an accepted plane's inliers are
    counted over all points. The first (largest) plane's refitted normal becomes the up direction
    for the others: a pose tilted by a few degrees (the `paper` target's are, by up to 3)
    otherwise smears a far table top over several height windows. Once a plane is accepted, the
    levels within `band_height_m` of it are not searched (`_held_by`: what lies there stands on it
    or belongs to it) but for horizontal surfaces wider than any object (a shelf's boards). A level
    is also rejected when it lies above the `camera` position (world; None: no such test), or its
    inliers form a strip.
    """
    camera = np.full(3, np.inf) if camera is None else camera
    planes: list[Plane] = []
    # Coordinates as rows (3, N): numpy's means and products along the long axis of a (N, 3) array
    # cost several times more than along contiguous rows.
    columns = np.ascontiguousarray(points.T)
    sample = np.ascontiguousarray(columns[:, ::_THIN])
    min_sample_points = config.min_plane_points / _THIN
    searchable = np.ones(sample.shape[1], dtype=bool)
    search_up = up
    heights = search_up @ sample
    order = np.argsort(heights)  # sorted once per direction: a subset of sorted heights is sorted
    for _ in range(2 * config.max_planes):
        if len(planes) == config.max_planes or searchable.sum() < min_sample_points:
            break
        sorted_heights = heights[order[searchable[order]]]
        grid = np.arange(sorted_heights[0], sorted_heights[-1] + config.plane_distance_m, config.plane_distance_m / 2)
        counts = (np.searchsorted(sorted_heights, grid + config.plane_distance_m, side="right")
                  - np.searchsorted(sorted_heights, grid - config.plane_distance_m, side="left"))
        if counts.max() < min_sample_points:
            break
        level = grid[counts.argmax()]
        window = searchable & (np.abs(heights - level) <= config.plane_distance_m)
        normal, offset, inliers = _refined(sample, searchable, search_up, level, window, search_up, up, config)
        if not _acceptable(sample, inliers, normal, offset, camera, config):
            searchable &= ~(window | inliers)
            continue
        planes.append(Plane(normal, float(offset), np.abs(normal @ columns - offset) <= config.plane_distance_m))
        if len(planes) == 1:
            search_up = normal
            heights = search_up @ sample
            order = np.argsort(heights)
        searchable &= ~_held_by(sample, normal, offset, config)
    return _parallel(planes, columns, config) if len(planes) > 1 else planes


def track_horizontal_planes(points: np.ndarray, previous: list[Plane], up: np.ndarray, config: SegmentationConfig,
                            camera: np.ndarray | None = None) -> list[Plane] | None:
    """The planes `previous` (of an earlier frame, in the same world frame) found again in these
    points, as `find_horizontal_planes` finds a level (the inliers of its height window, refitted,
    the same tests), without searching the heights for others; None when one of them fails a test
    (the caller then searches in full). A plane that comes into view is found at the next full
    search (`PlaneTracker`)."""
    camera = np.full(3, np.inf) if camera is None else camera
    columns = np.ascontiguousarray(points.T)
    sample = np.ascontiguousarray(columns[:, ::_THIN])
    searchable = np.ones(sample.shape[1], dtype=bool)
    planes: list[Plane] = []
    for plane in previous:
        window = searchable & (np.abs(plane.normal @ sample - plane.offset) <= config.plane_distance_m)
        normal, offset, inliers = _refined(sample, searchable, plane.normal, plane.offset, window, up, up, config)
        if not _acceptable(sample, inliers, normal, offset, camera, config):
            return None
        planes.append(Plane(normal, float(offset), np.abs(normal @ columns - offset) <= config.plane_distance_m))
        searchable &= ~_held_by(sample, normal, offset, config)
    return _parallel(planes, columns, config) if len(planes) > 1 else planes


def _held_by(sample: np.ndarray, normal: np.ndarray, offset: float, config: SegmentationConfig) -> np.ndarray:
    """Which points of `sample` (rows (3, N)) an accepted plane holds, so that no other level is
    searched among them: those within `band_height_m` of it, what stands on it (mug bodies at one
    height) or belongs to it (a table's rim), but for the levels there that are surfaces of their
    own (`_surfaces`: a shelf's boards, 25-35 cm apart, the lowest 15-35 cm above the floor)."""
    height = normal @ sample - offset
    held: np.ndarray = np.abs(height) <= config.band_height_m
    for level in _surfaces(sample, height, held, normal, config):
        held &= np.abs(height - level) > _REFIT_WINDOWS[0] * config.plane_distance_m
    return held


def _surfaces(sample: np.ndarray, height: np.ndarray, among: np.ndarray, normal: np.ndarray,
              config: SegmentationConfig) -> list[float]:
    """The levels at least `_SURFACE_APART_M` from 0 among the points `among` of `sample` (rows
    (3, N), `height` above a plane of `normal`) where a horizontal surface lies that is wider than
    any object: the height window of `plane_distance_m` holds at least `min_plane_points`
    (thinned), `_SURFACE_PEAK` times what each of the windows
    `_SURFACE_SHELL` windows above and below holds (the slices of mug bodies and of walls hold as
    many points at every height: a surface's lie at one), and its points spread at least
    `min_plane_spread_m` along their narrower horizontal axis (no strip of a wall) and
    `_SURFACE_SPREAD_M` along their wider one (a box's top, however flat, is no wider than
    `max_extent_m`). Largest first."""
    distance = config.plane_distance_m
    heights = np.sort(height[among])
    if len(heights) < config.min_plane_points / _THIN:
        return []
    grid = np.arange(heights[0], heights[-1] + distance, distance / 2)

    def count(levels: np.ndarray) -> np.ndarray:
        return np.searchsorted(heights, levels + distance, side="right") - np.searchsorted(heights, levels - distance)

    shell = _SURFACE_SHELL * distance
    inside, beside = count(grid), np.maximum(count(grid - shell), count(grid + shell))
    peaks = np.flatnonzero((np.abs(grid) >= _SURFACE_APART_M) & (inside >= config.min_plane_points / _THIN)
                           & (inside >= _SURFACE_PEAK * beside))
    levels: list[float] = []
    for level in grid[peaks[np.argsort(-inside[peaks], kind="stable")]]:
        narrow, wide = _spreads(plane_axes(normal) @ np.compress(among & (np.abs(height - level) <= distance), sample, axis=1))
        if all(abs(level - other) > shell for other in levels) and narrow >= config.min_plane_spread_m \
                and wide >= _SURFACE_SPREAD_M:
            levels.append(float(level))
    return levels


def _refined(sample: np.ndarray, searchable: np.ndarray, normal: np.ndarray, offset: float, inliers: np.ndarray,
             search_up: np.ndarray, up: np.ndarray, config: SegmentationConfig
             ) -> tuple[np.ndarray, float, np.ndarray]:
    """A level's plane (normal, offset, its inliers among the `searchable` points of `sample`, as
    rows (3, N)) refitted: least squares on the inliers, then the inliers of the refitted plane; the
    wider second window takes in the parts of a plane that a tilted pose lifted out of the first.
    A fit tilted more than `plane_max_tilt_deg` from `up` ends the refits."""
    max_tilt_cos = np.cos(np.radians(config.plane_max_tilt_deg))
    for width in _REFIT_WINDOWS:
        fitted = _fit_plane(np.compress(inliers, sample, axis=1), search_up)
        if fitted is None or fitted[0] @ up < max_tilt_cos:
            break
        normal, offset = fitted
        inliers = searchable & (np.abs(normal @ sample - offset) <= width * config.plane_distance_m)
    return normal, offset, inliers


def _acceptable(sample: np.ndarray, inliers: np.ndarray, normal: np.ndarray, offset: float, camera: np.ndarray,
                config: SegmentationConfig) -> bool:
    """Whether a refitted level is a support plane: enough inliers, seen from above (nothing on a
    plane seen from below can be seen), not a strip."""
    return not (inliers.sum() < config.min_plane_points / _THIN or camera @ normal - offset <= 0.0
                or _narrow_spread(np.compress(inliers, sample, axis=1), normal) < config.min_plane_spread_m)


def _parallel(planes: list[Plane], columns: np.ndarray, config: SegmentationConfig) -> list[Plane]:
    """The planes made parallel, with the normal of the widest one (its narrower horizontal spread
    largest; usually the floor): a plane's tilt is known to about noise / extent, and a table top
    fitted alone was off by 1-2 degrees on the `paper` target (the floor's by 0.1 against the
    true pose), which lifted the far side of the table into the objects and merged its mugs.
    `columns`: the points as rows (3, N)."""
    inliers = [np.compress(p.inliers, columns, axis=1) for p in planes]
    spreads = [_narrow_spread(own[:, ::_THIN], p.normal) for own, p in zip(inliers, planes)]
    normal = planes[int(np.argmax(spreads))].normal
    along = normal @ columns
    out = []
    for own in inliers:
        offset = float(normal @ own.mean(axis=1))
        out.append(Plane(normal, offset, np.abs(along - offset) <= config.plane_distance_m))
    return out


def _narrow_spread(columns: np.ndarray, normal: np.ndarray) -> float:
    """Standard deviation of the points (as rows (3, N)) along their narrower axis within the plane."""
    return _spreads(plane_axes(normal) @ columns)[0]


def _spreads(flat: np.ndarray) -> tuple[float, float]:
    """Standard deviations of 2-D points (as rows (2, N)) along their narrower and wider axes."""
    flat = flat - flat.mean(axis=1, keepdims=True)
    narrow, wide = np.sqrt(np.maximum(np.linalg.eigvalsh(flat @ flat.T / flat.shape[1]), 0.0))
    return float(narrow), float(wide)


def _fit_plane(columns: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares plane (unit normal pointing along `up`, offset) of points as rows (3, N), or
    None for < 3 points. The normal: the least eigenvector of the points' scatter matrix (what the
    SVD of the centred points gives, at a third of its cost)."""
    if columns.shape[1] < 3:
        return None
    center = columns.mean(axis=1)
    centred = columns - center[:, None]
    least = np.linalg.eigh(centred @ centred.T)[1][:, 0]
    normal = least if least @ up >= 0 else -least
    return normal, float(normal @ center)


def plane_axes(up: np.ndarray) -> np.ndarray:
    """Two unit vectors spanning the plane orthogonal to `up`, as the rows of a (2, 3) array."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.cross(up, helper)
    first /= np.linalg.norm(first)
    return np.stack([first, np.cross(up, first)])
