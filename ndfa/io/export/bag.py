"""`ndfa export bag`: an ndfa recording as a ROS1 `.bag` or a ROS2 bag (sqlite3 or mcap storage).

For ROS tools (rviz, rqt_bag, Foxglove) and for round trips through `ndfa ingest bag`, which the
tests use to check the importer on every bag flavour. The bag looks like a RealSense-style driver's:

| topic                                        | type                          | content                         |
|----------------------------------------------|-------------------------------|---------------------------------|
| /camera/color/image_raw                      | sensor_msgs/Image rgb8        | colour (raw)                    |
| /camera/color/image_raw/compressed           | sensor_msgs/CompressedImage   | colour as JPEG or PNG (compressed) |
| /camera/depth/image_raw                      | sensor_msgs/Image 16UC1       | depth, millimetres (raw)        |
| /camera/depth/image_raw/compressedDepth      | sensor_msgs/CompressedImage   | compressedDepth PNG (compressed) |
| /camera/depth/camera_info                    | sensor_msgs/CameraInfo        | K, plumb_bob with zero D        |
| /camera/instances                            | sensor_msgs/Image mono16      | instance ids, when present      |
| /tf                                          | tf2_msgs/TFMessage            | map -> camera_link, per frame   |
| /tf_static                                   | tf2_msgs/TFMessage            | camera_link -> camera_optical   |
| /ndfa/ground_truth                           | std_msgs/String               | ground-truth JSON (ndfa's own)  |
| /ndfa/ground_truth/pose                      | geometry_msgs/PoseStamped     | true camera pose (ndfa's own)   |

Images are in `camera_optical` (OpenCV axes, as ROS optical frames are); /tf places the camera's
body frame `camera_link` (x forward, y left, z up, REP 103) in `map`, and /tf_static the fixed
optical rotation under it, so an importer must chain two transforms, as with a real robot.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag1 import WriterError as WriterError1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.rosbag2 import WriterError as WriterError2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from ndfa.core.errors import ExportError
from ndfa.core.geometry import invert_pose, make_pose, quaternion_xyzw_from_matrix
from ndfa.io.atomic import atomic_path
from ndfa.io.ingest import ros_images
from ndfa.io.ingest.bag_topics import GROUND_TRUTH_POSE_TOPIC, GROUND_TRUTH_TOPIC  # what `ndfa ingest bag` reads back
from ndfa.io.recording import Frame, RecordingReader
from ndfa.io.recording.writer import depth_to_millimetres

WORLD_FRAME = "map"
BODY_FRAME = "camera_link"
OPTICAL_FRAME = "camera_optical"
# T_link_optical: optical x (right) = body -y, optical y (down) = body -z, optical z (forward) = body x.
LINK_FROM_OPTICAL = make_pose(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.zeros(3))

COLOR_TOPIC = "/camera/color/image_raw"
DEPTH_TOPIC = "/camera/depth/image_raw"
INFO_TOPIC = "/camera/depth/camera_info"
INSTANCES_TOPIC = "/camera/instances"

# The ROS1 Noetic store lacks tf2_msgs (it lives outside ros_comm); its definition is one line.
_TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms"


@dataclass(frozen=True)
class BagExport:
    out: Path
    frames: int
    topics: list[str]
    size_bytes: int


def export_bag(recording_path: str | Path, out_path: str | Path, version: int = 1, storage: str = "sqlite3",
               compressed: bool = False, color_format: str = "jpeg") -> BagExport:
    """Write the recording at `recording_path` as a ROS `version` (1 or 2) bag at `out_path`.

    ROS2 bags are directories, stored as `storage` ("sqlite3" or "mcap"). `compressed` writes
    colour as `color_format` ("jpeg", lossy, or "png") CompressedImage and depth as compressedDepth.
    Nothing is written at `out_path` unless the whole bag is (temporary name, then a rename).
    """
    recording_path, out_path = Path(recording_path), Path(out_path)
    if version not in (1, 2):
        raise ExportError(f"ROS bag version must be 1 or 2, got {version}")
    if storage not in ("sqlite3", "mcap"):
        raise ExportError(f"ROS2 bag storage must be sqlite3 or mcap, got {storage!r}")
    if color_format not in ("jpeg", "png"):
        raise ExportError(f"compressed colour format must be jpeg or png, got {color_format!r}")
    if out_path.exists():
        raise ExportError(f"{out_path} already exists; choose a new path (a bag is never overwritten)")
    reader = RecordingReader(recording_path)

    try:
        # The temporary keeps the bag's name: a ROS2 bag names its database file after its folder.
        with atomic_path(out_path) as temporary, _BagWriter(temporary, version, storage) as bag:
            frames = _write_recording(bag, reader, compressed, color_format)
    except (WriterError1, WriterError2, OSError) as error:
        raise ExportError(f"cannot write {out_path}: {error}") from None
    size = sum(p.stat().st_size for p in out_path.rglob("*") if p.is_file()) if out_path.is_dir() else out_path.stat().st_size
    return BagExport(out_path, frames, sorted(bag.connections), size)


def _write_recording(bag: _BagWriter, reader: RecordingReader, compressed: bool, color_format: str) -> int:
    frames = 0
    for frame in reader.frames():
        stamp = round(frame.timestamp * 1e9)
        if frames == 0:
            bag.write("/tf_static", "tf2_msgs/msg/TFMessage", stamp, bag.tf_message(
                [(stamp, BODY_FRAME, OPTICAL_FRAME, LINK_FROM_OPTICAL)]))
            if reader.ground_truth is not None:
                bag.write(GROUND_TRUTH_TOPIC, "std_msgs/msg/String", stamp,
                          bag.types["std_msgs/msg/String"](data=json.dumps(reader.ground_truth)))
        _write_frame(bag, frame, stamp, compressed, color_format)
        frames += 1
    return frames


def _write_frame(bag: _BagWriter, frame: Frame, stamp: int, compressed: bool, color_format: str) -> None:
    header = bag.header(stamp, OPTICAL_FRAME, frame.index)
    depth_mm = depth_to_millimetres(frame.depth)
    if frame.rgb is not None:
        if compressed:
            data = ros_images.encode_jpeg(frame.rgb) if color_format == "jpeg" else ros_images.encode_png(frame.rgb)
            bag.write(COLOR_TOPIC + "/compressed", "sensor_msgs/msg/CompressedImage", stamp,
                      bag.compressed_image(header, f"rgb8; {color_format} compressed rgb8", data))
        else:
            bag.write(COLOR_TOPIC, "sensor_msgs/msg/Image", stamp, bag.image(header, frame.rgb, "rgb8"))
    if compressed:
        bag.write(DEPTH_TOPIC + "/compressedDepth", "sensor_msgs/msg/CompressedImage", stamp,
                  bag.compressed_image(header, "16UC1; compressedDepth png", ros_images.encode_compressed_depth(depth_mm)))
    else:
        bag.write(DEPTH_TOPIC, "sensor_msgs/msg/Image", stamp, bag.image(header, depth_mm, "16UC1"))
    bag.write(INFO_TOPIC, "sensor_msgs/msg/CameraInfo", stamp, bag.camera_info(header, frame.K, frame.image_size))
    if frame.instances is not None:
        bag.write(INSTANCES_TOPIC, "sensor_msgs/msg/Image", stamp, bag.image(header, frame.instances, "mono16"))
    world_from_link = frame.pose_world_camera @ invert_pose(LINK_FROM_OPTICAL)
    bag.write("/tf", "tf2_msgs/msg/TFMessage", stamp, bag.tf_message([(stamp, WORLD_FRAME, BODY_FRAME, world_from_link)]))
    if frame.pose_world_camera_true is not None:
        bag.write(GROUND_TRUTH_POSE_TOPIC, "geometry_msgs/msg/PoseStamped", stamp,
                  bag.pose_stamped(bag.header(stamp, WORLD_FRAME, frame.index), frame.pose_world_camera_true))


class _BagWriter:
    """rosbags' ROS1 or ROS2 writer behind one interface, with the message builders of its typestore."""

    def __init__(self, path: Path, version: int, storage: str) -> None:
        self.version = version
        if version == 1:
            self.typestore: Typestore = get_typestore(Stores.ROS1_NOETIC)
            self.typestore.register(get_types_from_msg(_TF_MESSAGE_MSG, "tf2_msgs/msg/TFMessage"))
            self._writer = Writer1(path)
        else:
            self.typestore = get_typestore(Stores.ROS2_HUMBLE)
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            self._writer = Writer2(path, version=9, storage_plugin=plugin)
        self.types = self.typestore.types
        self.connections: dict[str, object] = {}

    def __enter__(self) -> _BagWriter:
        self._writer.open()
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, traceback: object) -> None:
        if exc_type is None:
            self._writer.close()
        else:
            self._writer.abort()

    def write(self, topic: str, msgtype: str, stamp: int, message: object) -> None:
        if topic not in self.connections:
            extra = {"latching": 1} if self.version == 1 and topic in ("/tf_static", GROUND_TRUTH_TOPIC) else {}
            self.connections[topic] = self._writer.add_connection(topic, msgtype, typestore=self.typestore, **extra)
        if self.version == 1:
            data = self.typestore.serialize_ros1(message, msgtype)
        else:
            data = self.typestore.serialize_cdr(message, msgtype)
        self._writer.write(self.connections[topic], stamp, data)

    def header(self, stamp: int, frame_id: str, seq: int) -> object:
        time = self.types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
        if self.version == 1:
            return self.types["std_msgs/msg/Header"](seq=seq, stamp=time, frame_id=frame_id)
        return self.types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)

    def image(self, header: object, pixels: np.ndarray, encoding: str) -> object:
        height, width = pixels.shape[:2]
        data = np.ascontiguousarray(pixels, dtype=pixels.dtype.newbyteorder("<")).view(np.uint8).reshape(-1)
        return self.types["sensor_msgs/msg/Image"](header=header, height=height, width=width, encoding=encoding,
                                                   is_bigendian=0, step=data.size // height, data=data)

    def compressed_image(self, header: object, fmt: str, data: bytes) -> object:
        return self.types["sensor_msgs/msg/CompressedImage"](header=header, format=fmt,
                                                             data=np.frombuffer(data, dtype=np.uint8))

    def camera_info(self, header: object, K: np.ndarray, image_size: tuple[int, int]) -> object:
        height, width = image_size
        matrices = {"D": np.zeros(5), "K": K.ravel(), "R": np.eye(3).ravel(),
                    "P": np.hstack([K, np.zeros((3, 1))]).ravel()}
        if self.version == 2:  # ROS2 renamed the fields to lower case
            matrices = {name.lower(): value for name, value in matrices.items()}
        roi = self.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self.types["sensor_msgs/msg/CameraInfo"](header=header, height=height, width=width,
                                                        distortion_model="plumb_bob", binning_x=0, binning_y=0,
                                                        roi=roi, **matrices)

    def tf_message(self, transforms: list[tuple[int, str, str, np.ndarray]]) -> object:
        """A TFMessage of (stamp, parent, child, T_parent_child) transforms."""
        stamped = []
        for stamp, parent, child, pose in transforms:
            translation = self.types["geometry_msgs/msg/Vector3"](*(float(v) for v in pose[:3, 3]))
            transform = self.types["geometry_msgs/msg/Transform"](translation=translation, rotation=self._quaternion(pose))
            stamped.append(self.types["geometry_msgs/msg/TransformStamped"](
                header=self.header(stamp, parent, 0), child_frame_id=child, transform=transform))
        return self.types["tf2_msgs/msg/TFMessage"](transforms=stamped)

    def pose_stamped(self, header: object, pose: np.ndarray) -> object:
        position = self.types["geometry_msgs/msg/Point"](*(float(v) for v in pose[:3, 3]))
        return self.types["geometry_msgs/msg/PoseStamped"](
            header=header, pose=self.types["geometry_msgs/msg/Pose"](position=position, orientation=self._quaternion(pose)))

    def _quaternion(self, pose: np.ndarray) -> object:
        x, y, z, w = (float(v) for v in quaternion_xyzw_from_matrix(pose[:3, :3]))
        return self.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)
