"""`ndfa ingest bag`: a ROS1 `.bag` or a ROS2 bag (directory, sqlite3 or mcap storage) -> a recording.

rosbags reads every kind of bag without a ROS install (`AnyReader`). The importer picks the topics
(depth, colour, CameraInfo, masks, poses) by type and name when that is unambiguous and asks for a
flag otherwise, then reads the bag twice:

1. a scan of the small messages and of every image header: tf, CameraInfo, the pose topic, the
   stamps of the images and their encodings (an unknown encoding stops the import here, before
   anything is written);
2. a stream of the image messages, decoding only those that make a frame.

A frame is one depth image: the colour image and the mask nearest in stamp within `max_dt`, the
CameraInfo nearest in stamp, and the camera pose at the depth stamp, interpolated through the tf
tree (or along an Odometry / PoseStamped topic). ROS camera optical frames already use OpenCV axes
(x right, y down, z forward), so the pose of the depth image's own frame (its header.frame_id, an
`*_optical_frame` in a well-formed bag) is `pose_world_camera` as it is.

Partly readable bags are imported as far as they go: a frame without a pose at its stamp, without
a colour image or mask close enough, or with an undecodable image is skipped and counted by reason
in `BagSummary.skipped`.

ndfa's own extension, written by `ndfa export bag`: a std_msgs/String on /ndfa/ground_truth holds
the recording's ground-truth JSON, and geometry_msgs/PoseStamped on /ndfa/ground_truth/pose the
true camera pose when the recorded one is perturbed; both come back into the recording.
"""

from __future__ import annotations

import bisect
import json
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Rosbag1Error
from rosbags.rosbag2 import ReaderError as Rosbag2Error
from rosbags.typesys import Stores, get_typestore

import ndfa
from ndfa.core.errors import IngestError, RecordingError
from ndfa.core.geometry import make_pose, matrix_from_quaternion_xyzw, quaternion_xyzw_from_matrix
from ndfa.io.ingest import PoseEstimator, ros_images
from ndfa.io.ingest.bag_topics import (
    COMPRESSED_IMAGE, GROUND_TRUTH_POSE_TOPIC, GROUND_TRUTH_TOPIC, IMAGE, ODOMETRY, TF_MESSAGE, BagTopic,
    choose_pose_source, choose_topics, describe_topics)
from ndfa.io.ingest.ros_images import ImageDecodeError, UnknownEncodingError
from ndfa.io.ingest.tf_buffer import TfLookupError, TransformBuffer, frame_name, stamp_ns
from ndfa.io.recording import Frame, RecordingWriter

# Bag errors rosbags raises for missing, truncated or malformed bags.
_BAG_ERRORS = (AnyReaderError, Rosbag1Error, Rosbag2Error)
# Preferred world frames of a tf tree, in order (REP 105); otherwise the root of the camera's tree.
WORLD_FRAMES = ("map", "odom", "world")


@dataclass
class BagSummary:
    """What `ingest_bag` wrote and what it left out."""

    bag: Path
    out: Path
    frames: int
    depth_messages: int
    topics: dict[str, str]  # role -> topic
    pose_source: str  # "tf", a topic, or "estimated"
    world_frame: str | None
    camera_frame: str
    skipped: dict[str, int] = field(default_factory=dict)  # reason -> frames
    instances: bool = False
    ground_truth: bool = False
    size_bytes: int = 0


def list_topics(path: str | Path) -> list[BagTopic]:
    """Every topic of the bag with its type, message count and guessed role (for `--list`)."""
    path = Path(path)
    with open_bag(path) as reader:
        return describe_topics(reader, path)


@contextmanager
def open_bag(path: Path) -> Iterator[AnyReader]:
    """An open AnyReader; missing, unreadable and corrupt bags become one IngestError naming the file."""
    if not path.exists():
        raise IngestError(f"{path}: no such file or directory")
    if path.is_file() and path.suffix not in (".bag", ".mcap", ".db3"):
        raise IngestError(f"{path}: not a bag: ROS1 bags end in .bag; ROS2 bags are directories "
                          "(or a single .db3 or .mcap file)")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except (*_BAG_ERRORS, OSError, KeyError, ValueError) as error:
        hint = " (ROS2 bags are directories with a metadata.yaml, or a ROS2 .mcap/.db3 file; ndfa recordings " \
               "are not bags)" if path.suffix == ".mcap" else ""
        if "index" in str(error).lower() and path.suffix == ".bag":
            hint = " (a ROS1 bag whose recording was cut off has no index: `rosbag reindex` repairs it)"
        raise IngestError(f"{path}: cannot read the bag: {error}{hint}") from None
    try:
        yield reader
    except _BAG_ERRORS as error:
        raise IngestError(f"{path}: the bag is corrupt: {error}") from None
    finally:
        reader.close()


def ingest_bag(
    path: str | Path,
    out: str | Path,
    *,
    rgb_topic: str | None = None,
    depth_topic: str | None = None,
    info_topic: str | None = None,
    mask_topic: str | None = None,
    pose_source: str | None = None,
    world_frame: str | None = None,
    camera_frame: str | None = None,
    max_dt: float = 0.02,
    estimate_poses: PoseEstimator | None = None,
    on_progress: Progress | None = None,
) -> BagSummary:
    """Import one bag into the recording `out`.

    Topics left None are found by type and name (an error lists the candidates when there are
    several). `pose_source` is "tf" or an Odometry/PoseStamped topic (default: tf when the bag has
    it, else its one pose topic). `world_frame` defaults to map, odom or world (the first in tf),
    `camera_frame` to the depth images' header.frame_id. `max_dt` (s) is how far in stamp a colour
    image or mask may be from its depth image. With `estimate_poses`, poses come from it instead of
    the bag (the bag's pose of the first frame, if any, anchors them). `on_progress(done, total)`
    follows the frames.
    """
    path, out = Path(path), Path(out)
    with open_bag(path) as reader:
        topics = {topic.name: topic for topic in describe_topics(reader, path)}
        chosen = choose_topics(path, topics, rgb_topic, depth_topic, info_topic, mask_topic)
        pose_topic = choose_pose_source(path, topics, pose_source, need=estimate_poses is None)
        scan = _scan(reader, path, chosen, pose_topic)
        camera = frame_name(camera_frame or scan.camera_frame)
        poses, world = _pose_lookup(path, scan, pose_topic, world_frame, camera, required=estimate_poses is None)
        plans, skipped = _plan_frames(scan, chosen, poses, round(max_dt * 1e9))
        meta = {
            "source": "rosbag",
            "session": path.stem if path.is_file() else path.name,
            "bag": str(path),
            "topics": chosen,
            "pose_source": "estimated" if estimate_poses else (pose_topic or "none"),
            "world_frame": world,
            "camera_frame": camera,
            "poses": "estimated" if estimate_poses else "given",
            "instances": "bag" if "mask" in chosen else "none",
            "generator": f"ndfa {ndfa.__version__} ingest bag",
        }
        written = _write_frames(reader, path, out, meta, chosen, plans, skipped, scan, estimate_poses, on_progress)
    return BagSummary(
        bag=path, out=out, frames=written, depth_messages=len(scan.stamps["depth"]), topics=chosen,
        pose_source=meta["pose_source"], world_frame=world, camera_frame=camera, skipped=dict(skipped),
        instances="mask" in chosen, ground_truth=scan.ground_truth is not None, size_bytes=out.stat().st_size,
    )


# --- the scan -------------------------------------------------------------------------------------

@dataclass
class _Scan:
    """What the first pass learns: stamps of each image role (in message order), intrinsics, transforms."""

    stamps: dict[str, list[int | None]]  # None: a message that could not be read
    camera_frame: str
    infos: list[tuple[int, np.ndarray, tuple[int, int]]]  # (stamp, K, (height, width)), sorted
    tf: TransformBuffer
    pose_samples: list[tuple[int, str, str, np.ndarray]]  # (stamp, parent, child, T_parent_child)
    true_poses: dict[int, np.ndarray]
    ground_truth: dict | None


def _scan(reader: AnyReader, path: Path, chosen: dict[str, str], pose_topic: str | None) -> _Scan:
    role_of = {topic: role for role, topic in chosen.items()}
    topics = reader.topics
    wanted = set(chosen.values()) | {name for name, info in topics.items() if info.msgtype == TF_MESSAGE}
    wanted |= {t for t in (pose_topic, GROUND_TRUTH_TOPIC, GROUND_TRUTH_POSE_TOPIC) if t in topics}
    connections = [c for c in reader.connections if c.topic in wanted]
    scan = _Scan({role: [] for role in ("depth", "color", "mask")}, "", [], TransformBuffer(), [], {}, None)
    for connection, _, data in reader.messages(connections=connections):
        topic = connection.topic
        role = role_of.get(topic)
        try:
            message = reader.deserialize(data, connection.msgtype)
        except AnyReaderError:
            if role in scan.stamps:  # keep the message's place: the second pass counts messages
                scan.stamps[role].append(None)
            continue
        if role in ("depth", "color", "mask"):
            _check_encoding(path, topic, role, connection.msgtype, message)
            scan.stamps[role].append(stamp_ns(message.header.stamp))
            if role == "depth" and not scan.camera_frame:
                scan.camera_frame = message.header.frame_id
        elif role == "info":
            K = np.asarray(message.K if hasattr(message, "K") else message.k, dtype=float).reshape(3, 3)
            scan.infos.append((stamp_ns(message.header.stamp), K, (int(message.height), int(message.width))))
        elif connection.msgtype == TF_MESSAGE:
            scan.tf.add_message(message, static="static" in topic)
        elif topic == pose_topic:
            pose = message.pose.pose if connection.msgtype == ODOMETRY else message.pose
            child = message.child_frame_id if connection.msgtype == ODOMETRY else ""
            scan.pose_samples.append((stamp_ns(message.header.stamp), message.header.frame_id, child, _pose_matrix(pose)))
        elif topic == GROUND_TRUTH_TOPIC:
            scan.ground_truth = _ground_truth(path, message.data)
        elif topic == GROUND_TRUTH_POSE_TOPIC:
            scan.true_poses[stamp_ns(message.header.stamp)] = _pose_matrix(message.pose)
    scan.infos.sort(key=lambda info: info[0])
    if not any(stamp is not None for stamp in scan.stamps["depth"]):
        raise IngestError(f"{path}: the depth topic {chosen['depth']} has no readable messages")
    if not scan.infos:
        raise IngestError(f"{path}: the CameraInfo topic {chosen['info']} has no readable messages")
    return scan


def _check_encoding(path: Path, topic: str, role: str, msgtype: str, message: object) -> None:
    if msgtype == IMAGE:
        known = {"depth": ros_images.DEPTH_ENCODINGS, "color": ros_images.COLOR_ENCODINGS,
                 "mask": ros_images.MASK_ENCODINGS}[role]
        if message.encoding not in known:
            raise IngestError(f"{path}: topic {topic}: unknown {role} encoding {message.encoding!r} "
                              f"(ndfa reads {', '.join(known)})")
    else:
        fmt = message.format.lower()
        readable = "png" in fmt or (role == "color" and ("jpeg" in fmt or "jpg" in fmt))
        if not readable:
            raise IngestError(f"{path}: topic {topic}: unknown {role} compressed format {message.format!r} "
                              f"(ndfa reads {'png, compressedDepth png' if role != 'color' else 'jpeg, png'})")


def _pose_matrix(pose: object) -> np.ndarray:
    p, q = pose.position, pose.orientation
    return make_pose(matrix_from_quaternion_xyzw(np.array([q.x, q.y, q.z, q.w])), np.array([p.x, p.y, p.z]))


def _ground_truth(path: Path, text: str) -> dict:
    try:
        truth = json.loads(text)
    except json.JSONDecodeError as error:
        raise IngestError(f"{path}: {GROUND_TRUTH_TOPIC} is not JSON: {error}") from None
    if not isinstance(truth, dict):
        raise IngestError(f"{path}: {GROUND_TRUTH_TOPIC} must hold a JSON object")
    return truth


# --- poses ----------------------------------------------------------------------------------------

PoseLookup = Callable[[int], np.ndarray | None]


def _pose_lookup(path: Path, scan: _Scan, pose_topic: str | None, world: str | None, camera: str,
                 required: bool) -> tuple[PoseLookup, str | None]:
    """A function stamp -> pose_world_camera (None where there is none), and the world frame."""
    if pose_topic is None:
        return (lambda stamp: None), None
    buffer = scan.tf
    if pose_topic != "tf":
        if not scan.pose_samples:
            raise IngestError(f"{path}: the pose topic {pose_topic} has no readable messages")
        _, parent, child, _ = scan.pose_samples[0]
        # A PoseStamped carries no child frame: its pose is taken to be the camera's.
        child = child or camera
        buffer.remove(child)
        for stamp, _, _, pose in scan.pose_samples:
            buffer.add(parent, child, stamp, pose[:3, 3], quaternion_xyzw_from_matrix(pose[:3, :3]), static=False)
        world = world or frame_name(parent)
    if camera not in buffer.frames:
        if required:
            raise IngestError(f"{path}: the camera frame {camera!r} is not in tf (frames: "
                              f"{', '.join(sorted(buffer.frames)) or 'none'}); choose it with --camera-frame")
        return (lambda stamp: None), None
    if world is None:
        ancestors = buffer.ancestors(camera)
        # A map (odom, world) the camera connects to; else one it should connect to (the lookup then
        # names the break); else the root of the camera's own tree.
        world = next((f for f in WORLD_FRAMES if f in ancestors),
                     next((f for f in WORLD_FRAMES if f in buffer.frames), ancestors[-1]))
    world = frame_name(world)
    if not buffer.connects(world, camera):
        if required:
            raise IngestError(f"{path}: broken tf chain: {buffer.describe_break(world, camera)}")
        return (lambda stamp: None), None  # poses are estimated; the bag's only anchored them

    def lookup(stamp: int) -> np.ndarray | None:
        try:
            return buffer.lookup(world, camera, stamp)
        except TfLookupError:
            return None

    return lookup, world


# --- frames ---------------------------------------------------------------------------------------

@dataclass
class _Plan:
    """One frame to write: which message of each role it is made of, its intrinsics and pose."""

    stamp: int
    parts: dict[str, int]  # role -> message ordinal within its topic
    K: np.ndarray
    image_size: tuple[int, int]
    pose: np.ndarray | None
    true_pose: np.ndarray | None


def _plan_frames(scan: _Scan, chosen: dict[str, str], poses: PoseLookup, max_dt_ns: int) -> tuple[list[_Plan], Counter]:
    skipped: Counter = Counter()
    sorted_stamps = {role: _by_stamp(stamps) for role, stamps in scan.stamps.items()}
    skipped["unreadable depth message"] = scan.stamps["depth"].count(None)
    info_stamps = [info[0] for info in scan.infos]
    plans, last_stamp = [], None
    for stamp, ordinal in zip(*sorted_stamps["depth"]):
        if stamp == last_stamp:
            skipped["duplicate depth stamp"] += 1
            continue
        parts = {"depth": ordinal}
        for role in ("color", "mask"):
            if role in chosen:
                match = _nearest(sorted_stamps[role], stamp, max_dt_ns)
                if match is None:
                    parts = None
                    skipped[f"no {role} image within max_dt"] += 1
                    break
                parts[role] = match
        if parts is None:
            continue
        _, K, size = scan.infos[_nearest_index(info_stamps, stamp)]
        plans.append(_Plan(stamp, parts, K, size, poses(stamp), scan.true_poses.get(stamp)))
        last_stamp = stamp
    return plans, skipped


def _by_stamp(stamps: list[int | None]) -> tuple[list[int], list[int]]:
    """The readable messages' stamps, sorted, and each one's ordinal (place in its topic)."""
    pairs = sorted((stamp, ordinal) for ordinal, stamp in enumerate(stamps) if stamp is not None)
    return [stamp for stamp, _ in pairs], [ordinal for _, ordinal in pairs]


def _nearest(stamps_ordinals: tuple[list[int], list[int]], stamp: int, max_dt_ns: int) -> int | None:
    """The ordinal of the message nearest to `stamp`, if within `max_dt_ns`."""
    stamps, ordinals = stamps_ordinals
    if not stamps:
        return None
    index = _nearest_index(stamps, stamp)
    return ordinals[index] if abs(stamps[index] - stamp) <= max_dt_ns else None


def _nearest_index(stamps: list[int], stamp: int) -> int:
    right = bisect.bisect_left(stamps, stamp)
    if right == 0:
        return 0
    if right == len(stamps):
        return len(stamps) - 1
    return right if stamps[right] - stamp < stamp - stamps[right - 1] else right - 1


_DECODERS = {
    ("depth", IMAGE): ros_images.depth_from_image, ("depth", COMPRESSED_IMAGE): ros_images.depth_from_compressed,
    ("color", IMAGE): ros_images.color_from_image, ("color", COMPRESSED_IMAGE): ros_images.color_from_compressed,
    ("mask", IMAGE): ros_images.mask_from_image, ("mask", COMPRESSED_IMAGE): ros_images.mask_from_compressed,
}
_UNDECODABLE = object()  # marks an image that was read but could not be decoded


def _write_frames(reader: AnyReader, path: Path, out: Path, meta: dict, chosen: dict[str, str], plans: list[_Plan],
                  skipped: Counter, scan: _Scan, estimate_poses: PoseEstimator | None,
                  on_progress: Callable[[int, int], None] | None) -> int:
    """Second pass: decode the images the plans use, in bag order, and write each frame as soon as
    its parts are there (frames in stamp order; only the images still waiting are held)."""
    if estimate_poses is None:
        for plan in plans:
            if plan.pose is None:
                skipped["no pose at the depth stamp"] += 1
        plans = [plan for plan in plans if plan.pose is not None]
    uses = Counter((role, ordinal) for plan in plans for role, ordinal in plan.parts.items())
    role_of = {topic: role for role, topic in chosen.items() if role != "info"}
    images: dict[tuple[str, int], object] = {}
    ordinals = Counter()
    next_plan, written, image_size = 0, 0, []
    try:
        with RecordingWriter(out, meta) as writer:
            if scan.ground_truth is not None:
                writer.write_ground_truth(scan.ground_truth)
            connections = [c for c in reader.connections if c.topic in role_of]
            for connection, _, data in reader.messages(connections=connections):
                role = role_of[connection.topic]
                key = (role, ordinals[role])
                ordinals[role] += 1
                if key not in uses:
                    continue
                images[key] = _decode(reader, role, connection.msgtype, data)
                while next_plan < len(plans) and all((r, o) in images for r, o in plans[next_plan].parts.items()):
                    plan = plans[next_plan]
                    next_plan += 1
                    parts = {}
                    for part in plan.parts.items():
                        parts[part[0]] = images[part] if uses[part] > 1 else images.pop(part)
                        uses[part] -= 1
                    written += _write_frame(writer, path, chosen, plan, parts, written, image_size, skipped,
                                            estimate_poses)
                    if on_progress is not None:
                        on_progress(next_plan, len(plans))
            skipped["image messages missing from the bag"] += len(plans) - next_plan
            if written == 0:
                reasons = ", ".join(f"{n} {why}" for why, n in skipped.items() if n) or "the bag has no frames"
                raise IngestError(f"{path}: no frame could be imported ({reasons})")
    except RecordingError as error:
        raise IngestError(f"{path}: cannot write {out}: {error}") from None
    for reason in [r for r, n in skipped.items() if n == 0]:
        del skipped[reason]
    return written


def _decode(reader: AnyReader, role: str, msgtype: str, data: bytes) -> object:
    try:
        return _DECODERS[role, msgtype](reader.deserialize(data, msgtype))
    except (AnyReaderError, ImageDecodeError, UnknownEncodingError):
        return _UNDECODABLE


def _write_frame(writer: RecordingWriter, path: Path, chosen: dict[str, str], plan: _Plan, parts: dict[str, object],
                 index: int, image_size: list, skipped: Counter, estimate_poses: PoseEstimator | None) -> int:
    """Write one frame; 1 if written, 0 if skipped (and counted). `image_size` holds the first frame's."""
    broken = [role for role, image in parts.items() if image is _UNDECODABLE]
    if broken:
        skipped[f"undecodable {broken[0]} image"] += 1
        return 0
    depth = parts["depth"]
    for role in ("color", "mask"):
        if role in parts and parts[role].shape[:2] != depth.shape:
            raise IngestError(f"{path}: {role} images of {chosen[role]} are {parts[role].shape[1]}x{parts[role].shape[0]}, "
                              f"depth images of {chosen['depth']} {depth.shape[1]}x{depth.shape[0]}: ndfa needs depth "
                              "registered to the colour camera (e.g. an aligned_depth_to_color topic)")
    if plan.image_size[0] and plan.image_size != depth.shape:
        raise IngestError(f"{path}: CameraInfo {chosen['info']} is for {plan.image_size[1]}x{plan.image_size[0]} images, "
                          f"but the depth images of {chosen['depth']} are {depth.shape[1]}x{depth.shape[0]}; "
                          "choose the depth camera's CameraInfo with --info-topic")
    if image_size and image_size[0] != depth.shape:
        skipped["image size changed"] += 1
        return 0
    image_size[:] = [depth.shape]
    frame = Frame(index=index, timestamp=plan.stamp / 1e9, rgb=parts.get("color"), depth=depth, K=plan.K,
                  pose_world_camera=plan.pose if plan.pose is not None else np.eye(4),
                  instances=parts.get("mask"), pose_world_camera_true=plan.true_pose)
    if estimate_poses is not None:
        frame.pose_world_camera = np.asarray(estimate_poses(frame), dtype=np.float64)
    writer.write_frame(frame)
    return 1
