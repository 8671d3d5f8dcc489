"""When registration by depth alone is ambiguous, and when colour can help: the checks behind the
RGB-D odometry's choice of residuals (`ndfa.trajectory.rgbd`)."""

from __future__ import annotations

import numpy as np


def plane_information(depth: np.ndarray, K: np.ndarray, step: int = 2, baseline: int = 1) -> np.ndarray:
    """The 6x6 information matrix (rotation, translation) of point-to-plane registration of this
    depth image to itself: sum over pixels of J^T J with J = (p x n, n), normals n from the
    neighbouring pixels' points. Why not Open3D's `compute_odometry_information_matrix`: it is the
    point-to-point matrix, which stays well conditioned on a wall and a floor (it counts the slide
    along them as constrained); the plane term, which is what the depth residuals measure, does not.
    Normals from neighbours `baseline` samples apart: on a sensor's noisy depth, adjacent pixels'
    normals scatter enough to make a bare wall look as constrained as a cluttered desk (smallest
    eigenvalue ratio ~0.02 either way at baseline 1, 0.0005 against 0.015 at 4 samples of 4 px)."""
    z = depth[::step, ::step].astype(np.float64)
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]] * step
    points = np.stack([(cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    b = baseline
    right, down = points[:-b, b:] - points[:-b, :-b], points[b:, :-b] - points[:-b, :-b]
    normals = np.cross(right, down)
    length = np.linalg.norm(normals, axis=-1)
    p = points[:-b, :-b]
    # Both neighbours valid and on the same surface (a depth jump is no plane).
    jump = 0.05 * b * p[..., 2]
    same = (np.abs(right[..., 2]) < jump) & (np.abs(down[..., 2]) < jump)
    keep = np.isfinite(length) & (length > 0) & same & (p[..., 2] > 0)
    if not keep.any():
        return np.zeros((6, 6))
    n = normals[keep] / length[keep, None]
    jacobian = np.hstack([np.cross(p[keep], n), n])
    return jacobian.T @ jacobian


# The grid `unseen_information` samples: this many columns whatever the image's size, normals across
# UNSEEN_BASELINE samples. At 320 px wide (a 640 x 480 frame as the odometry subsamples it) every 4th
# pixel, normals over 16 px: 2.9 deg of a 60 deg view at any resolution, 5 cm at 1 m.
UNSEEN_COLUMNS = 80
UNSEEN_BASELINE = 4


def unseen_information(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """`plane_information` with normals over a wide baseline, for finding the directions depth
    cannot see (`keep_prediction_where_unseen`). The baseline is a fixed share of the image's width,
    not a pixel count: the same sample step on a 160 x 120 image spans twice the angle, and its
    normals skip the small objects (mugs, table legs, a desk's edge) that pin a slide there."""
    step = max(1, round(depth.shape[1] / UNSEEN_COLUMNS))
    return plane_information(depth, K, step=step, baseline=UNSEEN_BASELINE)


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


def keep_prediction_where_unseen(result: np.ndarray, prediction: np.ndarray, information: np.ndarray,
                                 depth_m: float, ratio: float) -> np.ndarray:
    """`result` (T_keyframe_frame) with its departure from `prediction` removed along the
    directions the frame's depth cannot see: the eigenvectors of its point-to-plane `information`
    (rotations as arc length at `depth_m`) whose eigenvalue is below `ratio` times the largest.

    Why: facing a bare wall, depth pins the distance and the two tilts, and nothing else; the
    slide along the wall and the roll about its normal are whatever the registration's noise makes
    of them, and fed back into the constant-velocity prediction they grow frame by frame (a
    hand-held pan across a wall: 20 cm off in one frame, 90 cm after 18). The motion model is the
    better guess there. The departure is taken as a small motion (rotation vector, translation) of
    the frame in its own coordinates, the parametrisation of `plane_information`."""
    from scipy.spatial.transform import Rotation

    scale = np.diag([1.0 / depth_m] * 3 + [1.0] * 3)
    eigenvalues, eigenvectors = np.linalg.eigh(scale @ information @ scale)
    if eigenvalues[-1] <= 0.0:
        return prediction.copy()
    seen = eigenvectors[:, eigenvalues >= ratio * eigenvalues[-1]]
    if seen.shape[1] == 6:
        return result
    departure = np.linalg.inv(prediction) @ result
    twist = np.concatenate([Rotation.from_matrix(departure[:3, :3]).as_rotvec(), departure[:3, 3]])
    unscaled = np.linalg.inv(scale)  # twist in arc-length units, projected, and back
    kept = scale @ seen @ seen.T @ unscaled @ twist
    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec(kept[:3]).as_matrix()
    step[:3, 3] = kept[3:]
    return prediction @ step
