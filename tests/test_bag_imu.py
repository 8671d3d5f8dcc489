"""World up from a bag's IMU: `ndfa ingest bag` records the still accelerometer readings in the
camera's axes (through the bag's tf), `ndfa detect`'s up step uses them, the support planes check
them, and `ndfa info` shows them. Without a tf between the IMU and the camera nothing is guessed."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.conventions import STANDARD_GRAVITY
from ndfa.core.geometry import axis_angle_to_matrix, invert_pose, make_pose
from ndfa.io.export.bag import LINK_FROM_OPTICAL, _BagWriter, _write_frame
from ndfa.io.ingest.bag import ingest_bag, list_topics
from ndfa.io.recording import RecordingReader
from ndfa.run.world import prepare_session
from ndfa.trajectory.up import angle_deg
from ndfa.trajectory.up_imu import imu_gravity

SAMPLE = Path(__file__).resolve().parents[1] / "recordings" / "sample"
STAMP0 = 1_767_600_000 * 10**9  # ns
FRAME_NS = 200_000_000  # the sample's 5 Hz
TILT = axis_angle_to_matrix(np.radians(25.0) * np.array([0.6, -0.8, 0.0]))  # the bag's world, 25 deg from z-up
# An IMU mounted on the camera body turned and shifted (as a RealSense D435i's is, more or less).
LINK_FROM_IMU = make_pose(axis_angle_to_matrix(np.array([np.pi / 2, 0.0, 0.3])), np.array([0.01, -0.02, 0.005]))


@pytest.fixture(scope="module")
def frames():
    """The sample source's first 8 frames, in a world tilted by TILT (no masks, no true poses)."""
    out = []
    for frame in RecordingReader(SAMPLE / "source.mcap").frames(stop=8):
        out.append(dataclasses.replace(frame, pose_world_camera=make_pose(TILT, np.zeros(3)) @ frame.pose_world_camera,
                                       instances=None, pose_world_camera_true=None))
    return out


def write_bag(path: Path, frames, imu_tf: bool = True, imu_error: np.ndarray = np.eye(3), moving: set[int] = frozenset(),
              topics=("/camera/imu",)) -> Path:
    """A ROS2 bag of the frames (map -> camera_link on /tf, camera_link -> camera_optical and, with
    `imu_tf`, camera_link -> imu_link on /tf_static) and 100 Hz accelerometer readings in imu_link
    around each frame: gravity's reaction (+g up) turned by `imu_error`; around the frames in `moving`
    the sensor accelerates (2 m/s^2 sideways)."""
    with _BagWriter(path, 2, "sqlite3") as bag:
        static = [(STAMP0, "camera_link", "camera_optical", LINK_FROM_OPTICAL)]
        if imu_tf:
            static.append((STAMP0, "camera_link", "imu_link", LINK_FROM_IMU))
        bag.write("/tf_static", "tf2_msgs/msg/TFMessage", STAMP0, bag.tf_message(static))
        for i, frame in enumerate(frames):
            stamp = STAMP0 + i * FRAME_NS
            _write_frame(bag, frame, stamp, False, "jpeg")
            world_from_imu = frame.pose_world_camera @ invert_pose(LINK_FROM_OPTICAL) @ LINK_FROM_IMU
            reading = imu_error @ world_from_imu[:3, :3].T @ (TILT @ np.array([0.0, 0.0, STANDARD_GRAVITY]))
            if i in moving:
                reading = reading + world_from_imu[:3, :3].T @ np.array([2.0, 0.0, 0.0])
            for k in range(-5, 5):
                t = stamp + k * 10_000_000
                vector = bag.types["geometry_msgs/msg/Vector3"]
                message = bag.types["sensor_msgs/msg/Imu"](
                    header=bag.header(t, "imu_link", 0),
                    orientation=bag.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.full(9, -1.0), angular_velocity=vector(0.0, 0.0, 0.0),
                    angular_velocity_covariance=np.zeros(9), linear_acceleration=vector(*(float(v) for v in reading)),
                    linear_acceleration_covariance=np.zeros(9))
                for topic in topics:
                    bag.write(topic, "sensor_msgs/msg/Imu", t, message)
    return path


def true_up_in_camera(frame) -> np.ndarray:
    return frame.pose_world_camera[:3, :3].T @ (TILT @ np.array([0.0, 0.0, 1.0]))


def test_the_import_records_gravity_in_the_camera_axes(tmp_path, frames):
    bag = write_bag(tmp_path / "bag", frames, moving={3})
    assert {t.name: t.role for t in list_topics(bag)}["/camera/imu"] == "imu"
    summary = ingest_bag(bag, tmp_path / "rec.mcap")
    assert summary.imu == "/camera/imu: a still reading at 7 of 8 frames"
    meta = RecordingReader(tmp_path / "rec.mcap").meta["imu"]
    assert meta["topic"] == "/camera/imu" and meta["frame"] == "imu_link" and meta["messages"] == 80
    assert meta["camera_from_imu"] == "tf imu_link -> camera_optical"
    gravity = imu_gravity({"imu": meta})
    by_time = {frame.timestamp: frame for frame in RecordingReader(tmp_path / "rec.mcap").frames()}
    assert sorted(gravity) == sorted(t for i, t in enumerate(by_time) if i != 3)  # frame 3: moving
    for timestamp, reading in gravity.items():
        assert np.linalg.norm(reading) == pytest.approx(STANDARD_GRAVITY)
        frame = frames[list(by_time).index(timestamp)]
        assert angle_deg(reading, true_up_in_camera(frame)) < 1e-4


def test_detect_takes_up_from_the_imu_and_the_planes_check_it(tmp_path, frames):
    ingest_bag(write_bag(tmp_path / "bag", frames), tmp_path / "rec.mcap")
    world = prepare_session(RecordingReader(tmp_path / "rec.mcap"), "source")
    assert world.up_source == "imu" and world.up.method == "imu" and world.notes == []
    assert angle_deg(world.up.up_world, TILT @ np.array([0.0, 0.0, 1.0])) < 0.01
    assert world.levelling is not None and world.up.tilt_deg == pytest.approx(25.0, abs=0.01)
    assert world.up_check.ok and angle_deg(world.up_check.up_world, world.up.up_world) < 2.0
    assert "from the IMU (still readings at 8 frames" in world.describe_up()
    assert world.as_dict()["up_check"]["method"] == "planes"

    result = CliRunner(env={"COLUMNS": "300"}).invoke(app, ["info", str(tmp_path / "rec.mcap")])
    assert result.exit_code == 0, result.output
    assert "/camera/imu: a still reading at 8 of 8 frames; into the camera by tf imu_link -> camera_optical" in result.output
    assert "levelled by 25.0 deg; from the IMU" in result.output


def test_an_imu_that_disagrees_with_the_planes_is_reported(tmp_path, frames):
    wrong = axis_angle_to_matrix(np.radians(10.0) * np.array([1.0, 0.0, 0.0]))
    ingest_bag(write_bag(tmp_path / "bag", frames, imu_error=wrong), tmp_path / "rec.mcap")
    world = prepare_session(RecordingReader(tmp_path / "rec.mcap"), "source")
    assert world.up_source == "imu" and len(world.notes) == 1
    # A 10 deg turn of the readings about an axis off the horizontal moves up by a little less.
    match = re.match(r"up from the IMU and from the planes differ by ([\d.]+) deg \(more than 5\)", world.notes[0])
    assert match and 8.0 < float(match[1]) <= 10.0 and world.notes[0].endswith("the IMU's is used")


def test_without_a_tf_to_the_camera_the_imu_is_not_guessed(tmp_path, frames):
    summary = ingest_bag(write_bag(tmp_path / "bag", frames, imu_tf=False), tmp_path / "rec.mcap")
    assert "no tf between the IMU's frame 'imu_link' and the camera's 'camera_optical'" in summary.imu
    meta = RecordingReader(tmp_path / "rec.mcap").meta["imu"]
    assert meta["camera_from_imu"] is None and meta["gravity_camera"] == []
    world = prepare_session(RecordingReader(tmp_path / "rec.mcap"), "source")
    assert world.up_source == "estimated" and world.up.ok  # the planes alone
    assert world.notes[0].startswith("IMU /camera/imu not used for up: no tf between")


def test_several_imu_topics_are_named_and_one_chosen(tmp_path, frames):
    bag = write_bag(tmp_path / "bag", frames[:3], topics=("/a/imu", "/b/imu"))
    summary = ingest_bag(bag, tmp_path / "none.mcap")
    assert summary.imu == "several IMU topics (/a/imu, /b/imu), none used: choose one with --imu-topic"
    assert "imu" not in RecordingReader(tmp_path / "none.mcap").meta
    summary = ingest_bag(bag, tmp_path / "b.mcap", imu_topic="/b/imu")
    assert summary.imu.startswith("/b/imu: a still reading at 3 of 3 frames")
    result = CliRunner(env={"COLUMNS": "300"}).invoke(app, ["ingest", "bag", str(bag), "--out", str(tmp_path / "cli.mcap"),
                                                           "--imu-topic", "/a/imu"])
    assert result.exit_code == 0, result.output
    assert "IMU (world up)" in result.output and "/a/imu: a still reading at 3 of 3 frames" in result.output
    with pytest.raises(Exception, match="--imu-topic '/c/imu' is not a sensor_msgs/Imu topic"):
        ingest_bag(bag, tmp_path / "c.mcap", imu_topic="/c/imu")
