"""Levelling a session's world: the smallest rotation that takes its up to +z, applied to its poses.

The core works in a z-up world (`ndfa.core.conventions`); `ndfa.trajectory.up` finds a session's
up, and these re-express the session in the levelled world (the world turns about its origin; the
cameras' motion relative to each other and the images are unchanged).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ndfa.core.conventions import world_up
from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import make_pose


def levelling_rotation(up_world: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) that takes `up_world` to +z (the core's up): about the axis
    up x z, by the angle between them. It leaves the heading alone as far as possible, so a world
    that is nearly z-up keeps its x and y. An up of exactly -z is turned over about x."""
    up = np.asarray(up_world, dtype=np.float64)
    norm = np.linalg.norm(up)
    if not (up.shape == (3,) and np.isfinite(norm) and norm > 0.0):
        raise TrajectoryError(f"up must be a non-zero finite 3-vector, got {up_world!r}")
    up = up / norm
    z = world_up()
    axis = np.cross(up, z)
    sin, cos = np.linalg.norm(axis), float(up @ z)
    if sin < 1e-12:
        return np.eye(3) if cos > 0.0 else np.diag([1.0, -1.0, -1.0])
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + cross + cross @ cross * ((1.0 - cos) / sin**2)


def level_poses(poses: np.ndarray | Sequence[np.ndarray], levelling: np.ndarray) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) re-expressed in the levelled world: levelling @ pose, with
    `levelling` the (3, 3) rotation from `levelling_rotation` (the world turns about its origin;
    the cameras' motion relative to each other is unchanged)."""
    return make_pose(np.asarray(levelling, dtype=np.float64), np.zeros(3)) @ np.asarray(poses, dtype=np.float64)


def level_frame(frame: Frame, levelling: np.ndarray) -> Frame:
    """A copy of `frame` (images shared, not copied) whose poses are in the levelled world. The true
    pose, when there is one, lives in the same world as the pose, so it is levelled too."""
    true = frame.pose_world_camera_true
    return dataclasses.replace(frame, pose_world_camera=level_poses(frame.pose_world_camera, levelling),
                               pose_world_camera_true=None if true is None else level_poses(true, levelling))
