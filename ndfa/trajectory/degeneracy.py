"""When registration by depth alone is ambiguous, and when colour can help: the checks behind the
RGB-D odometry's choice of residuals (`ndfa.trajectory.rgbd`)."""

from __future__ import annotations

import numpy as np


def plane_information(depth: np.ndarray, K: np.ndarray, step: int = 2) -> np.ndarray:
    """The 6x6 information matrix (rotation, translation) of point-to-plane registration of this
    depth image to itself: sum over pixels of J^T J with J = (p x n, n), normals n from the
    neighbouring pixels' points. Why not Open3D's `compute_odometry_information_matrix`: it is the
    point-to-point matrix, which stays well conditioned on a wall and a floor (it counts the slide
    along them as constrained); the plane term, which is what the depth residuals measure, does not."""
    z = depth[::step, ::step].astype(np.float64)
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]] * step
    points = np.stack([(cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    right, down = points[:-1, 1:] - points[:-1, :-1], points[1:, :-1] - points[:-1, :-1]
    normals = np.cross(right, down)
    length = np.linalg.norm(normals, axis=-1)
    p = points[:-1, :-1]
    # Both neighbours valid and on the same surface (a depth jump is no plane).
    same = (np.abs(right[..., 2]) < 0.05 * p[..., 2]) & (np.abs(down[..., 2]) < 0.05 * p[..., 2])
    keep = np.isfinite(length) & (length > 0) & same & (p[..., 2] > 0)
    if not keep.any():
        return np.zeros((6, 6))
    n = normals[keep] / length[keep, None]
    jacobian = np.hstack([np.cross(p[keep], n), n])
    return jacobian.T @ jacobian


def depth_degeneracy(information: np.ndarray, depth_m: float) -> float:
    """Smallest over largest eigenvalue of a depth term's 6x6 information matrix, with rotations
    expressed as arc length at `depth_m` (so a direction is compared in metres either way): near 0
    when some motion leaves the depth residuals unchanged (a single plane, two planes' slide along
    their intersection), near 1 for a scene that constrains every direction alike."""
    scale = np.diag([1.0 / depth_m] * 3 + [1.0] * 3)
    eigenvalues = np.linalg.eigvalsh(scale @ information @ scale)
    return float(eigenvalues[0] / eigenvalues[-1]) if eigenvalues[-1] > 0.0 else 0.0


def textured_fraction(rgb: np.ndarray, valid: np.ndarray, threshold: float) -> float:
    """Fraction of the valid pixels whose intensity (0-1) changes by more than `threshold` to the
    next pixel right or down."""
    gray = rgb.astype(np.float32).mean(axis=2) / 255.0
    gradient = np.zeros_like(gray)
    gradient[:, :-1] = np.abs(np.diff(gray, axis=1))
    gradient[:-1] = np.maximum(gradient[:-1], np.abs(np.diff(gray, axis=0)))
    return float((gradient[valid] > threshold).mean()) if valid.any() else 0.0
