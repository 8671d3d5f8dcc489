"""`ndfa ingest bag`: a ROS1 `.bag` or a ROS2 bag (directory, sqlite3 or mcap storage) -> a recording.

rosbags reads every kind of bag without a ROS install (`AnyReader`). The importer picks the topics
(depth, colour, CameraInfo, masks, poses) by type and name when that is unambiguous and asks for a
flag otherwise, then reads the bag twice:

1. a scan of the small messages and of every image header: tf, CameraInfo, the pose topic, the
   stamps of the images and their encodings (an unknown encoding stops the import here, before
   anything is written; bag_scan.py);
2. a stream of the image messages, decoding only those that make a frame (bag_frames.py).

A frame is one depth image: the colour image and the mask nearest in stamp within `max_dt`, the
CameraInfo nearest in stamp, and the camera pose at the depth stamp, interpolated through the tf
tree (or along an Odometry / PoseStamped topic; bag_poses.py). ROS camera optical frames already use OpenCV axes
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

import os
import sqlite3
import struct
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path

import apsw
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag1 import ReaderError as Rosbag1Error
from rosbags.rosbag2 import ReaderError as Rosbag2Error
from rosbags.typesys import Stores, get_typestore

import ndfa
from ndfa.core.errors import IngestError
from ndfa.core.progress import Progress
from ndfa.io.ingest import MAX_DT_S, PoseEstimator
from ndfa.io.ingest.bag_frames import plan_frames, write_frames
from ndfa.io.ingest.bag_imu import imu_meta
from ndfa.io.ingest.bag_poses import pose_lookup
from ndfa.io.ingest.bag_scan import scan_bag
from ndfa.io.ingest.bag_topics import BagTopic, choose_imu_topic, choose_pose_source, choose_topics, describe_topics
from ndfa.io.ingest.tf_buffer import frame_name

# Bag errors rosbags raises for missing, truncated or malformed bags.
_BAG_ERRORS = (AnyReaderError, Rosbag1Error, Rosbag2Error)
# What rosbags' parsers (and sqlite) raise on damaged bytes beyond their own errors: its ROS1 reader
# asserts record sizes, and a length field read from damaged bytes can be anything.
# rosbags reads ROS2 sqlite3 storage with apsw (its dependency), whose errors are not sqlite3's.
_DAMAGED_DATA_ERRORS = (AssertionError, struct.error, IndexError, UnicodeDecodeError, OverflowError, MemoryError,
                        EOFError, sqlite3.DatabaseError, apsw.Error)


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
    imu: str = "no IMU topic"  # what the IMU gave for world up (bag_imu.py), in one line


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
    reader = None
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
        # rosbags takes a ROS2 metadata.yaml's values as they come: a topic name that is a mapping
        # fails only when topics are sorted. Touch them here, where the error is the bag's.
        _ = reader.topics, [(c.topic + c.msgtype, c.msgcount + 0) for c in reader.connections]
    except (*_BAG_ERRORS, *_DAMAGED_DATA_ERRORS, OSError, KeyError, ValueError, TypeError, AttributeError) as error:
        hint = " (ROS2 bags are directories with a metadata.yaml, or a ROS2 .mcap/.db3 file; ndfa recordings " \
               "are not bags)" if path.suffix == ".mcap" else ""
        if "index" in str(error).lower() and path.suffix == ".bag":
            hint = " (a ROS1 bag whose recording was cut off has no index: `rosbag reindex` repairs it)"
        if reader is not None:
            with suppress(Exception):  # open, but its topics are broken: its files must not be left open
                reader.close()
        what = one_line(error)
        if isinstance(error, (TypeError, AttributeError)) and path.is_dir():
            what = f"its metadata.yaml holds a value of the wrong type ({what})"
        raise IngestError(f"{path}: cannot read the bag: {what}{hint}") from None
    try:
        yield reader
    except (*_BAG_ERRORS, *_DAMAGED_DATA_ERRORS) as error:
        raise IngestError(f"{path}: the bag is corrupt: {one_line(error)}") from None
    except (KeyError, ValueError, TypeError, AttributeError) as error:
        if not _raised_in_rosbags(error):
            raise  # ndfa's own bug: a traceback, not a message blaming the bag
        # e.g. a ROS1 message record naming a connection the bag does not have (KeyError)
        raise IngestError(f"{path}: the bag is corrupt: rosbags cannot read it ({type(error).__name__}: "
                          f"{one_line(error)})") from None
    finally:
        try:
            reader.close()
        except (*_BAG_ERRORS, *_DAMAGED_DATA_ERRORS, OSError):
            pass  # closing a damaged bag: the error that matters is already on its way


def _raised_in_rosbags(error: BaseException) -> bool:
    """Whether `error` was raised inside rosbags' own code: its parsers index and convert what they
    read, so damaged bytes end there as plain KeyErrors or ValueErrors."""
    traceback = error.__traceback__
    while traceback is not None and traceback.tb_next is not None:
        traceback = traceback.tb_next
    return traceback is not None and f"{os.sep}rosbags{os.sep}" in traceback.tb_frame.f_code.co_filename


def one_line(error: BaseException) -> str:
    """A library's error as one line: a YAML parser's report (a broken ROS2 metadata.yaml) becomes
    its problem and position; any other text has its line breaks folded; an empty one is named by its type."""
    cause: BaseException | None = error
    while cause is not None:  # rosbags wraps its YAML parser's (ruamel's) error: found by what it has
        if "yaml" in type(cause).__module__:
            mark = getattr(cause, "problem_mark", None)
            problem = getattr(cause, "problem", None) or getattr(cause, "context", None)
            if problem and mark is not None:
                return f"metadata.yaml is not valid YAML: {problem} at line {mark.line + 1}, column {mark.column + 1}"
            first = str(cause).strip().splitlines()[:1]
            return f"metadata.yaml is not valid YAML: {first[0] if first else type(cause).__name__}"
        cause = cause.__cause__ or cause.__context__
    if isinstance(error, AssertionError) and not str(error):  # rosbags' ROS1 reader asserts record sizes
        return "a record's sizes do not match its contents (the file is damaged)"
    text = " ".join(str(error).split())
    return (text[:300] + "...") if len(text) > 300 else text or type(error).__name__


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
    max_dt: float = MAX_DT_S,
    estimate_poses: PoseEstimator | None = None,
    on_progress: Progress | None = None,
    imu_topic: str | None = None,
) -> BagSummary:
    """Import one bag into the recording `out`.

    Topics left None are found by type and name (an error lists the candidates when there are
    several). `pose_source` is "tf" or an Odometry/PoseStamped topic (default: tf when the bag has
    it, else its one pose topic). `world_frame` defaults to map, odom or world (the first in tf),
    `camera_frame` to the depth images' header.frame_id. `max_dt` (s) is how far in stamp a colour
    image or mask may be from its depth image. With `estimate_poses`, poses come from it instead of
    the bag (the bag's pose of the first frame, if any, anchors them). `on_progress(done, total)`
    follows the frames. `imu_topic` (default: the bag's one sensor_msgs/Imu topic, if any): its
    still readings, in the camera's axes, go to meta["imu"] for world up (bag_imu.py).
    """
    path, out = Path(path), Path(out)
    with open_bag(path) as reader:
        topics = {topic.name: topic for topic in describe_topics(reader, path)}
        chosen = choose_topics(path, topics, rgb_topic, depth_topic, info_topic, mask_topic)
        pose_topic = choose_pose_source(path, topics, pose_source, need=estimate_poses is None)
        imu_topic, imu_note = choose_imu_topic(path, topics, imu_topic)
        scan = scan_bag(reader, path, chosen, pose_topic, imu_topic)
        camera = frame_name(camera_frame or scan.camera_frame)
        poses, world = pose_lookup(path, scan, pose_topic, world_frame, camera, required=estimate_poses is None)
        plans, skipped = plan_frames(scan, chosen, poses, round(max_dt * 1e9))
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
        if imu_topic is not None:
            meta["imu"] = imu_meta(scan, imu_topic, camera, [plan.stamp for plan in plans])
            imu_note = f"{imu_topic}: {meta['imu']['note']}"
        written = write_frames(reader, path, out, meta, chosen, plans, skipped, scan, estimate_poses, on_progress)
    return BagSummary(
        bag=path, out=out, frames=written, depth_messages=len(scan.stamps["depth"]), topics=chosen,
        pose_source=meta["pose_source"], world_frame=world, camera_frame=camera, skipped=dict(skipped),
        instances="mask" in chosen, ground_truth=scan.ground_truth is not None, size_bytes=out.stat().st_size,
        imu=imu_note,
    )
