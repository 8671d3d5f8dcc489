"""`RecordingReader`: opens an ndfa recording (MCAP), checks it against the contract in channels.py,
and streams it back as `Frame`s.

The reader is strict on purpose: ndfa is an analysis tool, and a truncated or malformed recording
would silently bias results. Every problem is a `RecordingError` naming the file, the channel and
what is wrong. Only what is needed is decompressed: the summary (at the end of the file) on open,
then one chunk (a few MB) at a time while iterating.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import zstandard
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.message import DecodeError
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Message
from mcap.summary import Summary

from ndfa.core.errors import RecordingError
from ndfa.core.frame import Frame
from ndfa.core.geometry import make_pose, matrix_from_quaternion_xyzw
from ndfa.io.recording import channels
from ndfa.io.recording.ground_truth import ground_truth_problem
from ndfa.io.recording.meta import meta_problem
from ndfa.io.recording.structure import ChunkRecord, check_chunk_indexes, check_structure

# The 8 bytes every MCAP file starts and ends with, and the footer record just before the end:
# opcode (1 byte), record length (8), summary start (8), summary offset start (8), summary CRC (4).
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_OPCODE = 0x02
_MESSAGE_INDEX_OPCODE = 0x07
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4

# What a damaged file makes the mcap library (and its decompressors) raise: CRC mismatches are
# ValueErrors, a message of a channel the file does not declare a KeyError, a damaged lz4 frame a
# RuntimeError. Huge length fields, which would raise OverflowError or MemoryError, are refused
# before the library reads them (`structure.check_structure`).
_CORRUPTION_ERRORS = (McapError, zstandard.ZstdError, struct.error, EOFError, ValueError, KeyError, RuntimeError)

# Pixel formats the reader accepts per image channel: encoding -> (numpy dtype, values per pixel).
_IMAGE_FORMATS: dict[str, dict[str, tuple[str, int]]] = {
    channels.COLOR: {channels.RGB8: ("u1", 3)},
    channels.DEPTH: {channels.MONO16: ("<u2", 1), channels.FLOAT32: ("<f4", 1)},
    channels.INSTANCES: {channels.MONO16: ("<u2", 1)},
}

# Wanted frames at least this far apart on average (`frames(positions=...)`, `--rate` on a fast camera)
# are read by seeking to each one's chunks instead of reading every chunk (`_sparse`).
SEEK_GAP_FRAMES = 4

# Channels without which a timestamp is not a frame.
_REQUIRED_PER_FRAME = (channels.DEPTH, channels.CALIBRATION, channels.TF)


class RecordingReader:
    """Reads an ndfa recording. Opening checks the file and decodes the first frame, so a broken
    recording fails here rather than halfway through an analysis.

        reader = RecordingReader("scene.mcap")
        print(reader.meta["session"], len(reader))
        for frame in reader.frames():
            ...

    meta: the /ndfa/meta message (source, session, depth_scale, units, and what the importer added).
    ground_truth: the /ndfa/ground_truth message, or None when the recording has none.
    has_instances: whether the recording has instance images.
    has_poses: whether the recording has camera poses (/tf). One without them (meta "poses":
        "none", as a sensor records) yields frames whose `pose_world_camera` is the identity, the
        placeholder a pose estimator replaces (`ndfa.io.ingest.PoseEstimator`).
    len(reader): number of frames (depth images), from the file's summary.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        chunks = _check_mcap_file(self.path)
        with open(self.path, "rb") as file:
            mcap = SeekingReader(file, validate_crcs=True)
            summary = self._read_summary(mcap)
            check_chunk_indexes(self.path, chunks, summary.chunk_indexes)
            self._chunk_indexes = list(summary.chunk_indexes)
            self._channels = self._check_channels(summary)
            counts = summary.statistics.channel_message_counts
            self._frame_count = counts.get(self._channels[channels.DEPTH].id, 0)
            instances_channel = self._channels.get(channels.INSTANCES)
            self.has_instances = instances_channel is not None and counts.get(instances_channel.id, 0) > 0
            self.has_poses = counts.get(self._channels[channels.TF].id, 0) > 0

            meta = self._read_json(mcap, channels.META)
            if meta is None:
                raise RecordingError(f"{self.path}: channel {channels.META} has no message")
            problem = meta_problem(meta)
            if problem:
                raise RecordingError(f"{self.path}: channel {channels.META}: {problem}")
            self.meta: dict[str, Any] = meta
            self.ground_truth: dict[str, Any] | None = self._read_json(mcap, channels.GROUND_TRUTH)
        if self.ground_truth is not None:
            problem = ground_truth_problem(self.ground_truth)
            if problem:
                raise RecordingError(f"{self.path}: channel {channels.GROUND_TRUTH}: {problem}")

        if not self.has_poses and self._frame_count and self.meta.get("poses") != "none":
            raise RecordingError(f"{self.path}: channel {channels.TF} has no message, and its meta does not say "
                                 f'"poses": "none" (says {self.meta.get("poses")!r})')

        # Metres per unit of a 16UC1 depth image; ndfa always writes millimetres.
        self._depth_scale = self.meta.get("depth_scale", channels.DEPTH_SCALE_M)  # checked: `meta_problem`

        for _ in self.frames(stop=1):  # decode the first frame: wrong encodings fail on open
            pass

    def __len__(self) -> int:
        return self._frame_count

    def frames(self, start: int | None = None, stop: int | None = None, step: int = 1,
               positions: Sequence[int] | None = None) -> Iterator[Frame]:
        """Yield the frames in time order; start, stop and step select positions as in a slice
        (positions count frames from 0 in time order, which is also `Frame.index` when the importer
        numbered frames from 0), or `positions` names them (in increasing order). Skipped frames
        are read but not decoded.
        """
        if step < 1:
            raise ValueError(f"step must be >= 1, got {step}")
        if positions is None:
            positions = range(len(self))[start:stop:step]
        elif any(b <= a for a, b in zip(positions, positions[1:])):
            raise ValueError("positions must increase")
        if len(positions) == 0:
            return
        wanted = positions if isinstance(positions, range) else frozenset(positions)
        with open(self.path, "rb") as file:
            mcap = SeekingReader(file, validate_crcs=True)
            times = self._indexed_times(file) if _sparse(positions) else None
            if times is not None:  # only the chunks that hold a wanted frame are read
                for position in positions:
                    for time_ns, messages in self._messages_by_time(mcap, times[position]):
                        yield self._assemble_frame(time_ns, messages)
                return
            for position, (time_ns, messages) in enumerate(self._messages_by_time(mcap)):
                if position in wanted:
                    yield self._assemble_frame(time_ns, messages)
                if position == positions[-1]:
                    return  # before reading on: frames(stop=1) must not touch the second frame

    def timestamps(self) -> list[float]:
        """Every frame's time in seconds (`Frame.timestamp`), in time order, no frame decoded: from
        the depth channel's message indexes (a few bytes per frame), or, where the file has none
        that add up to its frames, by reading the file through (as `frames` does: ~5 ms a frame)."""
        with open(self.path, "rb") as file:
            indexed = self._indexed_times(file)
            if indexed is not None:
                return [time_ns / 1e9 for time_ns in indexed]
            return [time_ns / 1e9 for time_ns, _ in self._messages_by_time(SeekingReader(file, validate_crcs=True))]

    def _indexed_times(self, file: BinaryIO) -> list[int] | None:
        """The depth messages' log times (ns, sorted) from the chunks' message index records (each
        frame has one depth message: `_REQUIRED_PER_FRAME`), or None where they are missing or do not
        add up to the frame count."""
        depth = self._channels[channels.DEPTH].id
        times: list[int] = []
        for chunk in self._chunk_indexes:
            offset = chunk.message_index_offsets.get(depth)
            if offset is None:
                continue  # no depth message in this chunk (the count check below catches a missing index)
            file.seek(offset)
            head = file.read(9)
            if len(head) < 9:
                return None
            opcode, length = struct.unpack("<BQ", head)
            body = file.read(length)
            if opcode != _MESSAGE_INDEX_OPCODE or len(body) != length or length < 6:
                return None
            channel, records = struct.unpack_from("<HI", body)
            if channel != depth or records % 16 or 6 + records > length:
                return None
            pairs = np.frombuffer(body, dtype="<u8", count=records // 8, offset=6)
            times.extend(int(t) for t in pairs[0::2])
        if len(times) != len(self) or len(set(times)) != len(times):
            return None
        return sorted(times)

    # -- opening ------------------------------------------------------------------------------

    def _read_summary(self, mcap: SeekingReader) -> Summary:
        try:
            summary = mcap.get_summary()
        except _CORRUPTION_ERRORS as error:
            raise RecordingError(f"{self.path} is corrupt: its summary section cannot be read ({error})") from error
        if summary is None:
            raise RecordingError(
                f"{self.path} has no summary section (index); ndfa needs it to stream the file. "
                "Rewrite it with ndfa, or add one with `mcap recover` (https://mcap.dev)"
            )
        if summary.statistics is None:
            raise RecordingError(f"{self.path} has no statistics record in its summary: ndfa counts frames with it")
        return summary

    def _check_channels(self, summary: Summary) -> dict[str, Channel]:
        """Map topic -> channel, checking the required channels exist and every known channel has the
        contract's message encoding and schema."""
        by_topic: dict[str, Channel] = {}
        for channel in summary.channels.values():
            if channel.topic in by_topic:
                raise RecordingError(f"{self.path}: channel {channel.topic} appears twice")
            by_topic[channel.topic] = channel

        missing = [topic for topic in channels.REQUIRED_CHANNELS if topic not in by_topic]
        if missing:
            raise RecordingError(f"{self.path} is not an ndfa recording: it has no channel {', '.join(missing)}")

        for topic, channel in by_topic.items():
            if topic not in channels.SCHEMA_NAMES:
                continue  # extra channels (e.g. added by hand in Foxglove) are ignored
            expected_encoding = "json" if topic in channels.JSON_CHANNELS else "protobuf"
            if channel.message_encoding != expected_encoding:
                raise RecordingError(
                    f"{self.path}: channel {topic} has message encoding {channel.message_encoding!r}, "
                    f"expected {expected_encoding!r}"
                )
            schema = summary.schemas.get(channel.schema_id)
            expected_schema = channels.SCHEMA_NAMES[topic]
            if topic not in channels.JSON_CHANNELS and (schema is None or schema.name != expected_schema):
                found = "no schema" if schema is None else f"schema {schema.name!r}"
                raise RecordingError(f"{self.path}: channel {topic} has {found}, expected {expected_schema!r}")
        return by_topic

    def _read_json(self, mcap: SeekingReader, topic: str) -> dict[str, Any] | None:
        """The single JSON object on `topic`, or None when the channel is absent or empty."""
        if topic not in self._channels:
            return None
        messages = [message for _, _, message in self._checked(mcap.iter_messages(topics=[topic]))]
        if len(messages) == 0:
            return None
        if len(messages) > 1:
            raise RecordingError(f"{self.path}: channel {topic} has {len(messages)} messages, expected one")
        try:
            value = json.loads(messages[0].data)
        except (UnicodeDecodeError, json.JSONDecodeError) as error:
            raise RecordingError(f"{self.path}: channel {topic} does not hold valid JSON: {error}") from error
        if not isinstance(value, dict):
            raise RecordingError(f"{self.path}: channel {topic} must hold a JSON object, got {type(value).__name__}")
        return value

    # -- streaming ----------------------------------------------------------------------------

    def _checked(self, iterator: Iterator[Any]) -> Iterator[Any]:
        """Pass `iterator` through, turning the mcap library's errors on damaged data into RecordingError."""
        while True:
            try:
                item = next(iterator)
            except StopIteration:
                return
            except _CORRUPTION_ERRORS as error:
                raise RecordingError(f"{self.path} is corrupt: {error}") from error
            yield item

    def _messages_by_time(self, mcap: SeekingReader, at_ns: int | None = None) -> Iterator[tuple[int, dict[str, Message]]]:
        """Yield (time in ns, {topic: message}) per timestamp, in time order: one frame each; with
        `at_ns`, the one frame at that time (only the chunks its messages lie in are read)."""
        topics = [topic for topic in channels.FRAME_CHANNELS if topic in self._channels]
        group_time, group = None, {}
        messages = mcap.iter_messages(topics=topics, log_time_order=True, starting_at=at_ns, ending_at=at_ns)
        for _, channel, message in self._checked(messages):
            if message.log_time != group_time:
                if group:
                    yield self._complete_group(group_time, group)
                group_time, group = message.log_time, {}
            if channel.topic in group:
                raise RecordingError(f"{self.path}: channel {channel.topic} has 2 messages at {_time(message.log_time)}")
            group[channel.topic] = message
        if group:
            yield self._complete_group(group_time, group)

    def _complete_group(self, time_ns: int, group: dict[str, Message]) -> tuple[int, dict[str, Message]]:
        missing = [topic for topic in _REQUIRED_PER_FRAME if topic not in group
                   and (topic != channels.TF or self.has_poses)]
        if missing:
            raise RecordingError(f"{self.path}: the frame at {_time(time_ns)} has no message on {', '.join(missing)}")
        return time_ns, group

    def _assemble_frame(self, time_ns: int, group: dict[str, Message]) -> Frame:
        """Decode the messages of one timestamp into a Frame."""
        calibration = self._parse(channels.CALIBRATION, group, CameraCalibration)
        depth_image = self._parse(channels.DEPTH, group, RawImage)
        depth = self._pixels(channels.DEPTH, depth_image, time_ns)
        if depth.dtype == np.uint16:
            depth = (depth * self._depth_scale).astype(np.float32)
        else:  # 32FC1 metres: NaN (and inf, negative) mark invalid pixels, which ndfa writes as 0
            depth = np.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0)
            depth[depth < 0] = 0.0

        if len(calibration.K) != 9:
            raise RecordingError(
                f"{self.path}: channel {channels.CALIBRATION} at {_time(time_ns)} has {len(calibration.K)} values in K, "
                "expected 9"
            )
        fx, fy = calibration.K[0], calibration.K[4]
        if not (np.all(np.isfinite(calibration.K)) and fx > 0 and fy > 0):
            # A zero focal length back-projects every pixel to infinity: the error would surface far
            # downstream as "observation 0: N points are NaN or infinite", naming neither file nor channel.
            raise RecordingError(
                f"{self.path}: channel {channels.CALIBRATION} at {_time(time_ns)}: K must be finite with focal lengths "
                f"fx, fy > 0, got fx {fx:g}, fy {fy:g}"
            )
        if calibration.width and (calibration.height, calibration.width) != depth.shape:
            raise RecordingError(
                f"{self.path}: channel {channels.CALIBRATION} at {_time(time_ns)} is for images of (H, W) = "
                f"{(calibration.height, calibration.width)}, but the depth image is {depth.shape}"
            )

        rgb = instances = pose_true = None
        if channels.COLOR in group:
            rgb = self._pixels(channels.COLOR, self._parse(channels.COLOR, group, RawImage), time_ns)
        if channels.INSTANCES in group:
            instances = self._pixels(channels.INSTANCES, self._parse(channels.INSTANCES, group, RawImage), time_ns)
        if channels.GROUND_TRUTH_POSE in group:
            pose_true = _pose_matrix(self._parse(channels.GROUND_TRUTH_POSE, group, PoseInFrame).pose)

        pose = np.eye(4)  # a recording without poses: the identity placeholder
        if self.has_poses:
            transform = self._parse(channels.TF, group, FrameTransform)
            if (transform.parent_frame_id, transform.child_frame_id) != (channels.WORLD_FRAME, channels.CAMERA_FRAME):
                raise RecordingError(
                    f"{self.path}: channel {channels.TF} at {_time(time_ns)} is the transform "
                    f"{transform.parent_frame_id!r} <- {transform.child_frame_id!r}, expected "
                    f"{channels.WORLD_FRAME!r} <- {channels.CAMERA_FRAME!r}"
                )
            pose = _pose_matrix(transform)

        try:
            return Frame(
                index=group[channels.DEPTH].sequence,
                timestamp=time_ns / 1e9,
                rgb=rgb,
                depth=depth,
                K=np.array(calibration.K, dtype=np.float64).reshape(3, 3),
                pose_world_camera=pose,
                instances=instances,
                pose_world_camera_true=pose_true,
            )
        except ValueError as error:
            raise RecordingError(f"{self.path}: the frame at {_time(time_ns)} is invalid: {error}") from error

    def _parse(self, topic: str, group: dict[str, Message], message_class: type) -> Any:
        try:
            return message_class.FromString(group[topic].data)
        except DecodeError as error:
            time_ns = group[topic].log_time
            raise RecordingError(
                f"{self.path}: channel {topic} at {_time(time_ns)} is not a valid "
                f"{message_class.DESCRIPTOR.full_name}: {error}"
            ) from error

    def _pixels(self, topic: str, image: RawImage, time_ns: int) -> np.ndarray:
        """The pixels of a RawImage as an (H, W) or (H, W, C) array of the encoding's dtype (a writable copy)."""
        formats = _IMAGE_FORMATS[topic]
        if image.encoding not in formats:
            raise RecordingError(
                f"{self.path}: channel {topic} at {_time(time_ns)} has encoding {image.encoding!r}, "
                f"expected {' or '.join(repr(name) for name in formats)}"
            )
        dtype, values_per_pixel = formats[image.encoding]
        row_bytes = image.width * values_per_pixel * np.dtype(dtype).itemsize
        expected_bytes = image.step * image.height
        if row_bytes == 0 or image.height == 0 or image.step < row_bytes or len(image.data) != expected_bytes:
            raise RecordingError(
                f"{self.path}: channel {topic} at {_time(time_ns)}: a {image.encoding} image of "
                f"{image.width}x{image.height} pixels with step {image.step} cannot hold {len(image.data)} bytes of data"
            )
        # Rows may be padded to `step` bytes: cut the padding off before viewing the bytes as pixels.
        rows = np.frombuffer(image.data, dtype=np.uint8).reshape(image.height, image.step)[:, :row_bytes]
        pixels = np.ascontiguousarray(rows).view(dtype).astype(np.dtype(dtype).newbyteorder("="))
        if values_per_pixel == 1:
            return pixels.reshape(image.height, image.width)
        return pixels.reshape(image.height, image.width, values_per_pixel)


def _sparse(positions: Sequence[int]) -> bool:
    """Whether `positions` skip so many frames that reading only the chunks of the wanted ones is
    cheaper than reading every chunk once: a chunk holds two or three 640 x 480 frames
    (`writer.CHUNK_SIZE_BYTES`), and a frame's messages may lie in two, so a frame read on its own
    costs one or two chunks' decompression and its checksum; from SEEK_GAP_FRAMES apart on average
    that is less than every chunk's."""
    if len(positions) < 2:
        return False
    return (positions[-1] - positions[0]) / (len(positions) - 1) >= SEEK_GAP_FRAMES


def _check_mcap_file(path: Path) -> dict[int, ChunkRecord]:
    """Refuse what is not a complete MCAP file, before the mcap library reads (or misreads) it;
    return its chunks by offset (`structure.check_structure`)."""
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    if not path.is_file():
        raise RecordingError(f"{path} is not a file")
    try:
        with open(path, "rb") as file:
            head = file.read(len(_MCAP_MAGIC))
            size = file.seek(0, 2)
            if head != _MCAP_MAGIC:
                raise RecordingError(f"{path} is not an MCAP file (it does not start with the MCAP magic bytes)")
            file.seek(max(size - len(_MCAP_MAGIC), 0))
            if file.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC or size < 2 * len(_MCAP_MAGIC) + _FOOTER_SIZE:
                raise RecordingError(
                    f"{path} is truncated or was not closed: it does not end with the MCAP magic bytes, so its "
                    "footer and summary are missing (was the writer interrupted, or the copy incomplete?). ndfa "
                    "does not analyse partial recordings; re-record it, or salvage it with `mcap recover` "
                    "(https://mcap.dev)"
                )
            _check_summary_crc(path, file, size)
            return check_structure(path, file, size)
    except OSError as error:
        raise RecordingError(f"{path} cannot be read: {error.strerror}") from error


def _check_summary_crc(path: Path, file: BinaryIO, size: int) -> None:
    """Compare the summary section with the CRC in the footer. The mcap library does not, and a
    damaged summary (frame counts, chunk offsets) would otherwise go unnoticed or fail obscurely."""
    footer_start = size - len(_MCAP_MAGIC) - _FOOTER_SIZE
    file.seek(footer_start)
    opcode, _, summary_start, _, summary_crc = struct.unpack("<BQQQI", file.read(_FOOTER_SIZE))
    if opcode != _FOOTER_OPCODE or summary_start > footer_start:
        raise RecordingError(f"{path} is corrupt: its footer is not a valid MCAP footer")
    if summary_crc == 0 or summary_start == 0:
        return  # no CRC written, or no summary (reported when the summary is read)
    # The CRC covers the summary section and the footer up to (not including) the CRC itself.
    file.seek(summary_start)
    if zlib.crc32(file.read(size - len(_MCAP_MAGIC) - 4 - summary_start)) != summary_crc:
        raise RecordingError(f"{path} is corrupt: its summary section does not match its CRC")


def _pose_matrix(transform: FrameTransform | Any) -> np.ndarray:
    """4x4 pose from a foxglove FrameTransform (translation, rotation) or Pose (position, orientation)."""
    if isinstance(transform, FrameTransform):
        t, q = transform.translation, transform.rotation
    else:
        t, q = transform.position, transform.orientation
    quaternion = np.array([q.x, q.y, q.z, q.w])
    if not np.linalg.norm(quaternion) > 0:
        return np.full((4, 4), np.nan)  # an unset rotation: Frame's check reports it
    return make_pose(matrix_from_quaternion_xyzw(quaternion), np.array([t.x, t.y, t.z]))


def _time(time_ns: int) -> str:
    return f"t = {time_ns / 1e9:.9f} s ({time_ns} ns)"
