"""Where planted objects stand: support planes and free spots in a scene cloud (`ndfa plant`).

A scene cloud is the points of a session's frames (every few frames, every few pixels) in its
z-up world. The support under a horizontal position is the dominant height of the points around
it, refitted as a plane; a free spot is a place on one support plane that both sessions saw, with
plane under the whole footprint and nothing standing on it. Pure numpy; no I/O.
"""

from __future__ import annotations

import numpy as np

from ndfa.sim.plant import SupportPlane

# Height bins of the support search, and the half-width of a support plane's inliers.
HEIGHT_BIN_M = 0.01
PLANE_BAND_M = 0.015
MIN_SUPPORT_POINTS = 40
MAX_SUPPORT_TILT_DEG = 10.0
# The grid of the free-spot search; a cell is seen when it holds this many points of the plane.
CELL_M = 0.04
MIN_CELL_POINTS = 3
# What stands on a plane: points this far above it, up to the band of objects; a cell is taken when
# this share of its points stand (a magazine on a table is 1 cm thick, the table's noise at 2.5 m about as much).
STANDING_M = (0.01, 0.35)
TAKEN_SHARE = 0.2


def support_at(cloud: np.ndarray, xy: np.ndarray, inner_m: float, outer_m: float) -> SupportPlane | None:
    """The support plane under horizontal position `xy`, from the points of `cloud` (N, 3) between
    `inner_m` and `outer_m` of it horizontally (the object's own points lie inside `inner_m`): the
    most populated height, refitted by least squares. None when too few points or too steep."""
    distance = np.linalg.norm(cloud[:, :2] - np.asarray(xy, dtype=float)[:2], axis=1)
    ring = cloud[(distance >= inner_m) & (distance <= outer_m)]
    if len(ring) < MIN_SUPPORT_POINTS:
        return None
    z = ring[:, 2]
    edges = np.arange(z.min(), z.max() + 2 * HEIGHT_BIN_M, HEIGHT_BIN_M)
    counts, _ = np.histogram(z, bins=edges)
    # Counts of the bin and its neighbours: a level split between two bins wins as one.
    window = np.convolve(counts, np.ones(3), mode="same")
    level = edges[int(np.argmax(window))] + HEIGHT_BIN_M / 2
    inliers = ring[np.abs(z - level) <= PLANE_BAND_M]
    if len(inliers) < MIN_SUPPORT_POINTS:
        return None
    return fit_plane(inliers)


def fit_plane(points: np.ndarray) -> SupportPlane | None:
    """Least-squares plane through `points` (N, 3), normal up; None when tilted more than
    `MAX_SUPPORT_TILT_DEG` (no support surface) or degenerate."""
    center = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - center, full_matrices=False)
    normal = vt[-1] if vt[-1][2] >= 0 else -vt[-1]
    if normal[2] < np.cos(np.radians(MAX_SUPPORT_TILT_DEG)):
        return None
    return SupportPlane(normal, float(normal @ center))


def largest_plane(clouds: list[np.ndarray]) -> tuple[SupportPlane, list[np.ndarray]] | None:
    """The horizontal plane with the largest area seen by every cloud, and per cloud its inliers:
    each candidate height (a peak of the height histogram of the first cloud) is scored by the
    grid cells holding its points in every cloud."""
    z = clouds[0][:, 2]
    edges = np.arange(z.min(), z.max() + 2 * HEIGHT_BIN_M, HEIGHT_BIN_M)
    counts, _ = np.histogram(z, bins=edges)
    window = np.convolve(counts, np.ones(3), mode="same")
    peaks = [i for i in np.argsort(-window)[:40] if window[i] >= MIN_SUPPORT_POINTS]
    best, best_area = None, 0
    tried: list[float] = []
    for i in peaks:
        level = edges[i] + HEIGHT_BIN_M / 2
        if any(abs(level - t) < 3 * PLANE_BAND_M for t in tried):
            continue
        tried.append(level)
        plane = fit_plane(clouds[0][np.abs(z - level) <= PLANE_BAND_M])
        if plane is None:
            continue
        on = [cloud[np.abs(plane.height(cloud)) <= PLANE_BAND_M] for cloud in clouds]
        cells = _common_cells([_cells(points) for points in on])
        if len(cells) > best_area:
            best, best_area = (plane, on), len(cells)
    return best


def free_spots(plane: SupportPlane, clouds: list[np.ndarray], clearance_m: float) -> np.ndarray:
    """(K, 2) centers of grid cells of `plane` where an object of footprint radius `clearance_m`
    fits: every cloud saw plane in every cell within `clearance_m`, and nothing standing there."""
    seen = _common_cells([_cells(cloud[np.abs(plane.height(cloud)) <= PLANE_BAND_M]) for cloud in clouds])
    standing: set[tuple[int, int]] = set()
    for cloud in clouds:
        height = plane.height(cloud)
        near = cloud[(height > -PLANE_BAND_M) & (height < STANDING_M[1])]
        up = (plane.height(near) > STANDING_M[0]).astype(float)
        keys, inverse = np.unique(np.floor(near[:, :2] / CELL_M).astype(np.int64), axis=0, return_inverse=True)
        share = np.bincount(inverse.ravel(), weights=up) / np.bincount(inverse.ravel())
        standing |= {(int(a), int(b)) for (a, b), taken in zip(keys, share) if taken >= TAKEN_SHARE}
    reach = int(np.ceil(clearance_m / CELL_M))
    offsets = [(dx, dy) for dx in range(-reach, reach + 1) for dy in range(-reach, reach + 1)
               if np.hypot(dx, dy) * CELL_M <= clearance_m]
    spots = [cell for cell in seen
             if all((cell[0] + dx, cell[1] + dy) in seen and (cell[0] + dx, cell[1] + dy) not in standing
                    for dx, dy in offsets)]
    return (np.array(sorted(spots), dtype=float).reshape(-1, 2) + 0.5) * CELL_M


def _cells(points: np.ndarray) -> set[tuple[int, int]]:
    """Grid cells holding at least `MIN_CELL_POINTS` of `points`."""
    if len(points) == 0:
        return set()
    keys, counts = np.unique(np.floor(points[:, :2] / CELL_M).astype(np.int64), axis=0, return_counts=True)
    return {(int(a), int(b)) for (a, b), n in zip(keys, counts) if n >= MIN_CELL_POINTS}


def _common_cells(cell_sets: list[set[tuple[int, int]]]) -> set[tuple[int, int]]:
    common = cell_sets[0]
    for cells in cell_sets[1:]:
        common = common & cells
    return common


def choose_spots(spots: np.ndarray, count: int, rng: np.random.Generator, apart_m: float,
                 avoid: np.ndarray, first_pair_apart_m: float = 0.0) -> np.ndarray | None:
    """`count` of `spots` (K, 2), drawn by `rng`, at least `apart_m` from each other and from
    `avoid` (M, 2); the first two at least `first_pair_apart_m` apart (a move's ends) where any
    two spots are, else as far apart as any. None when they do not fit."""
    avoid = np.asarray(avoid, dtype=float).reshape(-1, 2)
    chosen: list[np.ndarray] = []
    for k in range(count):
        taken = np.vstack([avoid, *chosen]) if (len(avoid) or chosen) else np.empty((0, 2))
        free = spots if len(taken) == 0 else spots[
            np.min(np.linalg.norm(spots[:, None] - taken[None], axis=2), axis=1) >= apart_m]
        if len(free) == 0:
            return None
        if k == 1 and first_pair_apart_m > 0:
            far = np.linalg.norm(free - chosen[0], axis=1)
            wide = free[far >= first_pair_apart_m]
            free = wide if len(wide) else free[[int(np.argmax(far))]]
        chosen.append(free[rng.integers(len(free))])
    return np.array(chosen)


# Segments' centers this close (horizontally) in different frames are one object.
SAME_OBJECT_M = 0.06


def group_centers(centers: np.ndarray) -> np.ndarray:
    """Greedy groups of segment `centers` (N, 3) whose horizontal positions lie within
    `SAME_OBJECT_M` of the most crowded one left: (K, 3) medians, the most populated first."""
    remaining = np.asarray(centers, dtype=float).reshape(-1, 3)
    groups = []
    while len(remaining):
        flat = remaining[:, :2]
        counts = (np.linalg.norm(flat[:, None] - flat[None], axis=2) <= SAME_OBJECT_M).sum(axis=1)
        near = np.linalg.norm(flat - flat[int(np.argmax(counts))], axis=1) <= SAME_OBJECT_M
        groups.append(np.median(remaining[near], axis=0))
        remaining = remaining[~near]
    return np.array(groups).reshape(-1, 3)
