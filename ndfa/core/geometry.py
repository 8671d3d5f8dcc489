"""Small rigid-body helpers shared by the simulator, the importers and the method.

Conventions: poses are 4x4 homogeneous matrices `T_a_b` that map points from frame b to frame a
(so `pose_world_camera` maps camera coordinates to world coordinates). Cameras use the OpenCV
convention: x right, y down, z forward (the optical axis). The world is z-up, in metres.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def make_pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 pose from a 3x3 rotation and a 3-vector translation."""
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    return pose


def invert_pose(pose: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose, without a general matrix inverse."""
    rotation, translation = pose[:3, :3], pose[:3, 3]
    return make_pose(rotation.T, -rotation.T @ translation)


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 pose to points of shape (N, 3)."""
    moved: np.ndarray = points @ pose[:3, :3].T + pose[:3, 3]
    return moved


def backproject(K: np.ndarray, rows: np.ndarray, cols: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Camera-frame points (N, 3) at depth `z` of pixel coordinates (rows, cols) (OpenCV pinhole
    model, pixel centres at integers; sub-pixel coordinates allowed)."""
    z = np.asarray(z, dtype=np.float64)
    return np.stack([(cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z, z], axis=1)


def rotation_z(angle: float) -> np.ndarray:
    """Rotation about the z axis by `angle` radians."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def axis_angle_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vector (axis * angle, radians) to a 3x3 rotation matrix."""
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.eye(3)
    k = np.asarray(rotvec, dtype=float) / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation: np.ndarray = np.eye(3) + np.sin(angle) * kx + (1.0 - np.cos(angle)) * (kx @ kx)
    return rotation


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """Camera-to-world pose of an OpenCV camera at `eye` whose optical axis points at `target`."""
    forward = np.asarray(target, dtype=float) - np.asarray(eye, dtype=float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    if np.linalg.norm(right) < 1e-9:  # looking straight up or down: any horizontal right works
        right = np.cross(forward, np.array([1.0, 0.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return make_pose(np.stack([right, down, forward], axis=1), eye)


def quaternion_xyzw_from_matrix(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a 3x3 rotation matrix, w >= 0."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    unit: np.ndarray = np.asarray(q)
    unit /= np.linalg.norm(unit)
    return -unit if unit[3] < 0 else unit


def matrix_from_quaternion_xyzw(q: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix of a quaternion (x, y, z, w); the quaternion need not be normalised."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def kabsch(moving: np.ndarray, fixed: np.ndarray, *, normalised: bool = False,
           with_scale: bool = False) -> tuple[np.ndarray, Any]:
    """The (4, 4) transform T and scale s minimising sum_i |s R moving_i + t - fixed_i|^2 over
    corresponding points (N, 3), N >= 3 and not all on one line: Kabsch's SVD fit, with Umeyama's
    scale (PAMI 1991) when `with_scale` (s is applied to T's rotation block; 1.0 without).
    Stacks of point sets (..., N, 3) give stacks of transforms (..., 4, 4) and scales (...).

    The best orthogonal matrix may be a reflection, which is not a motion: then the axis of the
    smallest singular value is flipped. `normalised` divides the cross-covariance by N, as Umeyama
    writes it; the fit is the same, the last bits of it are not, so each caller keeps its form.
    """
    moving, fixed = np.asarray(moving, dtype=np.float64), np.asarray(fixed, dtype=np.float64)
    moving_mean, fixed_mean = moving.mean(axis=-2), fixed.mean(axis=-2)
    moving_centred, fixed_centred = moving - moving_mean[..., None, :], fixed - fixed_mean[..., None, :]
    covariance = np.swapaxes(fixed_centred, -1, -2) @ moving_centred
    if normalised:
        covariance = covariance / moving.shape[-2]
    u, singular, vt = np.linalg.svd(covariance)
    reflection = np.ones(singular.shape)  # the diagonal of the reflection matrix
    reflection[..., 2] = np.where(np.linalg.det(u) * np.linalg.det(vt) < 0, -1.0, 1.0)
    rotation = (u * reflection[..., None, :]) @ vt
    scale = np.ones(singular.shape[:-1])
    if with_scale:
        spread = np.sum(moving_centred**2, axis=-1)
        variance = np.mean(spread, axis=-1) if normalised else np.sum(spread, axis=-1)
        scale = np.sum(singular * reflection, axis=-1) / variance
    transform = np.zeros(moving.shape[:-2] + (4, 4))
    transform[..., 3, 3] = 1.0
    transform[..., :3, :3] = scale[..., None, None] * rotation
    transform[..., :3, 3] = fixed_mean - scale[..., None] * (rotation @ moving_mean[..., None])[..., 0]
    return transform, scale if scale.ndim else float(scale)  # a float for one point set, an array for a stack


def project(K: np.ndarray, points_camera: np.ndarray) -> np.ndarray:
    """Pixel coordinates (N, 2), (column u, row v), of camera-frame points (N, 3): the OpenCV
    pinhole model, pixel centres at integers, the inverse of `backproject`. Points at z <= 0 get
    meaningless (or infinite) coordinates without a warning: callers keep those in front, and
    round or bound the coordinates as they need."""
    points_camera = np.asarray(points_camera)
    z = points_camera[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * points_camera[:, 0] / z + K[0, 2]
        v = K[1, 1] * points_camera[:, 1] / z + K[1, 2]
    return np.stack([u, v], axis=1)


def interpolate_pose(pose_a: np.ndarray, pose_b: np.ndarray, weight: float) -> np.ndarray:
    """The pose `weight` (0..1) of the way from `pose_a` to `pose_b`: translation linearly, rotation
    by slerp the shorter way round (as tf2 and TUM's tools interpolate)."""
    from scipy.spatial.transform import Rotation, Slerp  # scipy only where poses are interpolated

    rotations = Rotation.from_matrix(np.stack([pose_a[:3, :3], pose_b[:3, :3]]))
    rotation = Slerp([0.0, 1.0], rotations)([weight]).as_matrix()[0]
    translation = (1 - weight) * pose_a[:3, 3] + weight * pose_b[:3, 3]
    return make_pose(rotation, translation)
