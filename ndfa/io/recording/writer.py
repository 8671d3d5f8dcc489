"""`RecordingWriter`: writes `Frame`s into one MCAP file per session (the contract in channels.py).

The file appears at its final path only when the writer closes cleanly: until then it is a hidden
temporary file in the same directory, so a crashed importer never leaves a half-written recording
that looks complete.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import build_file_descriptor_set

from ndfa import __version__
from ndfa.core.errors import RecordingError
from ndfa.core.frame import Frame
from ndfa.core.geometry import quaternion_xyzw_from_matrix
from ndfa.io.atomic import Staged
from ndfa.io.recording import channels
from ndfa.io.recording.ground_truth import ground_truth_problem
from ndfa.io.recording.meta import FORMAT, FORMAT_VERSION

# Uncompressed bytes buffered before a chunk is compressed and written. It bounds the writer's
# memory and is what a reader decompresses at a time; 4 MiB holds about two 640x480 frames
# (rgb + depth + instances = 2.1 MB), so the messages of one frame mostly share a chunk.
CHUNK_SIZE_BYTES = 4 * 1024 * 1024

# The depth encoding holds millimetres in a uint16, so 65.535 m is the farthest depth it can store.
_MAX_DEPTH_MM = np.iinfo(np.uint16).max

# The latest time an MCAP message can carry: log_time is unsigned 64-bit nanoseconds (year 2554).
MAX_TIMESTAMP_S = 18_446_744_073.0  # floor((2**64 - 1) / 1e9): rounding to ns stays below 2**64

# Keys the writer puts into the meta message itself; the caller's meta must not set them.
_WRITER_META_KEYS = ("format", "format_version", "depth_scale", "units")
_REQUIRED_META_KEYS = ("source", "session")

_PROTOBUF_TYPES = {
    channels.COLOR: RawImage,
    channels.DEPTH: RawImage,
    channels.CALIBRATION: CameraCalibration,
    channels.INSTANCES: RawImage,
    channels.TF: FrameTransform,
    channels.GROUND_TRUTH_POSE: PoseInFrame,
}

# JSON Schemas of the two JSON channels: loose on purpose (objects), they tell a viewer what the
# message is rather than enforce it.
_JSON_SCHEMAS = {
    channels.META: {
        "title": "ndfa recording metadata",
        "type": "object",
        "required": ["format", "format_version", "source", "session", "depth_scale", "units"],
        "properties": {
            "format": {"type": "string"},
            "format_version": {"type": "integer"},
            "source": {"type": "string", "description": "where the frames come from, e.g. an importer name"},
            "session": {"type": "string", "description": "name of the session (scene, sequence)"},
            "depth_scale": {"type": "number", "description": "metres per unit of the 16UC1 depth images"},
            "units": {"type": "object"},
        },
    },
    channels.GROUND_TRUTH: {
        "title": "ndfa ground truth: scene objects, instance ids, change labels",
        "type": "object",
    },
}


class RecordingWriter:
    """Writes one session into an MCAP recording at `path`.

    Use it as a context manager:

        with RecordingWriter("scene.mcap", {"source": "sim", "session": "scene0"}) as writer:
            for frame in frames:
                writer.write_frame(frame)
            writer.write_ground_truth({"objects": [...]})

    `meta` must hold "source" and "session" (strings); any other JSON-compatible entries (e.g.
    "provenance": {...}) are kept as they are. The writer adds "format", "format_version",
    "depth_scale" and "units". A meta with "poses": "none" (a recording as a sensor writes it,
    without camera poses) makes the writer leave /tf out; the frames' poses are then ignored.
    The file at `path` is replaced only when the block exits without an exception (or `close()`
    is called); on an exception (or `abort()`) nothing at `path` changes.
    """

    def __init__(self, path: str | Path, meta: dict[str, Any], chunk_size: int = CHUNK_SIZE_BYTES) -> None:
        self.path = Path(path)
        self._meta_json = _encode_json(self.path, "meta", _complete_meta(self.path, meta))
        self._writes_poses = meta.get("poses") != "none"
        self._ground_truth_json: bytes | None = None
        self._last_time_ns: int | None = None
        self._first_time_ns: int | None = None
        self._image_size: tuple[int, int] | None = None  # (height, width) of the first frame
        self._closed = False

        # Beside `path` (see `ndfa.io.atomic`); its folder must exist. Opened with "x": never clobber anything.
        try:
            self._staged = Staged(self.path, make_parents=False)
            self._file = open(self._staged.temporary, "xb")
        except OSError as error:
            raise RecordingError(f"cannot write recording {self.path}: {error.strerror}") from error

        self._mcap = McapWriter(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._mcap.start(profile="", library=f"ndfa/{__version__} {LIBRARY_IDENTIFIER}")
        # Every channel is registered up front, so that even an empty recording has the required
        # ones; the reader tells an optional channel is used from its message count.
        self._channel_ids = {topic: self._register_protobuf(topic, cls) for topic, cls in _PROTOBUF_TYPES.items()}
        for topic, schema in _JSON_SCHEMAS.items():
            schema_id = self._mcap.register_schema(
                name=channels.SCHEMA_NAMES[topic], encoding="jsonschema", data=json.dumps(schema).encode()
            )
            self._channel_ids[topic] = self._mcap.register_channel(topic, message_encoding="json", schema_id=schema_id)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, traceback: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def write_frame(self, frame: Frame) -> None:
        """Append one frame: its images, calibration and pose(s), all stamped with its timestamp."""
        self._check_open()
        if not isinstance(frame, Frame):
            raise RecordingError(f"{self.path}: write_frame expects a Frame, got {type(frame).__name__}")
        try:
            frame.validate()  # again: a Frame's arrays may have been replaced after it was built
        except ValueError as error:
            raise RecordingError(f"{self.path}: frame {frame.index} is invalid: {error}") from error
        if frame.index >= 2**32:
            raise RecordingError(f"{self.path}: frame index {frame.index} does not fit the MCAP sequence (uint32)")

        if not 0 <= frame.timestamp < MAX_TIMESTAMP_S:  # NaN fails too
            raise RecordingError(
                f"{self.path}: frame {frame.index} has timestamp {frame.timestamp:g} s, outside what MCAP holds "
                f"(0 to {MAX_TIMESTAMP_S:.4g} s: unsigned 64-bit nanoseconds); are the stamps in seconds?")
        time_ns = int(round(frame.timestamp * 1e9))
        if self._last_time_ns is not None and time_ns <= self._last_time_ns:
            raise RecordingError(
                f"{self.path}: frame {frame.index} has timestamp {frame.timestamp:.9f} s, not after the previous "
                f"frame's {self._last_time_ns / 1e9:.9f} s; timestamps must be strictly increasing"
            )
        if self._image_size is None:
            self._image_size = frame.image_size
        elif frame.image_size != self._image_size:
            raise RecordingError(
                f"{self.path}: frame {frame.index} has images of (H, W) = {frame.image_size}, "
                f"but the recording's are {self._image_size}"
            )
        if self._first_time_ns is None:
            self._first_time_ns = time_ns
        self._last_time_ns = time_ns

        stamp = Timestamp(seconds=time_ns // 10**9, nanos=time_ns % 10**9)
        if frame.rgb is not None:
            self._write(channels.COLOR, _raw_image(stamp, frame.rgb, channels.RGB8), time_ns, frame.index)
        depth_mm = depth_to_millimetres(frame.depth)
        self._write(channels.DEPTH, _raw_image(stamp, depth_mm, channels.MONO16), time_ns, frame.index)
        self._write(channels.CALIBRATION, _calibration(stamp, frame.K, frame.image_size), time_ns, frame.index)
        if frame.instances is not None:
            self._write(channels.INSTANCES, _raw_image(stamp, frame.instances, channels.MONO16), time_ns, frame.index)
        if self._writes_poses:
            self._write(channels.TF, _frame_transform(stamp, frame.pose_world_camera), time_ns, frame.index)
        if frame.pose_world_camera_true is not None:
            true_pose = _pose_in_world(stamp, frame.pose_world_camera_true)
            self._write(channels.GROUND_TRUTH_POSE, true_pose, time_ns, frame.index)

    def write_ground_truth(self, ground_truth: dict[str, Any]) -> None:
        """Set the session's ground truth (scene objects, instance ids, change labels), at most once.

        Numpy arrays and scalars become JSON lists and numbers; JSON object keys are strings, so
        e.g. an integer instance id used as a key comes back as a string.
        """
        self._check_open()
        if self._ground_truth_json is not None:
            raise RecordingError(f"{self.path}: ground truth was already written")
        if not isinstance(ground_truth, dict):
            raise RecordingError(f"{self.path}: ground truth must be a dict, got {type(ground_truth).__name__}")
        self._ground_truth_json = _encode_json(self.path, "ground truth", ground_truth)
        problem = ground_truth_problem(json.loads(self._ground_truth_json))  # as the reader will check it
        if problem:
            self._ground_truth_json = None
            raise RecordingError(f"{self.path}: ground truth: {problem}")

    def close(self) -> None:
        """Finish the file (meta, ground truth, summary) and move it onto `path`."""
        if self._closed:
            return
        # Meta and ground truth are stamped with the first frame's time, so that a viewer shows
        # them at the start of the timeline; written last, in a chunk of their own, so a reader
        # finds them without decompressing images.
        time_ns = self._first_time_ns or 0
        try:
            self._mcap.flush()
            self._mcap.add_message(self._channel_ids[channels.META], time_ns, self._meta_json, time_ns)
            if self._ground_truth_json is not None:
                channel_id = self._channel_ids[channels.GROUND_TRUTH]
                self._mcap.add_message(channel_id, time_ns, self._ground_truth_json, time_ns)
            self._mcap.finish()
            self._file.flush()
            os.fsync(self._file.fileno())  # the data must be on disk before the rename makes it visible
            self._file.close()
            self._staged.commit()
        except OSError as error:
            self.abort()
            raise RecordingError(f"cannot finish recording {self.path}: {error}") from error
        self._closed = True

    def abort(self) -> None:
        """Discard everything written so far; the file at `path`, if any, is left as it was."""
        self._closed = True
        self._file.close()
        self._staged.discard()

    def _check_open(self) -> None:
        if self._closed:
            raise RecordingError(f"{self.path}: the writer is closed")

    def _register_protobuf(self, topic: str, message_class: type) -> int:
        descriptor_set = build_file_descriptor_set(message_class)
        schema_id = self._mcap.register_schema(
            name=message_class.DESCRIPTOR.full_name, encoding="protobuf", data=descriptor_set.SerializeToString()
        )
        return self._mcap.register_channel(topic, message_encoding="protobuf", schema_id=schema_id)

    def _write(self, topic: str, message: Any, time_ns: int, index: int) -> None:
        # log time = publish time = the frame's time; the sequence number carries the frame index.
        channel_id, data = self._channel_ids[topic], message.SerializeToString()
        self._mcap.add_message(channel_id, log_time=time_ns, data=data, publish_time=time_ns, sequence=index)


def depth_to_millimetres(depth: np.ndarray) -> np.ndarray:
    """(H, W) depth in metres -> (H, W) uint16 millimetres, rounded; NaN, inf and negative -> 0 (invalid),
    beyond 65.535 m -> 65535."""
    millimetres = np.nan_to_num(depth * np.float32(1000.0), nan=0.0, posinf=0.0, neginf=0.0)
    return np.rint(np.clip(millimetres, 0.0, _MAX_DEPTH_MM)).astype(np.uint16)


def _raw_image(stamp: Timestamp, pixels: np.ndarray, encoding: str) -> RawImage:
    height, width = pixels.shape[:2]
    # Foxglove's RawImage has no endianness field: multi-byte pixels are little-endian.
    data = np.ascontiguousarray(pixels, dtype=pixels.dtype.newbyteorder("<")).tobytes()
    return RawImage(
        timestamp=stamp,
        frame_id=channels.CAMERA_FRAME,
        width=width,
        height=height,
        encoding=encoding,
        step=len(data) // height,
        data=data,
    )


def _calibration(stamp: Timestamp, K: np.ndarray, image_size: tuple[int, int]) -> CameraCalibration:
    height, width = image_size
    # Images are undistorted pinhole images: plumb_bob with zero coefficients, no rectification,
    # and the projection P = [K | 0] of a monocular camera.
    projection = np.hstack([K, np.zeros((3, 1))])
    return CameraCalibration(
        timestamp=stamp,
        frame_id=channels.CAMERA_FRAME,
        width=width,
        height=height,
        distortion_model="plumb_bob",
        D=[0.0] * 5,
        K=K.ravel().tolist(),
        R=np.eye(3).ravel().tolist(),
        P=projection.ravel().tolist(),
    )


def _frame_transform(stamp: Timestamp, pose_world_camera: np.ndarray) -> FrameTransform:
    translation, rotation = _translation_rotation(pose_world_camera)
    return FrameTransform(
        timestamp=stamp,
        parent_frame_id=channels.WORLD_FRAME,
        child_frame_id=channels.CAMERA_FRAME,
        translation=translation,
        rotation=rotation,
    )


def _pose_in_world(stamp: Timestamp, pose_world_camera: np.ndarray) -> PoseInFrame:
    position, orientation = _translation_rotation(pose_world_camera)
    return PoseInFrame(
        timestamp=stamp, frame_id=channels.WORLD_FRAME, pose=Pose(position=position, orientation=orientation)
    )


def _translation_rotation(pose: np.ndarray) -> tuple[Vector3, Quaternion]:
    x, y, z = (float(value) for value in pose[:3, 3])
    qx, qy, qz, qw = (float(value) for value in quaternion_xyzw_from_matrix(pose[:3, :3]))
    return Vector3(x=x, y=y, z=z), Quaternion(x=qx, y=qy, z=qz, w=qw)


def _complete_meta(path: Path, meta: dict[str, Any]) -> dict[str, Any]:
    """The caller's meta plus what the writer guarantees about the file."""
    if not isinstance(meta, dict):
        raise RecordingError(f"{path}: meta must be a dict, got {type(meta).__name__}")
    for key in _REQUIRED_META_KEYS:
        if not isinstance(meta.get(key), str) or not meta[key]:
            raise RecordingError(f"{path}: meta needs a non-empty string {key!r}, got {meta.get(key)!r}")
    clashes = [key for key in _WRITER_META_KEYS if key in meta]
    if clashes:
        raise RecordingError(f"{path}: meta must not set {clashes}: the writer sets them")
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        **meta,
        "depth_scale": channels.DEPTH_SCALE_M,
        "units": {"depth": "millimetres (16UC1)", "pose": "metres", "time": "nanoseconds (log_time)"},
    }


def _encode_json(path: Path, what: str, value: dict[str, Any]) -> bytes:
    try:
        # allow_nan=False: NaN is not JSON, and Foxglove's parser would reject the message.
        return json.dumps(_json_compatible(value), allow_nan=False).encode()
    except (TypeError, ValueError) as error:
        raise RecordingError(f"{path}: {what} cannot be written as JSON: {error}") from error


def _json_compatible(value: Any) -> Any:
    """Replace numpy arrays and scalars (and paths) by the Python values json understands."""
    if isinstance(value, dict):
        return {_json_compatible(key): _json_compatible(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_compatible(item) for item in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    return value
