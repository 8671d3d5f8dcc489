"""DBSCAN on 3-D points (Ester et al. 1996), with a k-d tree: the clustering step of the segmentation;
exact (`dbscan`), or on a voxel grid (`voxel_dbscan`, the segmentation's default: docs/speed.md)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


def dbscan(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """DBSCAN cluster index per point (-1: noise). Core points have >= `min_points` neighbours
    within `eps` (themselves included); linked cores form a cluster; a border point joins the
    cluster of one of its core neighbours."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    return _clusters(points, None, eps, min_points)


def voxel_dbscan(points: np.ndarray, eps: float, min_points: int, side: float) -> np.ndarray:
    """`dbscan` of the points binned in voxels of `side` (metres): each voxel one point at its points'
    mean, weighing as many points; a core voxel's voxels within `eps` (its own included) hold >=
    `min_points` points; each point takes its voxel's cluster. Two points whose voxels are linked
    lie at most eps + 2 sqrt(3) side apart (a voxel's mean is inside it), and two points under eps
    apart may be cut where their means are farther: the clusters follow the exact ones up to about
    a voxel (tests/test_dbscan.py measures how closely). The pair search and the graph then count
    voxels, not points."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    cells = np.floor(points / side).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    _, voxel, counts = np.unique((cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2],
                                 return_inverse=True, return_counts=True)
    voxel = voxel.ravel()
    means = np.stack([np.bincount(voxel, points[:, axis]) / counts for axis in range(3)], axis=1)
    labels: np.ndarray = _clusters(means, counts, eps, min_points)[voxel]
    return labels


def _clusters(points: np.ndarray, weights: np.ndarray | None, eps: float, min_points: int) -> np.ndarray:
    """DBSCAN of `points` (non-empty), each weighing `weights` points (None: one each)."""
    size = len(points)
    pairs = cKDTree(points).query_pairs(eps, output_type="ndarray")
    first, second = pairs[:, 0].copy(), pairs[:, 1].copy()
    if weights is None:
        neighbours = 1 + np.bincount(first, minlength=size) + np.bincount(second, minlength=size)
    else:
        neighbours = weights + np.bincount(first, weights[second], size) + np.bincount(second, weights[first], size)
    core = neighbours >= min_points
    cluster = np.full(size, -1, dtype=np.int64)
    if core.any():
        first_core, second_core = core[first], core[second]
        both = first_core & second_core
        _, component = connected_components(_graph(first[both], second[both], size),
                                            directed=True, connection="weak")
        cluster[core] = component[core]
        for a, b, a_core, b_core in ((first, second, first_core, second_core), (second, first, second_core, first_core)):
            border = a_core & ~b_core  # border points: a non-core point next to a core point
            cluster[b[border]] = cluster[a[border]]
    return cluster


def _graph(first: np.ndarray, second: np.ndarray, size: int) -> csr_matrix:
    """The one-way edges first -> second as a CSR matrix, built directly (rows by a stable radix
    sort of 16-bit indices where they fit: a COO matrix's conversion sorted them at twice the
    cost). Its weakly connected components are the components of the undirected graph."""
    order = np.argsort(first.astype(np.uint16) if size <= 1 << 16 else first, kind="stable")
    indptr = np.zeros(size + 1, dtype=np.int64)
    np.cumsum(np.bincount(first, minlength=size), out=indptr[1:])
    return csr_matrix((np.ones(len(first)), second[order], indptr), shape=(size, size))
