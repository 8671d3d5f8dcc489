"""DBSCAN on 3-D points (Ester et al. 1996), with a k-d tree: the clustering step of the segmentation."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def dbscan(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """DBSCAN cluster index per point (-1: noise). Core points have >= `min_points` neighbours
    within `eps` (themselves included); linked cores form a cluster; a border point joins the
    cluster of one of its core neighbours."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(points).query_pairs(eps, output_type="ndarray")
    neighbours = 1 + np.bincount(pairs[:, 0], minlength=len(points)) + np.bincount(pairs[:, 1], minlength=len(points))
    core = neighbours >= min_points
    cluster = np.full(len(points), -1, dtype=np.int64)
    if core.any():
        both = pairs[core[pairs[:, 0]] & core[pairs[:, 1]]]
        graph = coo_matrix((np.ones(len(both), dtype=np.int8), (both[:, 0], both[:, 1])), shape=(len(points),) * 2)
        _, component = connected_components(graph, directed=False)
        cluster[core] = component[core]
        for a, b in ((0, 1), (1, 0)):  # border points: a non-core point next to a core point
            border = pairs[core[pairs[:, a]] & ~core[pairs[:, b]]]
            cluster[border[:, b]] = cluster[border[:, a]]
    return cluster
