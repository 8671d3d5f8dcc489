"""The odometry's cheaper paths (ndfa.trajectory.rgbd): the keyframe rule's overlap over the pixels
with depth, and frames registered from the constant-velocity prediction alone, features only where
that registration is doubtful. On the analytic checkered room of test_trajectory_rgbd."""

from __future__ import annotations

import numpy as np

from ndfa.core.frame import Frame
from ndfa.core.geometry import look_at
from ndfa.trajectory import rgbd_view
from ndfa.trajectory.metrics import absolute_trajectory_error
from ndfa.trajectory.rgbd import RgbdOdometry, RgbdOdometryConfig
from tests.test_trajectory_rgbd import K, clip, render


def run(frames: list[Frame], config: RgbdOdometryConfig) -> tuple[RgbdOdometry, float]:
    odometry = RgbdOdometry(config)
    for frame in frames:
        odometry.update(frame)
    poses = odometry.finish()
    return odometry, absolute_trajectory_error(poses, [frame.pose_world_camera for frame in frames]).rmse_m


def test_the_keyframe_overlap_counts_only_the_pixels_with_depth():
    # Depth on a third of the image (a sensor that sees only the near middle): Open3D's fitness
    # counts inliers over all pixels, so it stays under 1/3 and under the 0.4 keyframe threshold
    # however well the frames overlap; over the pixels with depth it is near 1.
    frames = clip(10, step_m=0.01, turn_deg=0.3)
    for frame in frames:
        frame.depth[:, :53] = 0.0
        frame.depth[:, 107:] = 0.0
    every, _ = run(frames, RgbdOdometryConfig(keyframe_overlap_of_depth=False, prediction_first=False))
    of_depth, _ = run(frames, RgbdOdometryConfig(keyframe_overlap_of_depth=True, prediction_first=False))
    assert len(every.keyframes) == len(frames)
    # 3 or 4 of the 10 (8 runs on 2026-12-07): Open3D's odometry is not repeatable to the bit, and
    # the degenerate strip below drifts, so where the overlap falls under 0.4 moves a frame or so.
    assert len(of_depth.keyframes) <= len(frames) // 2
    # (Not the accuracy: this strip of depth leaves the depth term degenerate at 160 x 120, and the
    # intensity term alone drifts 6-15 cm here either way; the sessions: docs/odometry.md.)


def corner_walk(frames: int, sidestep_at: int | None = None) -> list[Frame]:
    """A camera walking 1 cm per frame and tilting up slowly while it looks into a corner of the
    room (three planes: the depth term sees every direction, so the frames are registered by
    hybrid); with `sidestep_at`, a 6 cm step sideways at that frame that no constant velocity foresees."""
    out = []
    for index in range(frames):
        side = 0.06 if sidestep_at is not None and index >= sidestep_at else 0.0
        pose = look_at(np.array([-0.5 + 0.01 * index, -0.3 + side, 1.2]), np.array([2.0, 1.5, 0.4 + 0.01 * index]))
        depth, rgb = render(pose)
        out.append(Frame(index=index, timestamp=index / 30.0, rgb=rgb, depth=depth, K=K, pose_world_camera=pose))
    return out


def test_a_steady_walk_is_registered_from_the_prediction_without_features(monkeypatch):
    made = []
    detect = rgbd_view.detect_features
    monkeypatch.setattr(rgbd_view, "detect_features", lambda *args: made.append(1) or detect(*args))
    frames = corner_walk(12)
    odometry, error = run(frames, RgbdOdometryConfig(prediction_first=True, prediction_first_in_a_row=100))
    assert error < 0.03
    # From the third frame on (the first two give the velocity) the prediction's registration holds.
    assert odometry.prediction_first_frames >= 7
    # Features made only for the keyframes (the loop search and later doubtful frames match
    # against them) and the frames before the velocity was known.
    assert len(made) <= len(frames) - odometry.prediction_first_frames
    without, error_without = run(frames, RgbdOdometryConfig(prediction_first=False))
    assert without.prediction_first_frames == 0 and error < error_without + 0.01


def test_by_default_no_two_frames_in_a_row_are_registered_from_the_prediction_alone():
    # The kitchen drifted through a run of them, each near a prediction that carried the last one's
    # error (docs/odometry.md, "Prediction first"): the frame after one is registered from features.
    odometry = RgbdOdometry(RgbdOdometryConfig(prediction_first=True))
    alone = []
    for frame in corner_walk(12):
        before = odometry.prediction_first_frames
        odometry.update(frame)
        alone.append(odometry.prediction_first_frames > before)
    assert sum(alone) >= 3
    assert not any(a and b for a, b in zip(alone, alone[1:]))


def test_a_sidestep_off_the_prediction_is_not_taken_from_the_prediction_alone():
    frames = corner_walk(10, sidestep_at=6)
    odometry = RgbdOdometry(RgbdOdometryConfig(prediction_first=True, prediction_first_in_a_row=100))
    first = []
    for frame in frames:
        odometry.update(frame)
        first.append(odometry.prediction_first_frames)
    assert first[5] > first[3]  # before the sidestep: the prediction
    assert first[6] == first[5]  # the sidestep lands far from it: doubtful, registered the other way
    truth = [frame.pose_world_camera for frame in frames]
    assert absolute_trajectory_error(odometry.finish(), truth).rmse_m < 0.03
