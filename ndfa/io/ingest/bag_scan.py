"""The first pass of `ndfa ingest bag`: tf, CameraInfo, the pose topic and the images' stamps.

It reads the small messages and the header of every image, so that an unknown image encoding, a
topic without readable messages or a broken ground truth stops the import before anything is
written, and the frames can be planned (`bag_frames.py`) from stamps alone.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader, AnyReaderError

from ndfa.core.errors import IngestError
from ndfa.core.geometry import make_pose, matrix_from_quaternion_xyzw
from ndfa.io.ingest import ros_images
from ndfa.io.ingest.bag_topics import GROUND_TRUTH_POSE_TOPIC, GROUND_TRUTH_TOPIC, IMAGE, ODOMETRY, TF_MESSAGE
from ndfa.io.ingest.tf_buffer import TransformBuffer, stamp_ns
from ndfa.io.recording.ground_truth import ground_truth_problem


@dataclass
class BagScan:
    """What the first pass learns: stamps of each image role (in message order), intrinsics, transforms."""

    stamps: dict[str, list[int | None]]  # None: a message that could not be read
    camera_frame: str
    infos: list[tuple[int, np.ndarray, tuple[int, int]]]  # (stamp, K, (height, width)), sorted
    tf: TransformBuffer
    pose_samples: list[tuple[int, str, str, np.ndarray]]  # (stamp, parent, child, T_parent_child)
    true_poses: dict[int, np.ndarray]
    ground_truth: dict | None
    imu_frame: str = ""  # the IMU messages' header.frame_id
    imu: list[tuple[int, np.ndarray]] = field(default_factory=list)  # (stamp, linear acceleration m/s^2 in imu_frame)


def scan_bag(reader: AnyReader, path: Path, chosen: dict[str, str], pose_topic: str | None,
             imu_topic: str | None = None) -> BagScan:
    """The first pass: the small messages and every image header (an unknown encoding stops here)."""
    role_of = {topic: role for role, topic in chosen.items()}
    topics = reader.topics
    wanted = set(chosen.values()) | {name for name, info in topics.items() if info.msgtype == TF_MESSAGE}
    wanted |= {t for t in (pose_topic, imu_topic, GROUND_TRUTH_TOPIC, GROUND_TRUTH_POSE_TOPIC) if t in topics}
    connections = [c for c in reader.connections if c.topic in wanted]
    scan = BagScan({role: [] for role in ("depth", "color", "mask")}, "", [], TransformBuffer(), [], {}, None)
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
            scan.pose_samples.append((stamp_ns(message.header.stamp), message.header.frame_id, child, pose_matrix(pose)))
        elif topic == imu_topic:
            a = message.linear_acceleration
            scan.imu.append((stamp_ns(message.header.stamp), np.array([a.x, a.y, a.z], dtype=np.float64)))
            scan.imu_frame = scan.imu_frame or message.header.frame_id
        elif topic == GROUND_TRUTH_TOPIC:
            scan.ground_truth = _ground_truth(path, message.data)
        elif topic == GROUND_TRUTH_POSE_TOPIC:
            scan.true_poses[stamp_ns(message.header.stamp)] = pose_matrix(message.pose)
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


def pose_matrix(pose: object) -> np.ndarray:
    p, q = pose.position, pose.orientation
    return make_pose(matrix_from_quaternion_xyzw(np.array([q.x, q.y, q.z, q.w])), np.array([p.x, p.y, p.z]))


def _ground_truth(path: Path, text: str) -> dict:
    try:
        truth = json.loads(text)
    except json.JSONDecodeError as error:
        raise IngestError(f"{path}: {GROUND_TRUTH_TOPIC} is not JSON: {error}") from None
    if not isinstance(truth, dict):
        raise IngestError(f"{path}: {GROUND_TRUTH_TOPIC} must hold a JSON object")
    problem = ground_truth_problem(truth)
    if problem:
        raise IngestError(f"{path}: {GROUND_TRUTH_TOPIC}: {problem}")
    return truth
