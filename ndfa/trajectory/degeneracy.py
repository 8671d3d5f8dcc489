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
    rows = np.arange(z.shape[0])[:, None] * step
    cols = np.arange(z.shape[1])[None, :] * step
    x, y = (cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z
    # Component by component on the kept pixels only: the same arithmetic as stacked (H, W, 3)
    # points with np.cross (the same matrix to the bit), in a third of the time.
    b = baseline
    here = (x[:-b, :-b], y[:-b, :-b], z[:-b, :-b])
    right = [c[:-b, b:] - h for c, h in zip((x, y, z), here, strict=True)]
    down = [c[b:, :-b] - h for c, h in zip((x, y, z), here, strict=True)]
    # Both neighbours valid and on the same surface (a depth jump is no plane).
    jump = 0.05 * b * here[2]
    keep = (np.abs(right[2]) < jump) & (np.abs(down[2]) < jump) & (here[2] > 0)
    r0, r1, r2 = (c[keep] for c in right)
    d0, d1, d2 = (c[keep] for c in down)
    p0, p1, p2 = (c[keep] for c in here)
    n0, n1, n2 = r1 * d2 - r2 * d1, r2 * d0 - r0 * d2, r0 * d1 - r1 * d0  # right x down
    length = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    ok = np.isfinite(length) & (length > 0)
    if not ok.any():
        return np.zeros((6, 6))
    length = length[ok]
    n0, n1, n2 = n0[ok] / length, n1[ok] / length, n2[ok] / length
    p0, p1, p2 = p0[ok], p1[ok], p2[ok]
    jacobian = np.empty((len(length), 6))  # (p x n, n)
    jacobian[:, 0], jacobian[:, 1], jacobian[:, 2] = p1 * n2 - p2 * n1, p2 * n0 - p0 * n2, p0 * n1 - p1 * n0
    jacobian[:, 3], jacobian[:, 4], jacobian[:, 5] = n0, n1, n2
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
    channels = rgb.astype(np.float32, copy=False)
    # The channels' mean, as numpy's mean over the last axis sums and divides it (the same values),
    # without its strided reduction (3.5x the time).
    gray = (channels[..., 0] + channels[..., 1] + channels[..., 2]) / np.float32(3.0) / np.float32(255.0)
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
