"""Generators of broken ROS bags: the seed bags mutated at the byte level (ROS1 record and header
length fields, the ROS2 bag's MCAP or SQLite file), broken ROS2 `metadata.yaml`, and bags written
with rosbags (through ndfa's exporter's writer) whose messages are broken: images whose size, step
and data disagree, unknown encodings, NaN or zero intrinsics, zero or NaN quaternions in /tf,
undecodable compressed images, broken ground-truth JSON."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from ndfa.core.geometry import look_at
from ndfa.io.export.bag import LINK_FROM_OPTICAL, _BagWriter
from ndfa.io.ingest.bag_topics import GROUND_TRUTH_TOPIC
from tests.fuzz.mcap_inputs import interesting_u32, mutated_mcap
from tests.fuzz.property import Blob

ROS1_MAGIC = b"#ROSBAG V2.0\n"


def ros1_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, header length, data length) of the ROS1 bag's records, as far as they parse."""
    records, offset = [], len(ROS1_MAGIC)
    while offset + 4 <= len(data):
        (header_length,) = struct.unpack_from("<I", data, offset)
        at_data = offset + 4 + header_length
        if at_data + 4 > len(data):
            break
        (data_length,) = struct.unpack_from("<I", data, at_data)
        records.append((offset, header_length, data_length))
        offset = at_data + 4 + data_length
    return records


@st.composite
def mutated_ros1(draw: st.DrawFn, seed: bytes) -> bytes:
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        records = ros1_records(bytes(data))
        kind = draw(st.sampled_from(["header length", "data length", "field length", "bit flip", "truncate",
                                     "overwrite"]))
        if kind in ("header length", "data length", "field length") and records:
            offset, header_length, data_length = draw(st.sampled_from(records))
            if kind == "header length":
                struct.pack_into("<I", data, offset, draw(interesting_u32(header_length)))
            elif kind == "data length":
                struct.pack_into("<I", data, offset + 4 + header_length, draw(interesting_u32(data_length)))
            elif header_length >= 4:  # the first field's length inside the record header
                struct.pack_into("<I", data, offset + 4, draw(interesting_u32()))
        elif kind == "truncate":
            data = data[:draw(st.integers(0, max(len(data) - 1, 0)))]
        elif kind == "bit flip" and data:
            data[draw(st.integers(0, len(data) - 1))] ^= 1 << draw(st.integers(0, 7))
        elif kind == "overwrite" and data:
            at = draw(st.integers(0, len(data) - 1))
            chunk = draw(st.binary(min_size=1, max_size=12))
            data[at:at + len(chunk)] = chunk
    return Blob(data)


_YAML_JUNK = ["{", "}", "[", ": :", "- - -", "\t", "'", '"', "&a", "*a", "!!python/object:os.system", "%YAML 9",
              "nanoseconds: -1", "nanoseconds: 1e400", "storage_identifier: nosuch", "version: 99", "path: ../../x",
              "message_count: many", "~", "null", "---\n---", "\x00", "key: [1, 2"]


@st.composite
def broken_metadata(draw: st.DrawFn, text: str) -> str:
    """A ROS2 bag's metadata.yaml with lines replaced, removed or garbled."""
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["replace line", "insert junk", "delete line", "truncate", "indent", "empty",
                                     "value"]))
        at = draw(st.integers(0, max(len(lines) - 1, 0)))
        if kind == "replace line" and lines:
            lines[at] = draw(st.sampled_from(_YAML_JUNK))
        elif kind == "insert junk":
            lines.insert(at, draw(st.sampled_from(_YAML_JUNK)))
        elif kind == "delete line" and lines:
            del lines[at]
        elif kind == "truncate":
            lines = lines[:at]
        elif kind == "indent" and lines:
            lines[at] = " " * draw(st.integers(1, 5)) + lines[at]
        elif kind == "empty":
            lines = []
        elif kind == "value" and lines and ":" in lines[at]:
            key = lines[at].split(":")[0]
            lines[at] = f"{key}: {draw(st.sampled_from(['-1', '', 'x', '[]', '{}', '1e999', 'null', '18446744073709551616']))}"
    return "\n".join(lines) + "\n"


# -- bags with broken messages ----------------------------------------------------------------------

STAMP0 = 1_700_000_000 * 10**9
_BREAKS = ["depth encoding", "depth step", "depth data", "depth size", "zero depth size", "colour size",
           "colour compressed garbage", "info nan K", "info zero K", "info size", "tf zero quaternion",
           "tf nan quaternion", "tf frames", "tf stamp", "ground truth json", "ground truth shape", "no info",
           "no tf", "stamp zero", "stamps backwards", "nothing"]


def _raw_image(bag: _BagWriter, header: object, height: int, width: int, encoding: str, step: int,
               data: np.ndarray) -> object:
    return bag.types["sensor_msgs/msg/Image"](header=header, height=height, width=width, encoding=encoding,
                                              is_bigendian=0, step=step, data=data.astype(np.uint8))


@st.composite
def broken_bag_spec(draw: st.DrawFn) -> dict:
    return dict(version=draw(st.sampled_from([(1, "sqlite3"), (2, "sqlite3"), (2, "mcap")])),
                frames=draw(st.integers(1, 3)),
                breaks=draw(st.lists(st.tuples(st.sampled_from(_BREAKS), st.integers(0, 2)), min_size=1, max_size=3)),
                value=draw(st.sampled_from([0, 1, -1, 2**31 - 1, 2**32 - 1, 7])))


def write_broken_bag(path: Path, spec: dict) -> Path:
    """A bag of spec["frames"] 8x6 frames with the listed parts broken at the listed frames."""
    version, storage = spec["version"]
    breaks: dict[int, set[str]] = {}
    for kind, frame in spec["breaks"]:
        breaks.setdefault(frame, set()).add(kind)
    odd = spec["value"] % 2**32
    K = np.array([[10.0, 0, 3.5], [0, 10.0, 2.5], [0, 0, 1]])
    if version == 1:
        path = path.with_suffix(".bag")
    with _BagWriter(path, version, storage) as bag:
        bag.write("/tf_static", "tf2_msgs/msg/TFMessage", STAMP0,
                  bag.tf_message([(STAMP0, "camera_link", "camera_optical", LINK_FROM_OPTICAL)]))
        for i in range(spec["frames"]):
            b = breaks.get(i, set())
            stamp = STAMP0 + (0 if "stamp zero" in b else (-i if "stamps backwards" in b else i) * 100_000_000)
            stamp = max(stamp, 0)
            header = bag.header(stamp, "camera_optical", i)
            depth = np.full((6, 8), 1500, np.uint16)
            raw = depth.view(np.uint8).reshape(-1)
            height, width, step, encoding = 6, 8, 16, "16UC1"
            if "depth encoding" in b:
                encoding = ["yuv422", "8UC1", "rgb8", "", "32FC1", "bayer_rggb8"][odd % 6]
            if "depth step" in b:
                step = odd
            if "depth data" in b:
                raw = raw[:odd % 100]
            if "depth size" in b:
                height, width = odd % 1000, odd % 7
            if "zero depth size" in b:
                height = width = step = 0
                raw = raw[:0]
            bag.write("/cam/depth", "sensor_msgs/msg/Image", stamp, _raw_image(bag, header, height, width, encoding,
                                                                               step, raw))
            if "colour compressed garbage" in b:
                bag.write("/cam/color/compressed", "sensor_msgs/msg/CompressedImage", stamp,
                          bag.compressed_image(header, "jpeg", bytes(range(odd % 50))))
            else:
                rgb_h = 3 if "colour size" in b else 6
                bag.write("/cam/color", "sensor_msgs/msg/Image", stamp,
                          bag.image(header, np.zeros((rgb_h, 8, 3), np.uint8), "rgb8"))
            if "no info" not in b:
                info_k = K.copy()
                if "info nan K" in b:
                    info_k[0, 0] = np.nan
                if "info zero K" in b:
                    info_k[:] = 0.0
                size = (odd % 100, 8) if "info size" in b else (6, 8)
                bag.write("/cam/info", "sensor_msgs/msg/CameraInfo", stamp, bag.camera_info(header, info_k, size))
            if "no tf" not in b:
                link = look_at(np.array([0.1 * i, 0.0, 1.0]), np.array([1.0, 0.5, 0.0])) @ np.linalg.inv(LINK_FROM_OPTICAL)
                message = bag.tf_message([(stamp + (10**12 if "tf stamp" in b else 0),
                                           "map" if "tf frames" not in b else "map", "camera_link"
                                           if "tf frames" not in b else "camera_link2", link)])
                if "tf zero quaternion" in b or "tf nan quaternion" in b:
                    value = 0.0 if "tf zero quaternion" in b else float("nan")
                    rotation = message.transforms[0].transform.rotation
                    rotation.x = rotation.y = rotation.z = rotation.w = value
                bag.write("/tf", "tf2_msgs/msg/TFMessage", stamp, message)
        if "ground truth json" in b or "ground truth shape" in b:
            text = "{not json" if "ground truth json" in b else '{"objects": [{"instance_id": "one"}]}'
            bag.write(GROUND_TRUTH_TOPIC, "std_msgs/msg/String", STAMP0, bag.types["std_msgs/msg/String"](data=text))
    return path


def copy_ros2(seed: Path, folder: Path) -> Path:
    shutil.copytree(seed, folder)
    return folder


def ros2_storage_file(folder: Path) -> Path:
    return next(p for p in folder.iterdir() if p.suffix in (".mcap", ".db3"))


__all__ = ["broken_bag_spec", "broken_metadata", "copy_ros2", "mutated_mcap", "mutated_ros1", "ros2_storage_file",
           "write_broken_bag"]
