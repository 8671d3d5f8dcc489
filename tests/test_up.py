"""World up from the data (ndfa.trajectory.up): a known tilt is recovered from the frames, the
levelling rotation undoes it, and input without a horizontal plane or with disagreeing poses is
refused with a reason instead of a guess."""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import axis_angle_to_matrix, invert_pose, make_pose
from ndfa.io.recording import RecordingReader
from ndfa.io.tum_format import read_tum
from ndfa.trajectory.level import level_frame, level_poses, levelling_rotation
from ndfa.trajectory.up import angle_deg, estimate_up
from ndfa.trajectory.up_imu import up_from_accelerations

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "recordings" / "sample" / "source.mcap"
REDKITCHEN = REPO.parent / "shared" / "data" / "redkitchen_7scenes"
Z = np.array([0.0, 0.0, 1.0])
# Camera looking along world +y, upright (OpenCV: x right, y down, z forward).
UPRIGHT = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def sample_frames() -> list[Frame]:
    """Six frames of the sample scene (z-up world: a room with tables and mugs)."""
    return list(RecordingReader(SAMPLE).frames(step=10))


def with_poses(frames: list[Frame], transform) -> list[Frame]:
    return [Frame(f.index, f.timestamp, None, f.depth, f.K, transform(f.pose_world_camera)) for f in frames]


def tilt_rotation(angle_deg_: float, heading_deg: float) -> np.ndarray:
    heading = np.radians(heading_deg)
    return axis_angle_to_matrix(np.radians(angle_deg_) * np.array([np.cos(heading), np.sin(heading), 0.0]))


def test_sample_scene_is_z_up(sample_frames):
    estimate = estimate_up(sample_frames)
    assert estimate.ok, estimate.reason
    assert estimate.method == "planes"
    assert estimate.frames == len(sample_frames) and estimate.frames_agreeing >= 3
    assert estimate.tilt_deg < 0.5
    assert 0.0 < estimate.support_fraction <= 1.0 and estimate.spread_deg < 2.0


@pytest.mark.parametrize("angle, heading", [(15.0, 30.0), (35.0, 200.0)])
def test_recovers_a_known_tilt_and_levels_it(sample_frames, angle, heading):
    tilt = make_pose(tilt_rotation(angle, heading), np.zeros(3))
    tilted = with_poses(sample_frames, lambda pose: tilt @ pose)
    estimate = estimate_up(tilted)
    assert estimate.ok, estimate.reason
    assert angle_deg(estimate.up_world, tilt[:3, :3] @ Z) < 0.5
    assert abs(estimate.tilt_deg - angle) < 0.5

    levelled = [level_frame(frame, estimate.levelling()) for frame in tilted]
    assert estimate_up(levelled).tilt_deg < 0.5
    # The cameras' motion relative to each other is unchanged by levelling.
    relative = invert_pose(levelled[0].pose_world_camera) @ levelled[-1].pose_world_camera
    np.testing.assert_allclose(relative, invert_pose(tilted[0].pose_world_camera) @ tilted[-1].pose_world_camera, atol=1e-9)


def test_first_camera_world(sample_frames):
    """Odometry's world: the first camera's frame, where up is about that camera's -y."""
    first = sample_frames[0].pose_world_camera
    estimate = estimate_up(with_poses(sample_frames, lambda pose: invert_pose(first) @ pose))
    assert estimate.ok, estimate.reason
    assert angle_deg(estimate.up_world, first[:3, :3].T @ Z) < 0.5


def test_disagreeing_poses_never_give_a_confident_up(sample_frames):
    # Each pose tilted by its own 8-20 deg: refused (the cameras' axes are not upright then) or used
    # with "low" confidence and a warning that says why -- never a confident up.
    rng = np.random.default_rng(3)
    wobbles = iter([make_pose(tilt_rotation(rng.uniform(8.0, 20.0), rng.uniform(0.0, 360.0)), np.zeros(3))
                    for _ in sample_frames])
    estimate = estimate_up(with_poses(sample_frames, lambda pose: next(wobbles) @ pose))
    if estimate.ok:
        assert estimate.confidence == "low" and estimate.warning, estimate
    else:
        assert estimate.up_world is None and "not held upright, or the poses are wrong" in estimate.reason
        with pytest.raises(TrajectoryError, match="not held upright"):
            estimate.levelling()


def test_wall_only_and_no_depth_fall_back_to_the_cameras_with_a_warning():
    rng = np.random.default_rng(0)
    tilt = tilt_rotation(25.0, 40.0)  # the world tilted: the cameras' up is tilt @ z, not z
    wall = [Frame(i, float(i), None, (2.0 + 0.002 * rng.normal(size=(240, 320))).astype(np.float32), K,
                  make_pose(tilt @ axis_angle_to_matrix([0.0, 0.0, 0.7 * i]) @ UPRIGHT, np.zeros(3))) for i in range(5)]
    estimate = estimate_up(wall)
    assert estimate.ok and estimate.method == "cameras" and estimate.confidence == "low"
    assert "no horizontal plane" in estimate.warning and "up from the cameras" in estimate.warning
    assert angle_deg(estimate.up_world, tilt @ Z) < 0.01
    assert estimate.frames == 5 and estimate.frames_used == 5

    no_depth = [Frame(i, float(i), None, np.zeros((240, 320), np.float32), K, make_pose(UPRIGHT, np.zeros(3)))
                for i in range(3)]
    estimate = estimate_up(no_depth)
    assert estimate.ok and estimate.method == "cameras" and estimate.frames_used == 0
    assert "no planar surfaces" in estimate.warning
    assert not estimate_up([]).ok and "no frames" in estimate_up([]).reason


def test_floor_seen_by_a_synthetic_camera():
    """A camera 1.5 m above a flat floor, pitched down 30 deg: up is the floor's normal."""
    pitch = np.radians(30.0)
    rotation = UPRIGHT @ axis_angle_to_matrix([-pitch, 0.0, 0.0])  # optical axis tilted down
    rows, cols = np.mgrid[0:240, 0:320]
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones_like(rows, float)], axis=-1)
    height = 1.5
    down = rays @ rotation.T @ -Z  # how fast each ray descends per unit of depth
    depth = np.where(down > 1e-3, height / np.maximum(down, 1e-3), 0.0).astype(np.float32)
    frames = [Frame(i, float(i), None, depth, K, make_pose(axis_angle_to_matrix([0.0, 0.0, 0.5 * i]) @ rotation,
                                                                np.array([0.0, 0.0, height]))) for i in range(4)]
    estimate = estimate_up(frames)
    assert estimate.ok, estimate.reason
    assert angle_deg(estimate.up_world, Z) < 0.1


def test_levelling_rotation():
    rng = np.random.default_rng(1)
    for up in [*rng.normal(size=(20, 3)), Z, -Z, np.array([1e-9, 0.0, -1.0])]:
        rotation = levelling_rotation(up)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        np.testing.assert_allclose(rotation @ (up / np.linalg.norm(up)), Z, atol=1e-9)
        axis = np.cross(up, Z)
        if np.linalg.norm(axis) > 1e-6:  # the smallest rotation: about up x z, which it keeps
            np.testing.assert_allclose(rotation @ axis, axis, atol=1e-9)
    np.testing.assert_array_equal(levelling_rotation(Z), np.eye(3))
    with pytest.raises(TrajectoryError):
        levelling_rotation(np.zeros(3))


def test_level_poses_and_frame_round_trip():
    rng = np.random.default_rng(2)
    tilt = tilt_rotation(25.0, 70.0)
    poses = np.stack([make_pose(axis_angle_to_matrix(rng.normal(size=3)), rng.normal(size=3)) for _ in range(4)])
    tilted = level_poses(poses, tilt)  # any rotation re-expresses the world
    levelled = level_poses(tilted, levelling_rotation(tilt @ Z))
    np.testing.assert_allclose(levelled, poses, atol=1e-9)

    frame = Frame(0, 0.0, None, np.ones((4, 4), np.float32), K, tilted[0], pose_world_camera_true=tilted[1])
    frame_levelled = level_frame(frame, levelling_rotation(tilt @ Z))
    np.testing.assert_allclose(frame_levelled.pose_world_camera, poses[0], atol=1e-9)
    np.testing.assert_allclose(frame_levelled.pose_world_camera_true, poses[1], atol=1e-9)
    assert frame_levelled.depth is frame.depth and frame.pose_world_camera is not frame_levelled.pose_world_camera


def test_up_from_accelerations():
    rng = np.random.default_rng(4)
    up = np.array([0.3, -0.9, -0.2])
    up /= np.linalg.norm(up)
    rotations = np.stack([axis_angle_to_matrix(rng.normal(size=3)) for _ in range(60)])
    acc_camera = np.einsum("nji,j->ni", rotations, 9.81 * up) + 0.05 * rng.normal(size=(60, 3))
    acc_camera[:10] += rng.normal(scale=3.0, size=(10, 3))  # moving: not still, must not count
    estimate = up_from_accelerations(acc_camera, rotations)
    assert estimate.ok and estimate.method == "imu", estimate.reason
    assert angle_deg(estimate.up_world, up) < 1.0
    assert estimate.frames == 60 and estimate.frames_used <= 52

    moving = up_from_accelerations(acc_camera[:10], rotations[:10])
    assert not moving.ok and "still" in moving.reason
    with pytest.raises(TrajectoryError, match="one pose per sample"):
        up_from_accelerations(acc_camera, rotations[:5])


@pytest.mark.skipif(not REDKITCHEN.is_dir(), reason=f"the 7-Scenes redkitchen slice is not at {REDKITCHEN} (../shared absent)")
def test_redkitchen_matches_its_gravity_file():
    """Real Kinect depth: the estimate is within a few degrees of the dataset's gravity (up = -gravity)."""
    stamps, poses = read_tum(REDKITCHEN / "groundtruth.txt")
    depth_list = [line.split() for line in (REDKITCHEN / "depth.txt").read_text().splitlines() if not line.startswith("#")]
    K_kinect = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
    frames = []
    for index in range(0, 50, 10):  # depth PNGs in millimetres, 0 and 65535 invalid
        stamp, name = float(depth_list[index][0]), depth_list[index][1]
        millimetres = np.asarray(Image.open(REDKITCHEN / name), dtype=np.float32)
        depth = np.where(millimetres == 65535, 0.0, millimetres / 1000.0).astype(np.float32)
        pose = poses[np.argmin(np.abs(stamps - stamp))]
        frames.append(Frame(index, stamp, None, depth, K_kinect, pose))
    estimate = estimate_up(frames)
    assert estimate.ok, estimate.reason
    gravity = np.loadtxt(REDKITCHEN / "gravity-direction.txt")
    assert angle_deg(estimate.up_world, -gravity) < 3.0
