"""Instance masks -> cleaned partial point clouds."""

import numpy as np
import pytest

from ndfa.io.recording import Frame
from ndfa.perception.observations import ObservationConfig, extract_observations, largest_cluster
from ndfa.sim.camera import PinholeCamera


def _frame(depth, instances):
    camera = PinholeCamera()
    return Frame(index=3, timestamp=0.0, rgb=None, depth=depth, K=camera.K, pose_world_camera=np.eye(4),
                 instances=instances)


def test_each_instance_becomes_one_cleaned_cloud_or_a_reasoned_skip():
    depth = np.full((480, 640), 2.0, dtype=np.float32)
    instances = np.zeros((480, 640), dtype=np.uint16)
    instances[200:240, 300:340] = 1                     # 1600 px at 1.0 m
    depth[200:240, 300:340] = 1.0
    depth[200:202, 300:340] = 3.5                       # a mask edge that hit the background
    instances[10:15, 10:15] = 2                         # 25 px: too small
    instances[300:340, 100:140] = 3                     # no valid depth
    depth[300:340, 100:140] = 0.0
    observations, skipped = extract_observations(_frame(depth, instances), ObservationConfig(max_points=5000))
    assert [o.instance_id for o in observations] == [1]
    cloud = observations[0].points_camera
    assert len(cloud) == 38 * 40                        # the background rows were cut off by the clustering
    np.testing.assert_allclose(cloud[:, 2], 1.0)
    assert observations[0].n_pixels == 1600 and not observations[0].touches_border
    reasons = {s.instance_id: s.reason for s in skipped}
    assert "min_pixels" in reasons[2] and reasons[3] == "no depth in range"


def test_points_back_project_through_the_intrinsics():
    depth = np.zeros((480, 640), dtype=np.float32)
    instances = np.zeros((480, 640), dtype=np.uint16)
    camera = PinholeCamera()
    cx, cy = int(camera.K[0, 2]), int(camera.K[1, 2])
    instances[cy - 10:cy + 10, cx - 10:cx + 10] = 5
    depth[cy - 10:cy + 10, cx - 10:cx + 10] = 1.5
    (observation,), _ = extract_observations(_frame(depth, instances))
    uv, z = camera.project(observation.points_camera)
    assert np.all(np.abs(uv[:, 0] - np.round(uv[:, 0])) < 1e-6) and np.allclose(z, 1.5)
    assert uv[:, 0].min() >= cx - 10 and uv[:, 0].max() <= cx + 9


def test_frames_without_masks_give_nothing():
    depth = np.ones((480, 640), dtype=np.float32)
    assert extract_observations(_frame(depth, None)) == ([], [])


def test_largest_cluster_is_the_biggest_connected_group():
    rng = np.random.default_rng(0)
    a = rng.normal(scale=0.005, size=(300, 3))
    b = rng.normal(scale=0.005, size=(100, 3)) + [0, 0, 1.0]
    chosen = largest_cluster(np.vstack([a, b]), voxel_m=0.02)
    assert set(chosen) == set(range(300))


@pytest.mark.parametrize("seed", range(20))
def test_component_labels_are_the_connected_components(seed):
    """`_component_labels` against scipy's connected components on random sparse graphs: the same
    partition, each component labelled by its smallest node."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from ndfa.perception.observations import _component_labels

    rng = np.random.default_rng(seed)
    count = int(rng.integers(1, 300))
    edges = rng.integers(0, count, size=(2, int(rng.integers(0, 2 * count))))
    labels = _component_labels(count, edges[0], edges[1])
    graph = coo_matrix((np.ones(edges.shape[1]), (edges[0], edges[1])), shape=(count, count))
    _, expected = connected_components(graph, directed=False)
    for component in np.unique(expected):
        members = np.flatnonzero(expected == component)
        assert np.all(labels[members] == members.min())
