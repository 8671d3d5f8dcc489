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
    levels within `band_height_m` of it are not searched: what lies there stands on it (mug bodies
    at one height) or belongs to it (a table's rim). A level is also rejected when it lies above
    the `camera` position (world; None: no such test), or its inliers form a strip.
    """
    camera = np.full(3, np.inf) if camera is None else camera
    planes: list[Plane] = []
    max_tilt_cos = np.cos(np.radians(config.plane_max_tilt_deg))
    sample = points[::_THIN]
    min_sample_points = config.min_plane_points / _THIN
    searchable = np.ones(len(sample), dtype=bool)
    search_up = up
    heights = sample @ search_up
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
        normal, offset, inliers = search_up, level, window
        # Least squares on the inliers, then the inliers of the refitted plane; the wider second
        # window takes in the parts of a plane that a tilted pose lifted out of the first.
        for width in _REFIT_WINDOWS:
            fitted = _fit_plane(sample[inliers], search_up)
            if fitted is None or fitted[0] @ up < max_tilt_cos:
                break
            normal, offset = fitted
            inliers = searchable & (np.abs(sample @ normal - offset) <= width * config.plane_distance_m)
        if (inliers.sum() < min_sample_points
                or camera @ normal - offset <= 0.0           # seen from below: nothing on it can be seen
                or _narrow_spread(sample[inliers], normal) < config.min_plane_spread_m):
            searchable &= ~(window | inliers)
            continue
        planes.append(Plane(normal, float(offset), np.abs(points @ normal - offset) <= config.plane_distance_m))
        if len(planes) == 1:
            search_up = normal
            heights = sample @ search_up
            order = np.argsort(heights)
        searchable &= np.abs(sample @ normal - offset) > config.band_height_m
    return _parallel(planes, points, config) if len(planes) > 1 else planes


def _parallel(planes: list[Plane], points: np.ndarray, config: SegmentationConfig) -> list[Plane]:
    """The planes made parallel, with the normal of the widest one (its narrower horizontal spread
    largest; usually the floor): a plane's tilt is known to about noise / extent, and a table top
    fitted alone was off by 1-2 degrees on the `paper` target (the floor's by 0.1 against the
    true pose), which lifted the far side of the table into the objects and merged its mugs."""
    inliers = [points[p.inliers] for p in planes]
    spreads = [_narrow_spread(own[::_THIN], p.normal) for own, p in zip(inliers, planes)]
    normal = planes[int(np.argmax(spreads))].normal
    along = points @ normal
    out = []
    for own in inliers:
        offset = float(own.mean(axis=0) @ normal)
        out.append(Plane(normal, offset, np.abs(along - offset) <= config.plane_distance_m))
    return out


def _narrow_spread(points: np.ndarray, normal: np.ndarray) -> float:
    """Standard deviation of the points along their narrower axis within the plane."""
    flat = points @ plane_axes(normal).T
    flat = flat - flat.mean(axis=0)
    return float(np.sqrt(np.linalg.eigvalsh(flat.T @ flat / len(flat))[0]))


def _fit_plane(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Least-squares plane (unit normal pointing along `up`, offset), or None for < 3 points."""
    if len(points) < 3:
        return None
    center = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - center, full_matrices=False)
    normal = vt[-1] if vt[-1] @ up >= 0 else -vt[-1]
    return normal, float(normal @ center)


def plane_axes(up: np.ndarray) -> np.ndarray:
    """Two unit vectors spanning the plane orthogonal to `up`, as the rows of a (2, 3) array."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.cross(up, helper)
    first /= np.linalg.norm(first)
    return np.stack([first, np.cross(up, first)])
