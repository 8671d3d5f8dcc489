"""ROS bags: `export_bag` then `ingest_bag` gives the recording back, on every bag flavour; bad bags
fail with messages that name the problem; partly readable bags import what can be read."""

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.errors import ExportError, IngestError
from ndfa.core.geometry import invert_pose, look_at
from ndfa.io.export.bag import LINK_FROM_OPTICAL, _BagWriter, export_bag
from ndfa.io.ingest import ros_images
from ndfa.io.ingest.bag import ingest_bag, list_topics
from ndfa.io.recording import RecordingReader, RecordingWriter

SAMPLE = Path(__file__).resolve().parents[1] / "recordings" / "sample"
FRAMES = 10
STAMP0 = 1_767_600_000 * 10**9  # ns


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory) -> Path:
    """The first frames of the sample target (it has masks, ground truth and perturbed + true poses)."""
    reader = RecordingReader(SAMPLE / "target.mcap")
    path = tmp_path_factory.mktemp("bag") / "small.mcap"
    meta = {k: v for k, v in reader.meta.items() if k not in ("format", "format_version", "depth_scale", "units")}
    with RecordingWriter(path, meta) as writer:
        for frame in reader.frames(stop=FRAMES):
            writer.write_frame(frame)
        writer.write_ground_truth(reader.ground_truth)
    return path


@pytest.mark.parametrize("version, storage, compressed, color_format", [
    (1, "sqlite3", False, "jpeg"),
    (2, "sqlite3", False, "jpeg"),
    (2, "mcap", False, "jpeg"),
    (1, "sqlite3", True, "jpeg"),
    (2, "sqlite3", True, "png"),
    (2, "mcap", True, "jpeg"),
])
def test_round_trip(small_recording, tmp_path, version, storage, compressed, color_format):
    bag = tmp_path / ("run.bag" if version == 1 else "run")
    exported = export_bag(small_recording, bag, version=version, storage=storage, compressed=compressed,
                          color_format=color_format)
    assert exported.frames == FRAMES
    summary = ingest_bag(bag, tmp_path / "back.mcap")
    assert summary.frames == FRAMES and summary.skipped == {}
    assert (summary.pose_source, summary.world_frame, summary.camera_frame) == ("tf", "map", "camera_optical")

    original, back = RecordingReader(small_recording), RecordingReader(tmp_path / "back.mcap")
    assert back.ground_truth == original.ground_truth
    assert back.meta["source"] == "rosbag" and back.has_instances
    for a, b in zip(original.frames(), back.frames(), strict=True):
        assert b.index == a.index and b.timestamp == pytest.approx(a.timestamp, abs=1e-6)
        np.testing.assert_array_equal(np.rint(b.depth * 1000), np.rint(a.depth * 1000))
        if compressed and color_format == "jpeg":
            assert np.abs(b.rgb.astype(int) - a.rgb.astype(int)).mean() < 3.0
        else:
            np.testing.assert_array_equal(b.rgb, a.rgb)
        np.testing.assert_allclose(b.K, a.K, atol=1e-9)
        np.testing.assert_array_equal(b.instances, a.instances)
        np.testing.assert_allclose(b.pose_world_camera, a.pose_world_camera, atol=1e-6)
        np.testing.assert_allclose(b.pose_world_camera_true, a.pose_world_camera_true, atol=1e-6)


def test_list_topics_and_cli(small_recording, tmp_path):
    bag = tmp_path / "run.bag"
    result = CliRunner().invoke(app, ["export", "bag", str(small_recording), "--out", str(bag), "--compressed"])
    assert result.exit_code == 0, result.output
    roles = {topic.name: topic.role for topic in list_topics(bag)}
    assert roles["/camera/depth/image_raw/compressedDepth"] == "depth"
    assert roles["/camera/color/image_raw/compressed"] == "color"
    assert roles["/camera/instances"] == "mask" and roles["/camera/depth/camera_info"] == "info"
    assert roles["/tf"] == roles["/tf_static"] == "tf"

    result = CliRunner(env={"COLUMNS": "200"}).invoke(app, ["ingest", "bag", str(bag), "--list"])
    assert result.exit_code == 0, result.output
    assert "/camera/depth/image_raw/compressedDepth" in result.output and "16UC1; compressedDepth png" in result.output
    result = CliRunner(env={"COLUMNS": "200"}).invoke(app, ["ingest", "bag", str(bag), "--out", str(tmp_path / "r.mcap")])
    assert result.exit_code == 0, result.output
    assert "frames written" in result.output and len(RecordingReader(tmp_path / "r.mcap")) == FRAMES
    with pytest.raises(ExportError, match="already exists"):
        export_bag(small_recording, bag)


# --- hand-made bags -------------------------------------------------------------------------------

def _write_bag(path: Path, frames: int = 4, depth_encoding: str = "16UC1", image_frame: str = "camera_optical",
               tf: list[tuple[int, str, str]] | None = None, extra=None, depth_topics=("/cam/depth",),
               info: bool = True, odometry: bool = False) -> list[np.ndarray]:
    """A ROS2 bag of `frames` 8x6 depth images, 0.1 s apart, with CameraInfo; `tf` lists (frame, parent,
    child) transforms to publish on /tf (moving) for frame indices; the camera optical frame hangs
    under camera_link on /tf_static. Returns the true pose_world_camera of each frame."""
    poses = [look_at(np.array([0.1 * i, 0.0, 1.0]), np.array([0.1 * i + 1.0, 0.5, 0.0])) for i in range(frames)]
    depth = np.full((6, 8), 1500, np.uint16)
    K = np.array([[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]])
    with _BagWriter(path, 2, "sqlite3") as bag:
        bag.write("/tf_static", "tf2_msgs/msg/TFMessage", STAMP0,
                  bag.tf_message([(STAMP0, "camera_link", "camera_optical", LINK_FROM_OPTICAL)]))
        for i, pose in enumerate(poses):
            stamp = STAMP0 + i * 100_000_000
            header = bag.header(stamp, image_frame, i)
            for topic in depth_topics:
                bag.write(topic, "sensor_msgs/msg/Image", stamp, bag.image(header, depth, depth_encoding))
            if info:
                bag.write("/cam/info", "sensor_msgs/msg/CameraInfo", stamp, bag.camera_info(header, K, (6, 8)))
            link = pose @ invert_pose(LINK_FROM_OPTICAL)
            for index, parent, child in tf or [(i, "map", "camera_link")]:
                if index == i:
                    bag.write("/tf", "tf2_msgs/msg/TFMessage", stamp, bag.tf_message([(stamp, parent, child, link)]))
            if odometry:
                odom = bag.types["nav_msgs/msg/Odometry"](
                    header=bag.header(stamp, "odom", i), child_frame_id="camera_link",
                    pose=bag.types["geometry_msgs/msg/PoseWithCovariance"](
                        pose=bag.pose_stamped(header, link).pose, covariance=np.zeros(36)),
                    twist=bag.types["geometry_msgs/msg/TwistWithCovariance"](
                        twist=bag.types["geometry_msgs/msg/Twist"](
                            linear=bag.types["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0),
                            angular=bag.types["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)),
                        covariance=np.zeros(36)))
                bag.write("/odom", "nav_msgs/msg/Odometry", stamp, odom)
            if extra is not None:
                extra(bag, i, stamp, header)
    return poses


def test_no_image_topics(tmp_path):
    with _BagWriter(tmp_path / "empty", 2, "sqlite3") as bag:
        bag.write("/chatter", "std_msgs/msg/String", STAMP0, bag.types["std_msgs/msg/String"](data="hello"))
    with pytest.raises(IngestError, match=r"no image topics.*/chatter"):
        ingest_bag(tmp_path / "empty", tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_broken_tf_chain(tmp_path):
    _write_bag(tmp_path / "bag", tf=[(i, "map", "base_link") for i in range(4)])
    with pytest.raises(IngestError, match=r"broken tf chain.*'map' and 'camera_optical'.*camera_optical -> camera_link.*joins 'map' and 'camera_link'"):
        ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")


def test_unknown_encoding_names_topic(tmp_path):
    _write_bag(tmp_path / "bag", depth_encoding="yuv422")
    with pytest.raises(IngestError, match=r"/cam/depth: unknown depth encoding 'yuv422'"):
        ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")


def test_missing_and_corrupt_bags(tmp_path):
    with pytest.raises(IngestError, match="no such file"):
        ingest_bag(tmp_path / "nothing.bag", tmp_path / "out.mcap")
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    with pytest.raises(IngestError, match="junk.bag"):
        ingest_bag(tmp_path / "junk.bag", tmp_path / "out.mcap")
    result = CliRunner().invoke(app, ["ingest", "bag", str(tmp_path / "nothing.bag"), "--list"])
    assert isinstance(result.exception, IngestError)


def test_ambiguous_topics_listed_then_chosen(tmp_path):
    def other_camera(bag, i, stamp, header):  # a second CameraInfo, in another namespace than the depth
        bag.write("/other/info", "sensor_msgs/msg/CameraInfo", stamp, bag.camera_info(header, np.eye(3), (6, 8)))

    poses = _write_bag(tmp_path / "bag", depth_topics=("/cam/left/depth", "/cam/right/depth"), extra=other_camera)
    with pytest.raises(IngestError, match=r"several depth topics: /cam/left/depth, /cam/right/depth; choose one with --depth-topic"):
        ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")
    summary = ingest_bag(tmp_path / "bag", tmp_path / "out.mcap", depth_topic="/cam/right/depth")
    assert summary.frames == 4 and summary.topics["depth"] == "/cam/right/depth" and summary.topics["info"] == "/cam/info"
    for frame, pose in zip(RecordingReader(tmp_path / "out.mcap").frames(), poses):
        np.testing.assert_allclose(frame.pose_world_camera, pose, atol=1e-9)
        assert frame.rgb is None and np.allclose(frame.depth, 1.5)


def test_partial_bag_skips_and_counts(tmp_path):
    """Frame 0 has no tf sample before it (tf starts at frame 1): no pose. Frame 2's colour image is
    a corrupt JPEG. Frame 3's colour is 50 ms off. The stamps between tf samples interpolate."""
    def color(bag, i, stamp, header):
        data = b"\xff\xd8 not a jpeg" if i == 2 else ros_images.encode_jpeg(np.zeros((6, 8, 3), np.uint8))
        off = 50_000_000 if i == 3 else 0
        bag.write("/cam/color/compressed", "sensor_msgs/msg/CompressedImage", stamp + off,
                  bag.compressed_image(bag.header(stamp + off, "camera_optical", i), "jpeg", data))

    _write_bag(tmp_path / "bag", frames=6, tf=[(i, "map", "camera_link") for i in (1, 3, 5)], extra=color)
    summary = ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")
    assert summary.frames == 3  # frames 1, 4 and 5
    assert summary.skipped == {"no pose at the depth stamp": 1, "undecodable color image": 1,
                               "no color image within max_dt": 1}
    stamps = [frame.timestamp for frame in RecordingReader(tmp_path / "out.mcap").frames()]
    assert stamps == pytest.approx([(STAMP0 + i * 100_000_000) / 1e9 for i in (1, 4, 5)])


def test_interpolated_pose_and_odometry_source(tmp_path):
    poses = _write_bag(tmp_path / "bag", frames=5, tf=[(i, "map", "camera_link") for i in (0, 2, 4)], odometry=True)
    ingest_bag(tmp_path / "bag", tmp_path / "tf.mcap")
    interpolated = [frame.pose_world_camera for frame in RecordingReader(tmp_path / "tf.mcap").frames()]
    # The camera moves along a line with a slowly turning view: interpolation is close, exact at samples.
    np.testing.assert_allclose(interpolated[2], poses[2], atol=1e-9)
    np.testing.assert_allclose(interpolated[1][:3, 3], poses[1][:3, 3], atol=1e-9)
    assert np.abs(interpolated[1] - poses[1]).max() < 0.05

    summary = ingest_bag(tmp_path / "bag", tmp_path / "odom.mcap", pose_source="/odom")
    assert summary.world_frame == "odom" and summary.frames == 5
    for frame, pose in zip(RecordingReader(tmp_path / "odom.mcap").frames(), poses):
        np.testing.assert_allclose(frame.pose_world_camera, pose, atol=1e-9)


def test_no_poses_needs_kiss_icp(tmp_path):
    with _BagWriter(tmp_path / "bag", 2, "sqlite3") as bag:
        for i in range(3):
            stamp = STAMP0 + i * 100_000_000
            header = bag.header(stamp, "camera_optical", i)
            bag.write("/depth", "sensor_msgs/msg/Image", stamp, bag.image(header, np.full((6, 8), 900, np.uint16), "16UC1"))
            bag.write("/info", "sensor_msgs/msg/CameraInfo", stamp, bag.camera_info(header, np.eye(3) * 5, (6, 8)))
    with pytest.raises(IngestError, match="--poses kiss-icp"):
        ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")
    moved = np.eye(4)
    moved[0, 3] = 0.5
    summary = ingest_bag(tmp_path / "bag", tmp_path / "out.mcap", estimate_poses=lambda frame: moved)
    assert summary.frames == 3 and summary.pose_source == "estimated"
    assert all(np.allclose(f.pose_world_camera, moved) for f in RecordingReader(tmp_path / "out.mcap").frames())


@pytest.mark.slow
def test_detection_survives_a_ros1_round_trip(tmp_path):
    from ndfa.run.detect import run_detection

    paths = {}
    for session in ("source", "target"):
        export_bag(SAMPLE / f"{session}.mcap", tmp_path / f"{session}.bag")
        ingest_bag(tmp_path / f"{session}.bag", tmp_path / f"{session}.mcap")
        paths[session] = tmp_path / f"{session}.mcap"

    def changes(source, target):
        return [(c.session, c.object_id, c.kind) for c in run_detection(source, target).changes]

    expected = changes(SAMPLE / "source.mcap", SAMPLE / "target.mcap")
    assert expected and changes(paths["source"], paths["target"]) == expected


def test_image_decoders():
    from types import SimpleNamespace as Message

    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.pad(rgb[:, :, ::-1].reshape(2, 9), ((0, 0), (0, 3)))  # bgr8 rows with 3 bytes of padding
    bgr = Message(encoding="bgr8", height=2, width=3, step=12, is_bigendian=0, data=padded.ravel())
    np.testing.assert_array_equal(ros_images.color_from_image(bgr), rgb)

    mm = np.array([[0, 1000], [65535, 1234]], dtype=np.uint16)
    big = Message(encoding="mono16", height=2, width=2, step=4, is_bigendian=1, data=mm.astype(">u2").view(np.uint8).ravel())
    np.testing.assert_allclose(ros_images.depth_from_image(big), mm / 1000.0, rtol=1e-6)
    metres = np.array([[np.nan, 1.5], [-1.0, 0.25]], dtype=np.float32)
    float_depth = Message(encoding="32FC1", height=2, width=2, step=8, is_bigendian=0, data=metres.view(np.uint8).ravel())
    np.testing.assert_array_equal(ros_images.depth_from_image(float_depth), [[0.0, 1.5], [0.0, 0.25]])

    # compressedDepth of 32FC1: quantised inverse depth, value = a / depth + b, 0 = invalid.
    quant_a, quant_b, depth = 100.0 * 101.0, 1.0 - 100.0 * 101.0 / 10.0, np.array([[0.0, 2.0], [4.0, 0.5]])
    values = np.where(depth > 0, np.rint(quant_a / np.where(depth > 0, depth, 1) + quant_b), 0).astype(np.uint16)
    data = ros_images.COMPRESSED_DEPTH_HEADER.pack(0, quant_a, quant_b) + ros_images.encode_png(values)
    decoded = ros_images.depth_from_compressed(Message(format="32FC1; compressedDepth png", data=np.frombuffer(data, np.uint8)))
    np.testing.assert_allclose(decoded, depth, atol=1e-3)

    with pytest.raises(ros_images.UnknownEncodingError, match="yuv422"):
        ros_images.depth_from_image(Message(encoding="yuv422", height=1, width=1, step=2, is_bigendian=0, data=b"ab"))
    with pytest.raises(ros_images.ImageDecodeError):
        ros_images.depth_from_image(Message(encoding="16UC1", height=4, width=4, step=8, is_bigendian=0, data=np.zeros(5, np.uint8)))


# -- bad input found by the fuzz suite (issue 18) -------------------------------------------------------

def test_a_broken_metadata_yaml_is_one_line(tmp_path):
    """The YAML parser's report (several lines, with a caret under the column) summarised."""
    _write_bag(tmp_path / "bag")
    text = (tmp_path / "bag" / "metadata.yaml").read_text().splitlines()
    text[2] = "{"
    (tmp_path / "bag" / "metadata.yaml").write_text("\n".join(text) + "\n")
    with pytest.raises(IngestError) as raised:
        ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")
    message = str(raised.value)
    assert "\n" not in message and "metadata.yaml is not valid YAML" in message and "at line" in message
    assert not (tmp_path / "out.mcap").exists()


def test_a_metadata_yaml_value_of_the_wrong_type_is_one_line(tmp_path):
    _write_bag(tmp_path / "bag")
    path = tmp_path / "bag" / "metadata.yaml"
    path.write_text(path.read_text().replace("name: /cam/info", "name: {}"))
    with pytest.raises(IngestError, match=r"metadata.yaml holds a value of the wrong type"):
        ingest_bag(tmp_path / "bag", tmp_path / "out.mcap")


def test_a_damaged_ros1_record_is_one_line(tmp_path):
    """rosbags' ROS1 reader asserts record sizes: a bare AssertionError once escaped."""
    corpus = Path(__file__).resolve().parent / "fuzz" / "corpus" / "regressions" / "bag" / "ros1-record-size.bag"
    with pytest.raises(IngestError, match=r"ros1-record-size.bag: cannot read the bag: a record's sizes do not match"):
        ingest_bag(corpus, tmp_path / "out.mcap")


def test_zero_quaternions_in_tf_and_nan_intrinsics_skip_frames(tmp_path):
    """A zero quaternion on /tf once became a NaN pose (and a numpy warning); NaN intrinsics a
    ValueError from Frame. The tf sample is refused (frame 1's pose is interpolated between its
    neighbours'), the frame with NaN intrinsics skipped and counted, the others imported."""
    import warnings

    from tests.fuzz.bag_inputs import write_broken_bag

    bag = write_broken_bag(tmp_path / "broken", {"version": (2, "sqlite3"), "frames": 3, "value": 0,
                                                 "breaks": [("tf zero quaternion", 1), ("info nan K", 2)]})
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        summary = ingest_bag(bag, tmp_path / "out.mcap")
    assert summary.frames == 2
    assert summary.skipped == {"invalid frame (K must be a finite (3, 3) matrix, got shape (3, 3))": 1}
    for frame in RecordingReader(tmp_path / "out.mcap").frames():
        assert np.all(np.isfinite(frame.pose_world_camera))


def test_a_damaged_sqlite_bag_is_one_line(small_recording, tmp_path):
    """rosbags reads ROS2 sqlite3 storage with apsw, whose CorruptError once escaped as a traceback."""
    bag = tmp_path / "run"
    export_bag(small_recording, bag, version=2, storage="sqlite3")
    database = bag / "run.db3"
    data = bytearray(database.read_bytes())
    data[len(data) // 2:] = bytes(len(data) - len(data) // 2)  # the second half zeroed
    database.write_bytes(bytes(data))
    with pytest.raises(IngestError, match=r"run: (the bag is corrupt|cannot read the bag): "):
        ingest_bag(bag, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_a_ros1_message_of_an_unknown_connection_is_one_line(tmp_path):
    """rosbags' ROS1 reader once let a KeyError out for a record naming connection 256 of 9."""
    corpus = Path(__file__).resolve().parent / "fuzz" / "corpus" / "regressions" / "bag" / "ros1-unknown-connection.bag"
    with pytest.raises(IngestError, match=r"ros1-unknown-connection.bag: the bag is corrupt: rosbags cannot read it "
                                          r"\(KeyError: 256\)"):
        ingest_bag(corpus, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_a_camera_info_with_zero_focal_lengths_skips_its_frame(tmp_path):
    """A CameraInfo with K all zero once imported fine and left a recording its reader refuses
    (found by the long fuzz pass): the frame is skipped and counted like NaN intrinsics."""
    from tests.fuzz.bag_inputs import write_broken_bag

    bag = write_broken_bag(tmp_path / "broken", {"version": (2, "sqlite3"), "frames": 3, "value": 0,
                                                 "breaks": [("info zero K", 1)]})
    summary = ingest_bag(bag, tmp_path / "out.mcap")
    assert summary.frames == 2
    assert summary.skipped == {"invalid frame (K must have focal lengths fx, fy > 0, got fx 0, fy 0)": 1}
    assert len(list(RecordingReader(tmp_path / "out.mcap").frames())) == 2
