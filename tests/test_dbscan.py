"""DBSCAN (`ndfa.perception.dbscan`): the exact clustering on small cases, and the voxel grid's
(`voxel_dbscan`, the segmentation's default) against the exact one on a synthetic table top."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.perception.dbscan import dbscan, voxel_dbscan
from ndfa.perception.segmentation_config import SegmentationConfig

EPS, MIN_POINTS = SegmentationConfig().dbscan_eps_m, SegmentationConfig().dbscan_min_points
SIDE = SegmentationConfig().dbscan_voxel_m


def _mug_front(center_xy, radius=0.04, height=0.10, spacing=0.005):
    """The half of a mug's wall a camera on the -y side sees, as points (x, y, z above the table),
    about as far apart as the segmentation's samples of a mug 1-2 m away (stride 2)."""
    angles = np.arange(-np.pi / 2, np.pi / 2, spacing / radius)
    heights = np.arange(0.012, height, spacing)
    a, z = np.meshgrid(angles, heights)
    return np.stack([center_xy[0] + radius * np.sin(a), center_xy[1] - radius * np.cos(a), z], axis=-1).reshape(-1, 3)


def _table_top(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Eight mug fronts on a 4 x 2 grid (walls 4-12 cm apart, at random), 2 mm of depth noise, and 60
    stray points in the volume above the table; and each point's object (-1: stray)."""
    rng = np.random.default_rng(seed)
    parts, owner = [], []
    for index in range(8):
        center = (index % 4 * 0.16 + rng.uniform(0, 0.03), index // 4 * 0.2 + rng.uniform(0, 0.02))
        front = _mug_front(center, radius=rng.uniform(0.035, 0.045))
        parts.append(front + rng.normal(0, 0.002, front.shape))
        owner.append(np.full(len(front), index))
    parts.append(rng.uniform((-0.1, -0.1, 0.0), (0.6, 0.4, 0.12), (60, 3)))
    owner.append(np.full(60, -1))
    points, owners = np.concatenate(parts), np.concatenate(owner)
    order = rng.permutation(len(points))
    return points[order], owners[order]


def _matches(reference: np.ndarray, labels: np.ndarray, min_points: int = 30) -> list[float]:
    """For each cluster of `reference` with `min_points` or more, the best IoU of a cluster of `labels`."""
    best = []
    for cluster in np.unique(reference[reference >= 0]):
        members = reference == cluster
        if members.sum() < min_points:
            continue
        overlaps = [np.sum(members & (labels == other)) / np.sum(members | (labels == other))
                    for other in np.unique(labels[members & (labels >= 0)])]
        best.append(max(overlaps, default=0.0))
    return best


def test_exact_dbscan_links_chains_and_leaves_strays_as_noise():
    chain = np.stack([np.arange(10) * 0.02, np.zeros(10), np.zeros(10)], axis=1)  # 2 cm steps
    far = chain + (1.0, 0.0, 0.0)
    stray = np.array([[0.5, 0.5, 0.5]])
    labels = dbscan(np.concatenate([chain, far, stray]), EPS, 3)
    assert len(set(labels[:10])) == 1 and len(set(labels[10:20])) == 1
    assert labels[0] != labels[10] and labels[-1] == -1
    assert dbscan(np.zeros((0, 3)), EPS, MIN_POINTS).shape == (0,)
    assert voxel_dbscan(np.zeros((0, 3)), EPS, MIN_POINTS, SIDE).shape == (0,)


@pytest.mark.parametrize("seed", [0, 4, 8, 10])
def test_voxel_dbscan_clusters_a_table_top_as_exact_dbscan_does(seed):
    """Tolerance: every exact cluster of >= 30 points has a voxel cluster with IoU >= 0.99, the two
    find as many such clusters, and each is one mug."""
    points, owners = _table_top(seed)
    exact = dbscan(points, EPS, MIN_POINTS)
    voxel = voxel_dbscan(points, EPS, MIN_POINTS, SIDE)
    assert len(_matches(exact, voxel)) == len(_matches(voxel, exact)) == 8
    assert min(_matches(exact, voxel)) >= 0.99
    assert min(_matches(voxel, exact)) >= 0.99
    for cluster in np.unique(voxel[voxel >= 0]):
        mugs = np.unique(owners[(voxel == cluster) & (owners >= 0)])
        assert len(mugs) <= 1


def test_voxel_dbscan_keeps_apart_what_is_farther_than_eps_and_two_voxels():
    """Two points are linked only if their voxels' means lie within eps: at most eps + 2 sqrt(3)
    voxels apart. Mugs whose walls are 1.5 cm apart are one cluster either way; 6.5 cm apart, two."""
    for gap, clusters in ((0.015, 1), (EPS + 2 * np.sqrt(3) * SIDE + 0.003, 2)):
        points = np.concatenate([_mug_front((0.0, 0.0)), _mug_front((0.08 + gap, 0.0))])
        for labels in (dbscan(points, EPS, MIN_POINTS), voxel_dbscan(points, EPS, MIN_POINTS, SIDE)):
            assert len(np.unique(labels[labels >= 0])) == clusters
            assert (labels >= 0).all()


def test_the_voxel_side_is_checked():
    with pytest.raises(ValueError):
        SegmentationConfig(dbscan_voxel_m=0.03)
    with pytest.raises(ValueError):
        SegmentationConfig(dbscan_voxel_m=-0.01)
    assert SegmentationConfig(dbscan_voxel_m=0.0).dbscan_voxel_m == 0.0
