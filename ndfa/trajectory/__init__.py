"""Poses for a recording: KISS-ICP odometry on depth (kiss.py, refined point-to-plane in refine.py),
RGB-D odometry on colour and depth with loop closure (rgbd.py, pose_graph.py), one session's
poses with the input checks and the frames it could not track (session.py),
trajectory errors (metrics.py), `rewrite_poses`, which
writes a copy of a recording with estimated poses (rewrite.py), and world up from the data with
the rotation that levels a session's world (level.py). TUM trajectory files are ndfa.io.tum_format."""

from ndfa.trajectory.kiss import DepthOdometry, OdometryConfig, depth_points, estimate_poses
from ndfa.trajectory.level import level_frame, level_poses, levelling_rotation
from ndfa.trajectory.metrics import AbsoluteError, RelativeError, absolute_trajectory_error, relative_pose_error
from ndfa.trajectory.rewrite import METHODS, PoseReport, rewrite_poses
from ndfa.trajectory.rgbd import RgbdOdometry, RgbdOdometryConfig
from ndfa.trajectory.session import SessionPoses, estimate_session_poses
from ndfa.trajectory.up import UpConfig, UpEstimate, estimate_up
from ndfa.trajectory.up_imu import up_from_accelerations

__all__ = [
    "AbsoluteError",
    "DepthOdometry",
    "METHODS",
    "OdometryConfig",
    "PoseReport",
    "RelativeError",
    "RgbdOdometry",
    "RgbdOdometryConfig",
    "SessionPoses",
    "UpConfig",
    "UpEstimate",
    "absolute_trajectory_error",
    "depth_points",
    "estimate_poses",
    "estimate_session_poses",
    "estimate_up",
    "level_frame",
    "level_poses",
    "levelling_rotation",
    "relative_pose_error",
    "rewrite_poses",
    "up_from_accelerations",
]
