"""DBSCAN on 3-D points (Ester et al. 1996), with a k-d tree: the clustering step of the segmentation."""

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
    pairs = cKDTree(points).query_pairs(eps, output_type="ndarray")
    first, second = pairs[:, 0].copy(), pairs[:, 1].copy()
    neighbours = 1 + np.bincount(first, minlength=len(points)) + np.bincount(second, minlength=len(points))
    core = neighbours >= min_points
    cluster = np.full(len(points), -1, dtype=np.int64)
    if core.any():
        first_core, second_core = core[first], core[second]
        both = first_core & second_core
        _, component = connected_components(_graph(first[both], second[both], len(points)),
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
