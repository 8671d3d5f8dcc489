"""Localization error for a session's camera poses: a rigid 6-DoF offset of the whole trajectory
(the sessions do not share a world frame) plus a random-walk drift (odometry error that grows
along the trajectory). The true poses stay in the recording's ground truth."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ndfa.core.geometry import axis_angle_to_matrix, make_pose, rotation_z


@dataclass(frozen=True)
class PoseError:
    offset_translation_m: float = 0.0    # offset translation drawn uniformly in [-v, v] per axis
    offset_yaw_deg: float = 0.0          # offset yaw drawn uniformly in [-v, v]
    offset_tilt_deg: float = 0.0         # offset roll and pitch drawn uniformly in [-v, v]
    drift_translation_m: float = 0.0     # std of the per-frame translation step of the random walk
    drift_yaw_deg: float = 0.0           # std of the per-frame yaw step of the random walk

    @property
    def enabled(self) -> bool:
        return any(v != 0.0 for v in asdict(self).values())

    def apply(self, true_poses: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Perturbed camera-to-world poses (N, 4, 4) and the offset (4, 4) that was applied.

        perturbed_i = offset @ drift_i @ true_i, where drift_i is the walk's pose at frame i,
        rotating about the trajectory's current position so that drift does not swing the far
        end of the room.
        """
        tilt = np.deg2rad(self.offset_tilt_deg)
        offset_rotation = rotation_z(np.deg2rad(rng.uniform(-self.offset_yaw_deg, self.offset_yaw_deg))) @ \
            axis_angle_to_matrix(np.array([rng.uniform(-tilt, tilt), rng.uniform(-tilt, tilt), 0.0]))
        offset = make_pose(offset_rotation, rng.uniform(-1, 1, size=3) * self.offset_translation_m)

        n = len(true_poses)
        steps_xyz = rng.normal(scale=self.drift_translation_m, size=(n, 3)) * np.array([1.0, 1.0, 0.3])
        steps_yaw = rng.normal(scale=np.deg2rad(self.drift_yaw_deg), size=n)
        steps_xyz[0], steps_yaw[0] = 0.0, 0.0  # the walk starts where the true trajectory starts
        walk_xyz, walk_yaw = np.cumsum(steps_xyz, axis=0), np.cumsum(steps_yaw)

        perturbed = np.empty_like(true_poses)
        for i, pose in enumerate(true_poses):
            center = pose[:3, 3]
            rotation = rotation_z(walk_yaw[i])
            drift = make_pose(rotation, center - rotation @ center + walk_xyz[i])
            perturbed[i] = offset @ drift @ pose
        return perturbed, offset
