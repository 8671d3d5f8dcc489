"""The constant-velocity motion model of the RGB-D odometry (rgbd.py): the last frame's motion,
repeated to predict the next frame's pose."""

from __future__ import annotations

import numpy as np


def motion_between(before: np.ndarray, after: np.ndarray, in_world: bool) -> np.ndarray:
    """The motion from pose `before` to `after`: the turn in the camera's frame, and the shift in
    the world's (`in_world`) or the camera's frame; `predict` applies it again."""
    if not in_world:
        return np.linalg.inv(before) @ after
    motion = np.eye(4)
    motion[:3, :3] = before[:3, :3].T @ after[:3, :3]
    motion[:3, 3] = after[:3, 3] - before[:3, 3]
    return motion


def predict(last: np.ndarray, motion: np.ndarray, in_world: bool) -> np.ndarray:
    """The pose after `last` by the same `motion` (`motion_between`) again."""
    if not in_world:
        return last @ motion
    # Back onto the rotations: the turn was taken with a transpose for the inverse, so a registration's
    # slightly non-orthonormal rotation (float32 inside Open3D) would otherwise grow by its own
    # error at every predicted frame (a 160 x 120 session's poses overflowed after 15 of them).
    left, _, right = np.linalg.svd(last[:3, :3] @ motion[:3, :3])
    pose = np.eye(4)
    pose[:3, :3] = left @ np.diag([1.0, 1.0, np.linalg.det(left @ right)]) @ right
    pose[:3, 3] = last[:3, 3] + motion[:3, 3]
    return pose
