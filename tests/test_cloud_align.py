"""The global alignment's feature pairs (`ndfa.run.cloud_align.feature_correspondences`) are Open3D's,
and its RANSAC on them is Open3D's feature-based RANSAC; the k-d trees kept by content."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.core.geometry import make_pose, rotation_z
from ndfa.run.cloud_align import AlignConfig, _described, feature_correspondences, point_tree, voxel_thin


def _brute_mutual(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    distance = ((query[:, None, :] - reference[None, :, :]) ** 2).sum(axis=2)
    forward, backward = distance.argmin(axis=1), distance.argmin(axis=0)
    rows = np.nonzero(backward[forward] == np.arange(len(query)))[0]
    return np.stack([rows, forward[rows]], axis=1)


def _scene(rng: np.random.Generator) -> np.ndarray:
    """A floor, two walls and boxes in no pattern, thinned to 5 cm voxels."""
    def plane(origin, u, v, n):
        a, b = rng.uniform(0, 1, size=(2, n))
        return np.asarray(origin) + a[:, None] * np.asarray(u) + b[:, None] * np.asarray(v)

    parts = [plane([0, 0, 0], [3, 0, 0], [0, 2.5, 0], 6000), plane([0, 2.5, 0], [3, 0, 0], [0, 0, 1.5], 4000),
             plane([0, 0, 0], [0, 2.5, 0], [0, 0, 1.5], 3500)]
    for x, y, (sx, sy, sz) in ((0.6, 0.5, (0.4, 0.3, 0.5)), (1.9, 1.4, (0.7, 0.4, 0.6)), (2.3, 0.4, (0.3, 0.3, 0.9))):
        parts += [plane([x, y, 0], [sx, 0, 0], [0, 0, sz], 500), plane([x, y + sy, 0], [sx, 0, 0], [0, 0, sz], 500),
                  plane([x, y, 0], [0, sy, 0], [0, 0, sz], 400), plane([x + sx, y, 0], [0, sy, 0], [0, 0, sz], 400),
                  plane([x, y, sz], [sx, 0, 0], [0, sy, 0], 400)]
    return voxel_thin(np.concatenate(parts) + rng.normal(0, 0.003, size=(sum(map(len, parts)), 3)), 0.05)


def test_feature_correspondences_are_the_mutual_nearest_neighbours():
    rng = np.random.default_rng(0)
    query, reference = rng.normal(size=(300, 33)), rng.normal(size=(400, 33))
    reference[:150] = query[:150] + rng.normal(0, 0.05, size=(150, 33))  # most of these pair up
    pairs = feature_correspondences(query, reference)
    np.testing.assert_array_equal(pairs, _brute_mutual(query, reference))
    assert len(pairs) >= 150


def test_too_few_mutual_pairs_give_every_nearest():
    rng = np.random.default_rng(1)
    query, reference = rng.normal(size=(200, 33)), rng.normal(size=(250, 33))
    mutual = _brute_mutual(query, reference)
    assert 0 < len(mutual) < 0.9 * len(query)
    every = feature_correspondences(query, reference, share=0.9)  # as Open3D falls back
    distance = ((query[:, None, :] - reference[None, :, :]) ** 2).sum(axis=2)
    np.testing.assert_array_equal(every, np.stack([np.arange(len(query)), distance.argmin(axis=1)], axis=1))


def test_the_pairs_and_ransac_on_them_are_open3ds():
    o3d = pytest.importorskip("open3d")
    registration = o3d.pipelines.registration
    rng = np.random.default_rng(2)
    source = _scene(rng)
    turn = make_pose(rotation_z(np.radians(25.0)), np.array([0.4, -0.3, 0.0]))
    target = _scene(rng) @ turn[:3, :3].T + turn[:3, 3]
    config = AlignConfig()
    t, s = _described(target, config), _described(source, config)
    pairs = feature_correspondences(t.array, s.array, s.tree())
    np.testing.assert_array_equal(pairs, np.asarray(registration.correspondences_from_features(t.features, s.features,
                                                                                               True)))
    for share in (0.2, 0.5):  # a third of the rows pair mutually: either side of the fall-back to every nearest
        np.testing.assert_array_equal(
            feature_correspondences(t.array, s.array, share=share),
            np.asarray(registration.correspondences_from_features(t.features, s.features, True, share)))

    def ransac(call):
        o3d.utility.random.seed(0)
        return np.asarray(call(registration.TransformationEstimationPointToPoint(False), 3,
                               [registration.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                                registration.CorrespondenceCheckerBasedOnDistance(0.1)],
                               registration.RANSACConvergenceCriteria(5000, 0.999)).transformation)

    by_features = ransac(lambda *rest: registration.registration_ransac_based_on_feature_matching(
        t.cloud, s.cloud, t.features, s.features, True, 0.1, *rest))
    by_pairs = ransac(lambda *rest: registration.registration_ransac_based_on_correspondence(
        t.cloud, s.cloud, o3d.utility.Vector2iVector(pairs), 0.1, *rest))
    np.testing.assert_array_equal(by_pairs, by_features)


def test_point_trees_are_kept_by_content():
    rng = np.random.default_rng(3)
    cloud = rng.uniform(size=(500, 3))
    tree = point_tree(cloud)
    assert point_tree(cloud.copy()) is tree
    assert point_tree(cloud + 1.0) is not tree
    np.testing.assert_array_equal(tree.data, cloud)


def test_ties_between_identical_features_are_broken_as_open3d_breaks_them():
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(4)
    query, reference = rng.uniform(0, 10, size=(300, 33)), rng.uniform(0, 10, size=(400, 33))
    reference[:200] = query[:200] + rng.normal(0, 0.5, size=(200, 33))
    query[::37] = 0.0  # points with no neighbours have all-zero features: ties both ways
    reference[::29] = 0.0
    reference[5::50] = reference[7]  # and twins elsewhere

    def feature(rows: np.ndarray):
        described = o3d.pipelines.registration.Feature()
        described.data = np.ascontiguousarray(rows.T)
        return described

    expected = np.asarray(o3d.pipelines.registration.correspondences_from_features(feature(query), feature(reference),
                                                                                  True))
    np.testing.assert_array_equal(feature_correspondences(query, reference), expected)


def test_icp_coarse_stages_pair_the_target_thinned_to_their_pairing_distance(monkeypatch):
    import ndfa.run.cloud_align as cloud_align

    rng = np.random.default_rng(5)
    source, scene = _scene(rng), _scene(rng)  # two samplings of one scene
    truth = make_pose(rotation_z(np.radians(6.0)), np.array([0.12, -0.08, 0.0]))  # target -> source
    target = (scene - truth[:3, 3]) @ truth[:3, :3]
    queried: list[int] = []
    icp_yaw = cloud_align.icp_yaw

    def counting(source_cloud, target_cloud, *args, **kwargs):
        queried.append(len(target_cloud))
        return icp_yaw(source_cloud, target_cloud, *args, **kwargs)

    monkeypatch.setattr(cloud_align, "icp_yaw", counting)
    config = AlignConfig()
    found = {coarse: cloud_align.icp_coarse_to_fine(source, target, np.eye(4), AlignConfig(icp_coarse_voxels=coarse))
             for coarse in (True, False)}
    assert queried[3:] == [len(target)] * 3
    assert queried[0] < queried[1] < queried[2] == len(target)  # 20 cm, 10 cm voxels, then all
    for transform in found.values():
        error = np.linalg.norm(cloud_align.apply_transform(transform, target) - cloud_align.apply_transform(truth, target),
                               axis=1)
        assert error.max() < 0.01
    # the thinned clouds are `voxel_thin`'s, kept by content; the cloud itself at its own voxels
    assert cloud_align.coarse_cloud(target, config.voxel_m, config) is target
    coarse = cloud_align.coarse_cloud(target, 0.2, config)
    np.testing.assert_array_equal(coarse, voxel_thin(target, 0.2))
    assert cloud_align.coarse_cloud(target.copy(), 0.2, config) is coarse
