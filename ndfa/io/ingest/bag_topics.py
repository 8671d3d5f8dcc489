"""Which topics of a ROS bag the importer reads: message types, ndfa's own topics, and the choice
of the depth, colour, mask, CameraInfo and pose topics by type and name (or by flag)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rosbags.highlevel import AnyReader, AnyReaderError

from ndfa.core.errors import IngestError
from ndfa.io.ingest import ros_images

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_TYPES = (ODOMETRY, POSE_STAMPED)
IMU = "sensor_msgs/msg/Imu"

# ndfa's extension topics: the ground-truth JSON (std_msgs/String) and the true camera pose when the
# recorded one is perturbed (PoseStamped); `ndfa export bag` writes them, the importer reads them back.
GROUND_TRUTH_TOPIC = "/ndfa/ground_truth"
GROUND_TRUTH_POSE_TOPIC = "/ndfa/ground_truth/pose"

# Topic names that mark an instance/label image rather than depth (mono16 looks alike).
_MASK_WORDS = ("instance", "mask", "label", "segment")


@dataclass(frozen=True)
class BagTopic:
    """One topic of a bag, and the role the importer would give it (depth, color, mask, info, tf, pose)."""

    name: str
    msgtype: str
    count: int
    role: str | None = None
    encoding: str | None = None  # of the first message, for image topics


def describe_topics(reader: AnyReader, path: Path) -> list[BagTopic]:
    described = []
    for name, info in sorted(reader.topics.items()):
        msgtype = info.msgtype or "?"
        encoding = None
        if msgtype in (IMAGE, COMPRESSED_IMAGE) and info.msgcount:
            first = first_message(reader, info.connections)
            if first is not None:
                encoding = first.encoding if msgtype == IMAGE else first.format
        described.append(BagTopic(name, msgtype, info.msgcount, guess_role(name, msgtype, encoding), encoding))
    return described


def first_message(reader: AnyReader, connections: list) -> object | None:
    for connection, _, data in reader.messages(connections=connections):
        try:
            return reader.deserialize(data, connection.msgtype)
        except AnyReaderError:
            return None
    return None


def guess_role(name: str, msgtype: str, encoding: str | None) -> str | None:
    lowered = name.lower()
    if msgtype == CAMERA_INFO:
        return "info"
    if msgtype == TF_MESSAGE:
        return "tf"
    if msgtype in POSE_TYPES:
        return "ground truth pose" if name == GROUND_TRUTH_POSE_TOPIC else "pose"
    if msgtype == IMU:
        # RealSense publishes its gyro as an Imu too (accelerations zero): only an accelerometer tells up.
        return None if "gyro" in lowered else "imu"
    if msgtype not in (IMAGE, COMPRESSED_IMAGE) or encoding is None:
        return None
    if any(word in lowered for word in _MASK_WORDS):
        return "mask"
    if msgtype == COMPRESSED_IMAGE:
        return "depth" if "compresseddepth" in encoding.lower() or "depth" in lowered else "color"
    if encoding in ("16UC1", "mono16", "32FC1") or "depth" in lowered:
        return "depth"
    return "color" if encoding in ros_images.COLOR_ENCODINGS else None


def choose_topics(path: Path, topics: dict[str, BagTopic], rgb: str | None, depth: str | None,
                   info: str | None, mask: str | None) -> dict[str, str]:
    """role -> topic for depth, info, and color and mask when the bag has them."""
    images = [t for t in topics.values() if t.msgtype in (IMAGE, COMPRESSED_IMAGE)]
    if not images:
        raise IngestError(f"{path}: the bag has no image topics (sensor_msgs/Image or CompressedImage); "
                          f"its topics: {topic_list(topics.values())}")
    chosen = {}
    for role, asked, types, flag in (("depth", depth, (IMAGE, COMPRESSED_IMAGE), "--depth-topic"),
                                     ("color", rgb, (IMAGE, COMPRESSED_IMAGE), "--rgb-topic"),
                                     ("mask", mask, (IMAGE, COMPRESSED_IMAGE), "--mask-topic"),
                                     ("info", info, (CAMERA_INFO,), "--info-topic")):
        if asked is not None:
            if asked not in topics:
                raise IngestError(f"{path}: no topic {asked!r} ({flag}); its topics: {topic_list(topics.values())}")
            if topics[asked].msgtype not in types:
                raise IngestError(f"{path}: {flag} {asked} is a {topics[asked].msgtype}, expected {' or '.join(types)}")
            chosen[role] = asked
            continue
        candidates = prefer_uncompressed([t.name for t in topics.values() if t.role == role and t.count])
        if role == "info" and len(candidates) > 1:
            candidates = nearest_namespace(candidates, chosen["depth"])
        if len(candidates) > 1:
            raise IngestError(f"{path}: several {role} topics: {', '.join(candidates)}; choose one with {flag}")
        if candidates:
            chosen[role] = candidates[0]
        elif role == "depth":
            raise IngestError(f"{path}: no depth image topic found (16UC1/32FC1 Image, compressedDepth, or a name "
                              f"with 'depth'); choose one with --depth-topic from: {topic_list(images)}")
        elif role == "info":
            raise IngestError(f"{path}: no sensor_msgs/CameraInfo topic: ndfa needs the depth camera's intrinsics")
    if chosen.get("color") == chosen["depth"]:
        del chosen["color"]
    return chosen


def nearest_namespace(candidates: list[str], topic: str) -> list[str]:
    """The candidate whose namespace is the longest prefix of `topic` (/camera/depth/camera_info for
    /camera/depth/image_raw/compressedDepth), if exactly one is; else all of them."""
    depth_of = {c: c.rsplit("/", 1)[0].count("/") for c in candidates if topic.startswith(c.rsplit("/", 1)[0] + "/")}
    deepest = [c for c, depth in depth_of.items() if depth == max(depth_of.values(), default=-1)]
    return deepest if len(deepest) == 1 else candidates


def prefer_uncompressed(names: list[str]) -> list[str]:
    """image_transport publishes X and X/compressed (X/compressedDepth): the same stream; keep X."""
    return [n for n in names if n.rsplit("/", 1)[0] not in names or n.rsplit("/", 1)[1] not in
            ("compressed", "compressedDepth", "theora")]


def choose_pose_source(path: Path, topics: dict[str, BagTopic], asked: str | None, need: bool) -> str | None:
    has_tf = any(t.role == "tf" and t.count for t in topics.values())
    if asked == "tf":
        if not has_tf:
            raise IngestError(f"{path}: --pose-topic tf, but the bag has no /tf or /tf_static messages")
        return "tf"
    if asked is not None:
        if asked not in topics or topics[asked].msgtype not in POSE_TYPES:
            found = [t.name for t in topics.values() if t.role == "pose"]
            raise IngestError(f"{path}: {asked!r} is not a nav_msgs/Odometry or geometry_msgs/PoseStamped topic "
                              f"of the bag (pose topics: {', '.join(found) or 'none'}; or 'tf')")
        return asked
    pose_topics = [t.name for t in topics.values() if t.role == "pose" and t.count]
    if any(t.role == "tf" and t.count and "static" not in t.name for t in topics.values()):
        return "tf"
    if len(pose_topics) == 1:
        return pose_topics[0]
    if len(pose_topics) > 1 and need:
        raise IngestError(f"{path}: no /tf, and several pose topics: {', '.join(pose_topics)}; choose one with --pose-topic")
    if has_tf:
        return "tf"  # only /tf_static: a fixed camera, or a world frame published as static
    if need:
        raise IngestError(f"{path}: the bag has no camera poses (no /tf, Odometry or PoseStamped topic); "
                          "pass --poses kiss-icp to estimate them from depth")
    return None


def choose_imu_topic(path: Path, topics: dict[str, BagTopic], asked: str | None) -> tuple[str | None, str]:
    """The sensor_msgs/Imu topic whose accelerometer gives world up, and a note when there is none:
    `asked` (--imu-topic), else the bag's one IMU topic (a gyro-only topic does not count). With
    several, none is used (the IMU is optional: the import goes on) and the note names them."""
    if asked is not None:
        if asked not in topics or topics[asked].msgtype != IMU:
            found = [t.name for t in topics.values() if t.msgtype == IMU]
            raise IngestError(f"{path}: --imu-topic {asked!r} is not a sensor_msgs/Imu topic of the bag "
                              f"(Imu topics: {', '.join(found) or 'none'})")
        return asked, ""
    candidates = [t.name for t in topics.values() if t.role == "imu" and t.count]
    if len(candidates) > 1:
        return None, f"several IMU topics ({', '.join(candidates)}), none used: choose one with --imu-topic"
    return (candidates[0], "") if candidates else (None, "no IMU topic")


def topic_list(topics: object) -> str:
    return ", ".join(f"{t.name} ({t.msgtype})" for t in topics) or "none"
