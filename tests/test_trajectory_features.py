"""Sparse feature initialisation of the RGB-D odometry (ndfa.trajectory.features), on a textured
synthetic room: a camera step well beyond dense odometry's basin."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import ndfa.trajectory.features as features_module
from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import axis_angle_to_matrix, kabsch, make_pose
from ndfa.io.ingest.synthetic import render_objects
from ndfa.sim.noise import DepthNoise
from ndfa.sim.presets import make_config
from ndfa.sim.render import SceneRenderer
from ndfa.sim.texture import room_textures
from ndfa.sim.trajectory import camera_poses
from ndfa.sim.world import build_world, procedural_models
from ndfa.trajectory.features import (
    RANSAC_BATCH,
    FeatureConfig,
    _hypotheses_needed,
    _ransac,
    _smooth_depth_mask,
    detect_features,
    estimate_motion,
    no_features,
)
from ndfa.trajectory.rgbd import RgbdOdometry, RgbdOdometryConfig

# 9 cm forward and sideways and 5 degrees of yaw and pitch in one frame: the paper scene's camera
# moves 8 cm and 3 degrees per frame (6 at most).
STEP = make_pose(axis_angle_to_matrix(np.radians([3.0, 4.0, 0.5])), np.array([0.06, -0.02, 0.065]))


@pytest.fixture(scope="module")
def pair() -> tuple[Frame, Frame]:
    """Two frames of a textured room, the second STEP away from the first (camera frame)."""
    config = make_config("sample", 1)
    config = dataclasses.replace(config, depth_noise=DepthNoise.off())
    world = build_world(config, procedural_models(config))
    renderer = SceneRenderer(render_objects(world, "source", room_textures(world.room, world.tables, np.random.default_rng(0))))
    camera = config.camera  # 320x240
    first = camera_poses(world.tables, config.trajectory, np.random.default_rng(0))[1]
    frames = []
    for index, pose in enumerate((first, first @ STEP)):
        view = renderer.render(camera, pose)
        depth = np.where(view.hit, view.depth, 0.0).astype(np.float32)
        frames.append(Frame(index=index, timestamp=index / 30.0, rgb=view.rgb, depth=depth, K=camera.K,
                            pose_world_camera=np.eye(4), pose_world_camera_true=pose))
    return frames[0], frames[1]


def _errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    difference = np.linalg.inv(truth) @ estimate
    angle = np.degrees(np.arccos(np.clip((np.trace(difference[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(np.linalg.norm(difference[:3, 3])), float(angle)


def test_features_recover_a_large_step(pair):
    first, second = pair
    features = [detect_features(f.rgb.mean(axis=2).astype(np.uint8), f.depth, f.K) for f in pair]
    assert min(len(f) for f in features) >= 50
    motion = estimate_motion(features[1], features[0])  # T_first_second
    assert motion is not None and motion.inliers >= 20
    distance, angle = _errors(motion.target_from_source, STEP)
    assert distance < 0.02 and angle < 1.0


def test_the_odometry_tracks_the_step_from_features_and_not_without(pair):
    truth = STEP
    results = {}
    for name, features in (("features", FeatureConfig()), ("prediction", None)):
        odometry = RgbdOdometry(RgbdOdometryConfig(features=features, loop_closure=False))
        poses = [odometry.update(frame) for frame in pair]
        results[name] = _errors(np.linalg.inv(poses[0]) @ poses[1], truth)
        if features is not None:
            assert odometry.feature_frames == 1
    assert results["features"][0] < 0.01 and results["features"][1] < 0.5
    # From the constant-velocity guess (no motion yet) the same step is out of dense odometry's reach.
    assert results["prediction"][0] > 0.03


def test_no_match_without_texture_or_overlap(pair):
    first, second = pair
    flat = np.full_like(first.rgb[..., 0], 128)
    assert len(detect_features(flat, first.depth, first.K)) == 0
    assert estimate_motion(no_features(first.K), detect_features(second.rgb.mean(axis=2).astype(np.uint8), second.depth, second.K)) is None


def _matches_with_outliers(inlier_share: float, count: int = 200, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """3D matches (moving, fixed, tolerance) of which `inlier_share` follow STEP, the rest random."""
    rng = np.random.default_rng(seed)
    moving = rng.uniform([-1.0, -1.0, 1.0], [1.0, 1.0, 4.0], (count, 3))
    fixed = moving @ STEP[:3, :3].T + STEP[:3, 3]
    outliers = rng.random(count) >= inlier_share
    fixed[outliers] = rng.uniform([-1.0, -1.0, 1.0], [1.0, 1.0, 4.0], (int(outliers.sum()), 3))
    return moving, fixed, np.full(count, 0.01)


def _best_of_all(moving: np.ndarray, fixed: np.ndarray, tolerance: np.ndarray, config: FeatureConfig,
                 hypotheses: int) -> np.ndarray:
    """The inliers of the first best of the first `hypotheses` samples RANSAC draws, scored one by one."""
    samples = np.random.default_rng(config.seed).integers(0, len(moving), (config.ransac_hypotheses, 3))[:hypotheses]
    best, best_count = None, -1
    for sample in samples:
        transform, _ = kabsch(moving[sample], fixed[sample])
        inliers = np.linalg.norm(moving @ transform[:3, :3].T + transform[:3, 3] - fixed, axis=1) < tolerance
        if inliers.sum() > best_count:
            best, best_count = inliers, int(inliers.sum())
    assert best is not None
    return best


def test_ransac_without_a_confidence_scores_every_hypothesis():
    config = FeatureConfig(ransac_confidence=0.0)
    for share in (0.3, 0.9):
        moving, fixed, tolerance = _matches_with_outliers(share)
        assert np.array_equal(_ransac(moving, fixed, tolerance, config),
                              _best_of_all(moving, fixed, tolerance, config, config.ransac_hypotheses))


def test_ransac_stops_after_a_batch_when_most_matches_agree_and_not_when_few_do(monkeypatch):
    config = FeatureConfig(ransac_confidence=0.999)
    scored = []
    original = features_module._kabsch_batch
    monkeypatch.setattr(features_module, "_kabsch_batch", lambda m, f: scored.append(len(m)) or original(m, f))
    # 90 % inliers: a batch of RANSAC_BATCH samples all but surely holds an all-inlier one.
    moving, fixed, tolerance = _matches_with_outliers(0.9)
    inliers = _ransac(moving, fixed, tolerance, config)
    assert scored == [RANSAC_BATCH]
    assert np.array_equal(inliers, _best_of_all(moving, fixed, tolerance, config, RANSAC_BATCH))
    assert inliers.sum() >= 0.85 * len(moving)
    # 25 % inliers: 0.999 needs more samples than are drawn, so all of them are scored, as without a confidence.
    scored.clear()
    moving, fixed, tolerance = _matches_with_outliers(0.25)
    inliers = _ransac(moving, fixed, tolerance, config)
    assert sum(scored) == config.ransac_hypotheses
    assert np.array_equal(inliers, _ransac(moving, fixed, tolerance, FeatureConfig(ransac_confidence=0.0)))


def test_hypotheses_needed():
    assert _hypotheses_needed(0.0, 0.999) == math.inf
    assert _hypotheses_needed(1.0, 0.999) == 1.0
    # log(0.001) / log(1 - 0.5^3) = 51.7: at half inliers two batches do not reach it, two more do.
    assert 51.0 < _hypotheses_needed(0.5, 0.999) < 52.0
    with pytest.raises(TrajectoryError):
        FeatureConfig(ransac_confidence=1.0)


def test_the_depth_mask_keeps_pixels_whose_window_is_valid_and_smooth():
    rng = np.random.default_rng(3)
    depth = rng.uniform(1.0, 1.02, (40, 50)).astype(np.float32)
    depth[5:8, 10:13] = np.nan  # a hole
    depth[20, 30] = 0.0  # no depth
    depth[30:, :] = 2.0  # a step: a silhouette along row 30
    depth[10, 40] = 9.0  # beyond max_depth_m
    config = FeatureConfig()
    mask = _smooth_depth_mask(depth, config)
    r = config.edge_radius_px
    valid = np.isfinite(depth) & (depth > 0) & (depth <= config.max_depth_m)
    expected = np.zeros_like(mask)
    for row in range(depth.shape[0]):
        for col in range(depth.shape[1]):
            window = (slice(max(0, row - r), row + r + 1), slice(max(0, col - r), col + r + 1))
            if valid[window].all():
                low, high = depth[window].min(), depth[window].max()
                expected[row, col] = 255 * bool(high - low < np.float32(config.edge_fraction) * low)
    assert mask.dtype == np.uint8 and np.array_equal(mask, expected)
    assert not mask[6, 11] and not mask[29, 25] and not mask[10, 40] and mask[15, 25]
