"""A recorded world frame that is not z-up: the simulated (level) world turned about a horizontal
axis.

Why: a real sensor's world frame is often its first camera frame, or an odometry's, whose up is
wherever the camera pointed. The core assumes z up (`ndfa.core.conventions`), so a recording has
to be levelled first; a tilted synthetic world is the test case for that levelling, with the
true tilt known.
"""

from __future__ import annotations

import numpy as np

from ndfa.core.geometry import axis_angle_to_matrix, make_pose


def tilt_pose(degrees: float, rng: np.random.Generator) -> np.ndarray:
    """pose_world_level (4, 4): a rotation by exactly `degrees` about a horizontal axis at a random
    azimuth (a mix of roll and pitch, no yaw), so that the level frame's up, z, lies `degrees`
    away from the tilted world's z. Points and poses map as p_world = pose_world_level @ p_level.
    The identity for 0 degrees."""
    if degrees == 0.0:
        return np.eye(4)
    azimuth = rng.uniform(-np.pi, np.pi)
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    return make_pose(axis_angle_to_matrix(np.deg2rad(degrees) * axis), np.zeros(3))
