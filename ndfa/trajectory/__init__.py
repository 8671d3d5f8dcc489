"""Poses for a recording: KISS-ICP odometry on depth (kiss.py, refined point-to-plane in refine.py),
RGB-D odometry on colour and depth with loop closure (rgbd.py, pose_graph.py),
trajectory errors (metrics.py), TUM trajectory files (tum_format.py), and `rewrite_poses`, which
writes a copy of a recording with estimated poses (rewrite.py)."""

from ndfa.trajectory.kiss import DepthOdometry, OdometryConfig, depth_points, estimate_poses
from ndfa.trajectory.metrics import AbsoluteError, RelativeError, absolute_trajectory_error, relative_pose_error
from ndfa.trajectory.rewrite import METHODS, PoseReport, rewrite_poses
from ndfa.trajectory.rgbd import RgbdOdometry, RgbdOdometryConfig, estimate_rgbd_poses
from ndfa.trajectory.tum_format import read_tum, write_tum

__all__ = [
    "AbsoluteError",
    "DepthOdometry",
    "METHODS",
    "OdometryConfig",
    "PoseReport",
    "RelativeError",
    "RgbdOdometry",
    "RgbdOdometryConfig",
    "absolute_trajectory_error",
    "depth_points",
    "estimate_poses",
    "estimate_rgbd_poses",
    "read_tum",
    "relative_pose_error",
    "rewrite_poses",
    "write_tum",
]
