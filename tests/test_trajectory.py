import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.sim.pose_error import PoseError
from ndfa.sim.scene import table_grid
from ndfa.sim.trajectory import ROUTES, TrajectoryConfig, camera_poses


@pytest.mark.parametrize("route", ROUTES)
def test_route_keeps_clear_of_tables_and_faces_the_nearest_one(route):
    tables = table_grid(2, 3)
    config = TrajectoryConfig(route=route)
    poses = camera_poses(tables, config, np.random.default_rng(0))
    assert len(poses) > 50
    positions = poses[:, :3, 3]
    steps = np.linalg.norm(np.diff(positions[:, :2], axis=0), axis=1)
    assert np.allclose(steps, config.step_m, atol=0.01)
    clearance = np.min([t.distance_xy(positions[:, :2]) for t in tables], axis=0)
    assert clearance.min() > 0.25  # smoothing rounds corners, never into a table
    heights = positions[:, 2] - tables[0].height
    assert np.all(np.abs(heights - config.height_above_table_m) <= config.height_wobble_m + 1e-9)
    # The optical axis (camera z in world) points at the nearest table most of the time.
    forward = poses[:, :3, 2]
    nearest = np.argmin([t.distance_xy(positions[:, :2]) for t in tables], axis=0)
    to_table = np.array([[*tables[k].center_xy, tables[k].height] for k in nearest]) - positions
    cosine = np.sum(forward * to_table, axis=1) / np.linalg.norm(to_table, axis=1)
    assert np.median(cosine) > 0.95
    assert np.allclose(np.linalg.det(poses[:, :3, :3]), 1.0)


def test_unknown_route_is_refused():
    with pytest.raises(SimError, match="unknown camera route"):
        camera_poses(table_grid(1, 2), TrajectoryConfig(route="spiral"), np.random.default_rng(0))


def test_pose_error_offset_is_rigid_and_drift_grows():
    poses = camera_poses(table_grid(2, 2), TrajectoryConfig(), np.random.default_rng(0))
    offset_only = PoseError(offset_translation_m=1.0, offset_yaw_deg=180.0, offset_tilt_deg=3.0)
    perturbed, offset = offset_only.apply(poses, np.random.default_rng(1))
    assert np.allclose(perturbed, offset @ poses)
    assert not np.allclose(offset, np.eye(4))

    drift_only = PoseError(drift_translation_m=0.003, drift_yaw_deg=0.05)
    drifted, offset = drift_only.apply(poses, np.random.default_rng(1))
    assert np.allclose(offset, np.eye(4))
    error = np.linalg.norm(drifted[:, :3, 3] - poses[:, :3, 3], axis=1)
    assert error[0] == pytest.approx(0.0)
    assert error[-20:].mean() > error[:20].mean()
    assert not PoseError().enabled and drift_only.enabled
