"""Tests of the recording contract: writer -> MCAP file -> reader, bad files, and the file opening in Rerun."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import build_file_descriptor_set

from ndfa.core.errors import RecordingError
from ndfa.core.geometry import axis_angle_to_matrix, make_pose
from ndfa.io.recording import (
    CALIBRATION,
    DEPTH,
    META,
    TF,
    Frame,
    RecordingReader,
    RecordingWriter,
)
from ndfa.io.recording.writer import depth_to_millimetres

HEIGHT, WIDTH = 48, 64
META_IN = {"source": "test", "session": "unit", "provenance": {"seed": 7, "tool": "pytest"}}


def random_pose(rng: np.random.Generator) -> np.ndarray:
    return make_pose(axis_angle_to_matrix(rng.normal(size=3)), rng.normal(size=3))


def make_frames(count: int = 5, seed: int = 0, optional: bool = True) -> list[Frame]:
    """Small random frames; depth is a whole number of millimetres so that it survives exactly."""
    rng = np.random.default_rng(seed)
    K = np.array([[52.5, 0.0, 31.5], [0.0, 52.5, 23.5], [0.0, 0.0, 1.0]])
    frames = []
    for index in range(count):
        depth_mm = rng.integers(0, 10_000, size=(HEIGHT, WIDTH))
        frames.append(
            Frame(
                index=index,
                timestamp=1.7e9 + index / 30,  # Unix time, as real sessions have
                rgb=rng.integers(0, 256, size=(HEIGHT, WIDTH, 3), dtype=np.uint8) if optional else None,
                depth=(depth_mm / 1000).astype(np.float32),
                K=K,
                pose_world_camera=random_pose(rng),
                instances=rng.integers(0, 6, size=(HEIGHT, WIDTH), dtype=np.uint16) if optional else None,
                pose_world_camera_true=random_pose(rng) if optional else None,
            )
        )
    return frames


def write_recording(path: Path, frames: list[Frame], ground_truth: dict | None = None) -> Path:
    with RecordingWriter(path, META_IN) as writer:
        for frame in frames:
            writer.write_frame(frame)
        if ground_truth is not None:
            writer.write_ground_truth(ground_truth)
    return path


def leftover_temp_files(directory: Path) -> list[Path]:
    return list(directory.glob(".*.tmp-*"))


# -- round trip ---------------------------------------------------------------------------------


def test_round_trip_keeps_every_field(tmp_path: Path) -> None:
    frames = make_frames()
    ground_truth = {"objects": [{"instance_id": np.uint16(3), "center": np.array([0.5, 1.0, 0.75])}], "changes": {"added": [3]}}
    reader = RecordingReader(write_recording(tmp_path / "session.mcap", frames, ground_truth))

    assert len(reader) == len(frames)
    assert reader.has_instances
    assert reader.meta["source"] == "test" and reader.meta["session"] == "unit"
    assert reader.meta["provenance"] == META_IN["provenance"]
    assert reader.meta["depth_scale"] == 0.001
    assert reader.ground_truth == {"objects": [{"instance_id": 3, "center": [0.5, 1.0, 0.75]}], "changes": {"added": [3]}}

    read = list(reader.frames())
    assert len(read) == len(frames)
    for written, back in zip(frames, read):
        assert back.index == written.index
        assert back.timestamp == pytest.approx(written.timestamp, abs=1e-6)
        np.testing.assert_array_equal(back.rgb, written.rgb)
        assert back.depth.dtype == np.float32
        np.testing.assert_array_equal(np.rint(back.depth * 1000), np.rint(written.depth * 1000))  # exact mm
        np.testing.assert_array_equal(back.K, written.K)
        np.testing.assert_allclose(back.pose_world_camera, written.pose_world_camera, atol=1e-9)
        np.testing.assert_allclose(back.pose_world_camera_true, written.pose_world_camera_true, atol=1e-9)
        np.testing.assert_array_equal(back.instances, written.instances)
        back.depth[0, 0] = 1.0  # arrays handed out are the caller's to modify


def test_optional_fields_absent(tmp_path: Path) -> None:
    reader = RecordingReader(write_recording(tmp_path / "plain.mcap", make_frames(optional=False)))
    assert not reader.has_instances
    assert reader.ground_truth is None
    for frame in reader.frames():
        assert frame.rgb is None and frame.instances is None and frame.pose_world_camera_true is None


def test_frames_selects_like_a_slice(tmp_path: Path) -> None:
    reader = RecordingReader(write_recording(tmp_path / "s.mcap", make_frames(count=7)))
    assert [frame.index for frame in reader.frames(1, None, 2)] == [1, 3, 5]
    assert [frame.index for frame in reader.frames(stop=2)] == [0, 1]
    assert [frame.index for frame in reader.frames(start=-2)] == [5, 6]


def test_empty_recording_is_valid(tmp_path: Path) -> None:
    reader = RecordingReader(write_recording(tmp_path / "empty.mcap", []))
    assert len(reader) == 0 and list(reader.frames()) == []


def test_depth_is_stored_as_rounded_clipped_millimetres() -> None:
    depth = np.array([[1.2344, 1.2346, np.nan, -1.0], [np.inf, 70.0, 0.0, 0.0004]], dtype=np.float32)
    expected = np.array([[1234, 1235, 0, 0], [0, 65535, 0, 0]], dtype=np.uint16)
    np.testing.assert_array_equal(depth_to_millimetres(depth), expected)


# -- the writer refuses bad input and never leaves a partial file ---------------------------------


def test_exception_inside_with_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "never.mcap"
    with pytest.raises(KeyboardInterrupt):
        with RecordingWriter(path, META_IN) as writer:
            writer.write_frame(make_frames(1)[0])
            raise KeyboardInterrupt
    assert not path.exists()
    assert leftover_temp_files(tmp_path) == []


def test_exception_inside_with_keeps_existing_file(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "keep.mcap", make_frames(2))
    before = path.read_bytes()
    with pytest.raises(RuntimeError):
        with RecordingWriter(path, META_IN) as writer:
            writer.write_frame(make_frames(1, seed=1)[0])
            raise RuntimeError("importer crashed")
    assert path.read_bytes() == before
    assert leftover_temp_files(tmp_path) == []


def test_clean_exit_replaces_existing_file(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "replace.mcap", make_frames(2))
    write_recording(path, make_frames(4))
    assert len(RecordingReader(path)) == 4
    assert leftover_temp_files(tmp_path) == []


@pytest.mark.parametrize("second_timestamp", [1.0, 0.5])  # equal, then earlier
def test_timestamps_must_increase(tmp_path: Path, second_timestamp: float) -> None:
    path = tmp_path / "time.mcap"
    first, second = make_frames(2)
    first.timestamp, second.timestamp = 1.0, second_timestamp
    with pytest.raises(RecordingError, match="strictly increasing") as error:
        with RecordingWriter(path, META_IN) as writer:
            writer.write_frame(first)
            writer.write_frame(second)
    assert str(path) in str(error.value) and "frame 1" in str(error.value)
    assert not path.exists() and leftover_temp_files(tmp_path) == []


def test_image_size_must_not_change(tmp_path: Path) -> None:
    first, second = make_frames(2)
    second.depth = np.zeros((HEIGHT // 2, WIDTH // 2), dtype=np.float32)
    second.rgb = second.instances = None
    with pytest.raises(RecordingError, match="images of"):
        with RecordingWriter(tmp_path / "size.mcap", META_IN) as writer:
            writer.write_frame(first)
            writer.write_frame(second)


def test_frame_checks_shapes_and_dtypes(tmp_path: Path) -> None:
    good = make_frames(1)[0]
    with pytest.raises(ValueError, match="rgb"):
        Frame(0, 0.0, good.rgb.astype(np.float32), good.depth, good.K, good.pose_world_camera)
    with pytest.raises(ValueError, match="depth"):
        Frame(0, 0.0, None, good.depth[None], good.K, good.pose_world_camera)
    with pytest.raises(ValueError, match="not a rigid transform"):
        Frame(0, 0.0, None, good.depth, good.K, 2 * np.eye(4) - np.diag([0, 0, 0, 1.0]))
    # A frame broken after it was built is caught by the writer, which names the file.
    good.instances = good.instances.astype(np.int64)
    path = tmp_path / "broken.mcap"
    with pytest.raises(RecordingError, match="instances") as error:
        with RecordingWriter(path, META_IN) as writer:
            writer.write_frame(good)
    assert str(path) in str(error.value)


def test_meta_needs_source_and_session(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="session"):
        RecordingWriter(tmp_path / "meta.mcap", {"source": "test"})
    with pytest.raises(RecordingError, match="JSON"):
        RecordingWriter(tmp_path / "meta.mcap", {**META_IN, "provenance": {"bad": object()}})
    assert list(tmp_path.iterdir()) == []


def test_unwritable_directory(tmp_path: Path) -> None:
    path = tmp_path / "no" / "such" / "dir" / "out.mcap"
    with pytest.raises(RecordingError, match="cannot write recording") as error:
        RecordingWriter(path, META_IN)
    assert str(path) in str(error.value)


# -- the reader refuses bad files, naming the file (and the channel) -----------------------------


def write_by_hand(path: Path, messages: list[tuple[str, int, Any]]) -> Path:
    """An MCAP file written with the mcap library directly, not with ndfa: (topic, time ns, message)
    where the message is a foxglove protobuf message or a dict (JSON)."""
    with open(path, "wb") as file:
        writer = McapWriter(file)
        writer.start()
        channel_ids: dict[str, int] = {}
        for topic, time_ns, message in messages:
            if topic not in channel_ids:
                if isinstance(message, dict):
                    schema_id = writer.register_schema("ndfa.Meta", "jsonschema", b'{"type": "object"}')
                    channel_ids[topic] = writer.register_channel(topic, "json", schema_id)
                else:
                    data = build_file_descriptor_set(type(message)).SerializeToString()
                    schema_id = writer.register_schema(type(message).DESCRIPTOR.full_name, "protobuf", data)
                    channel_ids[topic] = writer.register_channel(topic, "protobuf", schema_id)
            data = json.dumps(message).encode() if isinstance(message, dict) else message.SerializeToString()
            writer.add_message(channel_ids[topic], log_time=time_ns, data=data, publish_time=time_ns)
        writer.finish()
    return path


def hand_frame(time_ns: int, depth: RawImage | None = None, skip: tuple[str, ...] = ()) -> list[tuple[str, int, Any]]:
    """The messages of one 4x3 frame at `time_ns`; `depth` replaces the depth image, `skip` drops channels."""
    if depth is None:
        depth = RawImage(width=4, height=3, encoding="16UC1", step=8, data=np.full((3, 4), 1500, "<u2").tobytes())
    calibration = CameraCalibration(width=4, height=3, K=[2.0, 0, 2, 0, 2.0, 1.5, 0, 0, 1])
    transform = FrameTransform(parent_frame_id="world", child_frame_id="camera", rotation=Quaternion(w=1.0))
    messages = [(DEPTH, time_ns, depth), (CALIBRATION, time_ns, calibration), (TF, time_ns, transform)]
    return [message for message in messages if message[0] not in skip]


META_MESSAGE = (META, 1, {"format": "ndfa.recording", "format_version": 1, "source": "hand", "session": "x"})


def test_reads_32fc1_metres_depth(tmp_path: Path) -> None:
    depth_m = np.array([[1.25, np.nan, -2.0, 3.0]] * 3, dtype="<f4")
    depth = RawImage(width=4, height=3, encoding="32FC1", step=16, data=depth_m.tobytes())
    reader = RecordingReader(write_by_hand(tmp_path / "f32.mcap", [META_MESSAGE, *hand_frame(10, depth)]))
    (frame,) = reader.frames()
    np.testing.assert_array_equal(frame.depth, np.array([[1.25, 0.0, 0.0, 3.0]] * 3, dtype=np.float32))
    np.testing.assert_array_equal(frame.pose_world_camera, np.eye(4))
    assert not reader.has_instances


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "absent.mcap"
    with pytest.raises(RecordingError, match="no such file") as error:
        RecordingReader(path)
    assert str(path) in str(error.value)


def test_text_file_is_not_a_recording(tmp_path: Path) -> None:
    path = tmp_path / "notes.mcap"
    path.write_text("these are not the frames you are looking for\n" * 10)
    with pytest.raises(RecordingError, match="not an MCAP file") as error:
        RecordingReader(path)
    assert str(path) in str(error.value)


def test_truncated_recording_is_refused(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "cut.mcap", make_frames(8))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="truncated") as error:
        RecordingReader(path)
    assert str(path) in str(error.value)


def test_corrupt_chunk_is_reported(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "flipped.mcap", make_frames(8))
    data = bytearray(path.read_bytes())
    middle = len(data) // 3
    data[middle : middle + 64] = bytes(64)  # zero out bytes inside compressed image data
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError) as error:
        list(RecordingReader(path).frames())
    assert str(path) in str(error.value)


def test_missing_depth_channel(tmp_path: Path) -> None:
    path = write_by_hand(tmp_path / "nodepth.mcap", [META_MESSAGE, *hand_frame(10, skip=(DEPTH,))])
    with pytest.raises(RecordingError, match="no channel /camera/depth") as error:
        RecordingReader(path)
    assert str(path) in str(error.value)


def test_wrong_depth_encoding(tmp_path: Path) -> None:
    depth = RawImage(width=4, height=3, encoding="mono8", step=4, data=bytes(12))
    path = write_by_hand(tmp_path / "mono8.mcap", [META_MESSAGE, *hand_frame(10, depth)])
    with pytest.raises(RecordingError, match="/camera/depth.*'mono8'") as error:
        RecordingReader(path)
    assert str(path) in str(error.value)


def test_wrong_depth_data_length(tmp_path: Path) -> None:
    depth = RawImage(width=4, height=3, encoding="16UC1", step=8, data=bytes(20))
    path = write_by_hand(tmp_path / "short.mcap", [META_MESSAGE, *hand_frame(10, depth)])
    with pytest.raises(RecordingError, match="/camera/depth.*20 bytes") as error:
        RecordingReader(path)
    assert str(path) in str(error.value)


def test_frame_missing_a_pose_names_its_time(tmp_path: Path) -> None:
    path = write_by_hand(tmp_path / "notf.mcap", [META_MESSAGE, *hand_frame(10), *hand_frame(2_000_000_000, skip=(TF,))])
    reader = RecordingReader(path)  # the first frame is fine
    with pytest.raises(RecordingError, match=r"t = 2\.000000000 s.*/tf") as error:
        list(reader.frames())
    assert str(path) in str(error.value)


# -- the file opens in Rerun as it is ------------------------------------------------------------


def rerun_binary() -> str | None:
    beside_python = Path(sys.executable).parent / "rerun"
    return str(beside_python) if beside_python.exists() else shutil.which("rerun")


@pytest.mark.skipif(rerun_binary() is None, reason="the rerun CLI (rerun-sdk) is not installed")
def test_recording_opens_in_rerun(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    mcap_path = write_recording(tmp_path / "view.mcap", make_frames(3))
    rrd_path = tmp_path / "view.rrd"
    command = [rerun_binary(), "mcap", "convert", str(mcap_path), "-o", str(rrd_path)]
    subprocess.run(command, check=True, capture_output=True, timeout=60)

    # Components per entity (over the chunks that change with time, i.e. the frames' data).
    components: dict[str, set[str]] = {}
    rows: dict[str, int] = {}
    for chunk in RrdReader(rrd_path).store().stream().to_chunks():
        if not chunk.is_static:
            components.setdefault(chunk.entity_path, set()).update(chunk.to_record_batch().schema.names)
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows

    assert {"Image:buffer", "Image:format"} <= components["/camera/depth"]
    assert {"Image:buffer", "Image:format"} <= components["/camera/color"]
    assert {"Pinhole:image_from_camera", "Pinhole:resolution"} <= components["/camera/calibration"]
    assert {"Transform3D:translation", "Transform3D:quaternion", "Transform3D:parent_frame"} <= components["/tf"]
    assert all(rows[entity] == 3 for entity in ("/camera/depth", "/camera/color", "/camera/calibration", "/tf"))


def test_a_recording_names_its_format_as_the_shipped_sample_does(tmp_path: Path) -> None:
    # The format name is part of the file contract: recordings written today and the shipped
    # sample (written before the package moved to ndfa.io) must say the same.
    shipped = RecordingReader(Path(__file__).resolve().parents[1] / "recordings" / "sample" / "source.mcap").meta
    frame = next(RecordingReader(Path(__file__).resolve().parents[1] / "recordings" / "sample" / "source.mcap").frames(stop=1))
    with RecordingWriter(tmp_path / "x.mcap", {"source": "test", "session": "x"}) as writer:
        writer.write_frame(frame)
    written = RecordingReader(tmp_path / "x.mcap").meta
    assert (written["format"], written["format_version"]) == (shipped["format"], shipped["format_version"]) == ("ndfa.recording", 1)


# -- damaged files (issue 18; tests/fuzz finds more) ---------------------------------------------------

def _tiny_with_chunk_field(tmp_path: Path, field_offset: int, value: int) -> Path:
    """The fuzz seed recording with one u64 field of its first chunk's header set to `value`
    (field_offset: bytes after the chunk record's body start)."""
    import struct

    from tests.fuzz.mcap_inputs import CHUNK_OPCODE, top_level_records
    from tests.fuzz.seeds import SEED

    data = bytearray((SEED / "tiny.mcap").read_bytes())
    offset = next(o for o, opcode, _ in top_level_records(bytes(data)) if opcode == CHUNK_OPCODE)
    struct.pack_into("<Q", data, offset + 9 + field_offset, value)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("value", [2**63, 2**64 - 1, 2**40])
def test_a_huge_uncompressed_chunk_size_is_refused_before_decompressing(tmp_path, value):
    """Once an OverflowError (2^63) or a MemoryError (2^40) from the zstd decompressor."""
    path = _tiny_with_chunk_field(tmp_path, 16, value)
    with pytest.raises(RecordingError, match=rf"damaged.mcap is corrupt: the chunk at byte \d+ says it holds {value} bytes"):
        RecordingReader(path)


@pytest.mark.parametrize("value", [0, 2**63, 2**64 - 1])
def test_a_chunk_records_length_that_does_not_fit_is_refused(tmp_path, value):
    path = _tiny_with_chunk_field(tmp_path, 32 + len("zstd"), value)
    with pytest.raises(RecordingError, match=rf"the chunk at byte \d+ holds {value} bytes of records by its header"):
        RecordingReader(path)


@pytest.mark.parametrize("value", [0, 2**63 - 1, 2**64 - 9])
def test_a_record_length_past_the_end_is_refused(tmp_path, value):
    import struct

    from tests.fuzz.mcap_inputs import top_level_records
    from tests.fuzz.seeds import SEED

    data = bytearray((SEED / "tiny.mcap").read_bytes())
    offset = top_level_records(bytes(data))[2][0]
    struct.pack_into("<Q", data, offset + 1, value)
    (tmp_path / "damaged.mcap").write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=r"damaged.mcap is corrupt: (the record at byte \d+|its records do not end|"
                                             r"the chunk at byte|a record at byte)"):
        RecordingReader(tmp_path / "damaged.mcap")


def test_a_ground_truth_without_instance_ids_is_refused_on_open(tmp_path, monkeypatch):
    """Once a KeyError deep in the scoring of `ndfa detect`. The writer refuses to write one; a
    recording from elsewhere (here: the writer with its check off) is refused when opened."""
    with pytest.raises(RecordingError, match=r'session.mcap: ground truth: "objects"\[0\] has no integer "instance_id"'):
        write_recording(tmp_path / "session.mcap", make_frames(), {"objects": [{"id": 3}]})
    assert not (tmp_path / "session.mcap").exists()
    monkeypatch.setattr("ndfa.io.recording.writer.ground_truth_problem", lambda truth: None)
    path = write_recording(tmp_path / "session.mcap", make_frames(), {"objects": [{"id": 3}]})
    with pytest.raises(RecordingError, match=r'session.mcap: channel /ndfa/ground_truth: "objects"\[0\] has no integer "instance_id"'):
        RecordingReader(path)
