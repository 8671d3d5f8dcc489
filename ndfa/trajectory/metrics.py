"""Trajectory accuracy: absolute trajectory error (ATE) and relative pose error (RPE), pure numpy.

The definitions are those of the TUM RGB-D benchmark (Sturm et al., IROS 2012) and of `evo`, so the
numbers compare with published ones:

- ATE: the estimate is rigidly aligned to the truth (SE(3), no scale: depth gives metric scale)
  by Umeyama's least-squares fit of the camera positions; the error is the RMSE of the remaining
  position differences. It measures the whole trajectory's shape, whatever its world frame.
- RPE: for pairs of frames (i, j) a fixed distance apart, the error of the estimated relative
  motion, E = (T_true_i^-1 T_true_j)^-1 (T_est_i^-1 T_est_j); translation |t(E)| in metres and
  rotation angle(E) in degrees. It measures drift per step and needs no alignment.

Trajectories are (N, 4, 4) arrays (or sequences of 4x4 arrays) of camera-to-world poses; frame k of
the estimate and of the truth must be the same instant.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ndfa.core.errors import TrajectoryError
from ndfa.core.geometry import kabsch


@dataclass(frozen=True)
class AbsoluteError:
    """ATE after rigid alignment. Distances in metres over `frames` positions; `alignment` is the
    (4, 4) transform T_truth_estimate applied to the estimate before the errors were taken."""

    frames: int
    rmse_m: float
    mean_m: float
    median_m: float
    max_m: float
    alignment: np.ndarray


@dataclass(frozen=True)
class RelativeError:
    """RPE over `pairs` frame pairs `delta` apart (in frames, or in metres travelled along the truth)."""

    delta: float
    unit: Literal["frames", "m"]
    pairs: int
    translation_rmse_m: float
    translation_mean_m: float
    rotation_rmse_deg: float
    rotation_mean_deg: float


def umeyama_alignment(source: np.ndarray, target: np.ndarray, with_scale: bool = False) -> tuple[np.ndarray, float]:
    """The similarity (rotation, translation, scale) that best maps points `source` (N, 3) onto
    `target` (N, 3) in the least-squares sense (Umeyama, PAMI 1991). Returns the (4, 4) rigid
    transform (scale applied to its rotation block when `with_scale`) and the scale (1.0 without)."""
    source, target = np.asarray(source, dtype=float), np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
        raise TrajectoryError(f"alignment needs two (N, 3) point sets with N >= 3, got {source.shape} and {target.shape}")
    return kabsch(source, target, normalised=True, with_scale=with_scale)


def absolute_trajectory_error(estimate: Sequence[np.ndarray] | np.ndarray,
                              truth: Sequence[np.ndarray] | np.ndarray) -> AbsoluteError:
    """ATE of `estimate` against `truth` after rigid SE(3) alignment of the positions (no scale)."""
    estimate, truth = _check_pair(estimate, truth)
    alignment, _ = umeyama_alignment(estimate[:, :3, 3], truth[:, :3, 3])
    aligned = estimate[:, :3, 3] @ alignment[:3, :3].T + alignment[:3, 3]
    errors = np.linalg.norm(aligned - truth[:, :3, 3], axis=1)
    return AbsoluteError(frames=len(errors), rmse_m=float(np.sqrt(np.mean(errors**2))), mean_m=float(errors.mean()),
                         median_m=float(np.median(errors)), max_m=float(errors.max()), alignment=alignment)


def one_break_error(estimate: Sequence[np.ndarray] | np.ndarray, reference: Sequence[np.ndarray] | np.ndarray,
                    min_share: float = 0.1) -> float:
    """RMSE (m) of the positions of `estimate` against `reference` with one break allowed: both cut
    at the frame that fits best into two pieces of at least `min_share` of the frames (and 3), each
    rigidly aligned on its own as `absolute_trajectory_error` aligns the whole (the whole's RMSE
    when the trajectories are too short to cut). One jump, or one short stretch where either lost
    its way, adds nothing; a drift along the whole path still shows, each piece holding its part
    (a random walk: about 0.6 times the whole's RMSE)."""
    estimate, reference = _check_pair(estimate, reference)
    moving, fixed = estimate[:, :3, 3], reference[:, :3, 3]
    count = len(moving)
    shortest = max(3, math.ceil(min_share * count))
    if count < 2 * shortest:
        return absolute_trajectory_error(estimate, reference).rmse_m
    # Prefix sums make each piece's least-squares fit O(1): the residual of the best rotation is the
    # two spreads less twice the cross-covariance's singular values (Kabsch; the smallest one's sign
    # flipped where the best orthogonal matrix is a reflection).
    def prefix(values: np.ndarray) -> np.ndarray:
        return np.concatenate([np.zeros((1,) + values.shape[1:]), np.cumsum(values, axis=0)])

    sum_moving, sum_fixed = prefix(moving), prefix(fixed)
    square_moving, square_fixed = prefix(np.sum(moving**2, axis=1)), prefix(np.sum(fixed**2, axis=1))
    cross = prefix(moving[:, :, None] * fixed[:, None, :])

    def residual(start: np.ndarray, end: np.ndarray) -> np.ndarray:
        n = (end - start)[:, None]
        a, b = sum_moving[end] - sum_moving[start], sum_fixed[end] - sum_fixed[start]
        spread = (square_moving[end] - square_moving[start]) + (square_fixed[end] - square_fixed[start])
        spread = spread - (np.sum(a**2, axis=1) + np.sum(b**2, axis=1)) / n[:, 0]
        covariance = (cross[end] - cross[start]) - a[:, :, None] * b[:, None, :] / n[:, :, None]
        u, singular, vt = np.linalg.svd(covariance)
        singular[:, 2] *= np.where(np.linalg.det(u) * np.linalg.det(vt) < 0, -1.0, 1.0)
        return np.maximum(spread - 2.0 * singular.sum(axis=1), 0.0)

    cuts = np.arange(shortest, count - shortest + 1)
    total = residual(np.zeros_like(cuts), cuts) + residual(cuts, np.full_like(cuts, count))
    return float(np.sqrt(total.min() / count))


def relative_pose_error(estimate: Sequence[np.ndarray] | np.ndarray, truth: Sequence[np.ndarray] | np.ndarray,
                        delta: float = 1, unit: Literal["frames", "m"] = "frames") -> RelativeError:
    """RPE over pairs (i, j): j = i + delta for unit "frames"; for unit "m", j is the first frame at
    least `delta` metres along the true path after i (as evo's --delta_unit m). Raises when no pair
    fits (the trajectory is shorter than delta)."""
    estimate, truth = _check_pair(estimate, truth)
    if not delta > 0:
        raise TrajectoryError(f"RPE delta must be > 0, got {delta}")
    pairs = _pairs(truth, delta, unit)
    if not pairs:
        raise TrajectoryError(f"no frame pairs {delta} {unit} apart in a trajectory of {len(truth)} frames")
    first, second = np.array(pairs).T
    true_motion = np.linalg.inv(truth[first]) @ truth[second]
    estimated_motion = np.linalg.inv(estimate[first]) @ estimate[second]
    error = np.linalg.inv(true_motion) @ estimated_motion
    translation = np.linalg.norm(error[:, :3, 3], axis=1)
    rotation = np.degrees(rotation_angle(error[:, :3, :3]))
    return RelativeError(delta=float(delta), unit=unit, pairs=len(pairs),
                         translation_rmse_m=float(np.sqrt(np.mean(translation**2))),
                         translation_mean_m=float(translation.mean()),
                         rotation_rmse_deg=float(np.sqrt(np.mean(rotation**2))),
                         rotation_mean_deg=float(rotation.mean()))


def rotation_angle(rotations: np.ndarray) -> np.ndarray:
    """Angle in radians of rotation matrices (..., 3, 3), numerically safe near 0 and pi."""
    cosine = (np.trace(rotations, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cosine, -1.0, 1.0))


def _pairs(truth: np.ndarray, delta: float, unit: str) -> list[tuple[int, int]]:
    if unit == "frames":
        step = int(round(delta))
        if step != delta:
            raise TrajectoryError(f"an RPE delta in frames must be a whole number, got {delta}")
        return [(i, i + step) for i in range(len(truth) - step)]
    if unit == "m":
        travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(truth[:, :3, 3], axis=0), axis=1))])
        ends = np.searchsorted(travelled, travelled + delta, side="left")
        return [(i, int(j)) for i, j in enumerate(ends) if j < len(truth)]
    raise TrajectoryError(f"RPE unit must be 'frames' or 'm', got {unit!r}")


def _check_pair(estimate: Sequence[np.ndarray] | np.ndarray,
                truth: Sequence[np.ndarray] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    estimate, truth = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    for name, poses in (("estimate", estimate), ("truth", truth)):
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise TrajectoryError(f"the {name} must be (N, 4, 4) poses, got shape {poses.shape}")
        if not np.all(np.isfinite(poses)):
            raise TrajectoryError(f"the {name} has non-finite poses")
    if len(estimate) != len(truth):
        raise TrajectoryError(f"the estimate has {len(estimate)} poses and the truth {len(truth)}: they must match frame by frame")
    if len(estimate) < 3:
        raise TrajectoryError(f"trajectory errors need at least 3 poses, got {len(estimate)}")
    return estimate, truth
