"""Generators of bad MCAP input: an ndfa recording mutated at the byte level (bit flips, truncation,
and above all the length and size fields of record, chunk and summary headers set to 0, huge or
negative-as-unsigned), and foreign MCAPs written with the mcap library in every layout."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType
from mcap.writer import Writer as McapWriter

from ndfa.io.recording import channels
from tests.fuzz.property import Blob

MAGIC = b"\x89MCAP0\r\n"
FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
CHUNK_OPCODE, FOOTER_OPCODE = 0x06, 0x02


def interesting_u64(original: int = 0, size: int = 0) -> st.SearchStrategy[int]:
    """Values a length field takes in broken files: 0, small, near the file size, 2^31/2^32/2^63
    boundaries, and small negative numbers read as unsigned."""
    return st.one_of(
        st.sampled_from([0, 1, 2**31 - 1, 2**31, 2**32 - 1, 2**32, 2**63 - 1, 2**63, 2**64 - 1]),
        st.integers(1, 64).map(lambda k: 2**64 - k),
        st.integers(-16, 16).map(lambda d: min(max(0, original + d), 2**64 - 1)),
        st.integers(0, 4).map(lambda k: max(0, size * k // 2 + k - 2)),
        st.integers(0, 2**64 - 1),
    )


def interesting_u32(original: int = 0) -> st.SearchStrategy[int]:
    return st.one_of(
        st.sampled_from([0, 1, 2**15, 2**16, 2**31 - 1, 2**31, 2**32 - 1]),
        st.integers(1, 16).map(lambda k: 2**32 - k),
        st.integers(-8, 8).map(lambda d: min(max(0, original + d), 2**32 - 1)),
        st.integers(0, 2**32 - 1),
    )


def top_level_records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, body length) of each record after the leading magic, as far as they parse."""
    records, offset = [], len(MAGIC)
    while offset + 9 <= len(data) - len(MAGIC):
        opcode, length = struct.unpack_from("<BQ", data, offset)
        records.append((offset, opcode, length))
        if opcode == FOOTER_OPCODE or offset + 9 + length > len(data):
            break
        offset += 9 + length
    return records


def fix_summary_crc(data: bytearray) -> None:
    """Recompute the footer's summary CRC, so that a mutated summary gets past the CRC check and
    reaches the parser."""
    size = len(data)
    if size < 2 * len(MAGIC) + FOOTER_SIZE:
        return
    footer = size - len(MAGIC) - FOOTER_SIZE
    opcode, _, summary_start, _, crc = struct.unpack_from("<BQQQI", data, footer)
    if opcode != FOOTER_OPCODE or crc == 0 or not 0 < summary_start <= footer:
        return
    struct.pack_into("<I", data, size - len(MAGIC) - 4, zlib.crc32(bytes(data[summary_start:size - len(MAGIC) - 4])))


@st.composite
def mutated_mcap(draw: st.DrawFn, seed: bytes) -> bytes:
    """`seed` with one to three mutations."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 3))):
        records = top_level_records(bytes(data))
        kind = draw(st.sampled_from(["record length", "record length", "chunk field", "chunk field",
                                     "field in a record", "footer field", "bit flip", "truncate", "overwrite"]))
        if kind == "truncate":
            cut = draw(st.integers(0, max(len(data) - 1, 0)))
            keep_magic = draw(st.booleans())  # a truncated copy with the magic re-appended gets past the first check
            data = data[:cut] + (MAGIC if keep_magic else b"")
        elif kind == "bit flip" and data:
            position = draw(st.integers(0, len(data) - 1))
            data[position] ^= 1 << draw(st.integers(0, 7))
        elif kind == "overwrite" and data:
            position = draw(st.integers(0, len(data) - 1))
            chunk = draw(st.binary(min_size=1, max_size=16))
            data[position:position + len(chunk)] = chunk
        elif kind == "record length" and records:
            offset, _, length = draw(st.sampled_from(records))
            struct.pack_into("<Q", data, offset + 1, draw(interesting_u64(length, len(data))))
        elif kind == "chunk field" and any(r[1] == CHUNK_OPCODE for r in records):
            offset, _, length = draw(st.sampled_from([r for r in records if r[1] == CHUNK_OPCODE]))
            body = offset + 9
            if body + 32 > len(data):
                continue
            compression_length = struct.unpack_from("<I", data, body + 28)[0]
            field = draw(st.sampled_from(["uncompressed size", "compression length", "records length",
                                          "uncompressed crc", "start time", "end time"]))
            if field == "uncompressed size":
                old = struct.unpack_from("<Q", data, body + 16)[0]
                struct.pack_into("<Q", data, body + 16, draw(interesting_u64(old, len(data))))
            elif field == "compression length":
                struct.pack_into("<I", data, body + 28, draw(interesting_u32(compression_length)))
            elif field == "records length" and body + 40 + compression_length <= len(data):
                at = body + 32 + compression_length
                old = struct.unpack_from("<Q", data, at)[0]
                struct.pack_into("<Q", data, at, draw(interesting_u64(old, len(data))))
            elif field == "uncompressed crc":
                struct.pack_into("<I", data, body + 24, draw(interesting_u32()))
            else:
                struct.pack_into("<Q", data, body + (0 if field == "start time" else 8), draw(interesting_u64()))
        elif kind == "field in a record" and records:
            offset, _, length = draw(st.sampled_from(records))
            body_end = min(offset + 9 + length, len(data))
            width = draw(st.sampled_from([4, 8]))
            if body_end - width < offset + 9:
                continue
            at = draw(st.integers(offset + 9, body_end - width))
            value = draw(interesting_u32() if width == 4 else interesting_u64(0, len(data)))
            struct.pack_into("<I" if width == 4 else "<Q", data, at, value)
        elif kind == "footer field" and len(data) >= 2 * len(MAGIC) + FOOTER_SIZE:
            footer = len(data) - len(MAGIC) - FOOTER_SIZE
            field = draw(st.sampled_from([1, 9, 17]))  # record length, summary start, summary offset start
            struct.pack_into("<Q", data, footer + field, draw(interesting_u64(0, len(data))))
        if draw(st.booleans()):
            fix_summary_crc(data)
    return Blob(data)


# -- foreign MCAPs -------------------------------------------------------------------------------

_COMPRESSIONS = [CompressionType.NONE, CompressionType.LZ4, CompressionType.ZSTD]
_TOPICS = [*channels.REQUIRED_CHANNELS, channels.COLOR, channels.INSTANCES, channels.GROUND_TRUTH,
           channels.GROUND_TRUTH_POSE, "/camera/image", "/tf", "/chatter", ""]
_MESSAGE_ENCODINGS = ["protobuf", "json", "ros1", "cdr", "flatbuffer", "", "x-unknown"]
_SCHEMA_ENCODINGS = ["protobuf", "jsonschema", "ros1msg", "ros2msg", "flatbuffer", "", "x-unknown"]


@st.composite
def layout(draw: st.DrawFn) -> dict:
    """Options of the mcap library's writer: every layout it can write."""
    chunked = draw(st.booleans())
    return dict(
        use_chunking=chunked,
        compression=draw(st.sampled_from(_COMPRESSIONS)),
        chunk_size=draw(st.sampled_from([64, 1024, 1 << 20])),
        index_types=draw(st.sampled_from([IndexType.NONE, IndexType.ALL, IndexType.CHUNK, IndexType.MESSAGE])),
        repeat_channels=draw(st.booleans()),
        repeat_schemas=draw(st.booleans()),
        use_statistics=draw(st.booleans()),
        use_summary_offsets=draw(st.booleans()),
        enable_crcs=draw(st.booleans()),
    )


def read_messages(path: Path) -> list[tuple]:
    """(schema, channel, message) of every message of a (well-formed) MCAP file."""
    with open(path, "rb") as file:
        return list(make_reader(file).iter_messages(log_time_order=False))


@st.composite
def rewritten_recording(draw: st.DrawFn, messages: list[tuple]) -> bytes:
    """An ndfa recording's messages rewritten by the mcap library in a drawn layout, with some
    messages dropped, duplicated, retimed or damaged: the contract's checks past the file format."""
    import io

    options = draw(layout())
    out = io.BytesIO()
    writer = McapWriter(out, **options)
    writer.start(profile=draw(st.sampled_from(["", "ndfa", "ros1"])), library="fuzz")
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    edits = draw(st.lists(st.tuples(st.integers(0, len(messages) - 1),
                                    st.sampled_from(["drop", "duplicate", "retime", "truncate", "garble", "empty"])),
                          max_size=3))
    by_index = dict(edits)
    for index, (schema, channel, message) in enumerate(messages):
        if schema is not None and schema.id not in schema_ids:
            schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
        if channel.id not in channel_ids:
            channel_ids[channel.id] = writer.register_channel(
                channel.topic, channel.message_encoding, schema_ids.get(channel.schema_id, 0), channel.metadata)
        data, log_time, copies = message.data, message.log_time, 1
        edit = by_index.get(index)
        if edit == "drop":
            continue
        if edit == "duplicate":
            copies = 2
        elif edit == "retime":
            log_time = draw(st.one_of(st.just(0), st.integers(0, 2**64 - 1), st.just(log_time - 1)))
        elif edit == "truncate":
            data = data[:draw(st.integers(0, max(len(data) - 1, 0)))]
        elif edit == "garble":
            data = draw(st.binary(max_size=64))
        elif edit == "empty":
            data = b""
        for _ in range(copies):
            writer.add_message(channel_ids[channel.id], log_time=log_time, data=data,
                               publish_time=message.publish_time, sequence=message.sequence)
    writer.finish()
    return Blob(out.getvalue())


@st.composite
def foreign_mcap(draw: st.DrawFn) -> bytes:
    """An MCAP file some other tool could have written: drawn topics, schemas and encodings (ndfa's
    own names among them), random payloads, in a drawn layout."""
    import io

    out = io.BytesIO()
    writer = McapWriter(out, **draw(layout()))
    writer.start(profile=draw(st.sampled_from(["", "ros1", "ros2", "x"])), library="fuzz")
    channel_ids = []
    for _ in range(draw(st.integers(0, 5))):
        schema_id = 0
        if draw(st.booleans()):
            schema_id = writer.register_schema(
                draw(st.sampled_from(["foxglove.RawImage", "foxglove.CameraCalibration", "foxglove.FrameTransform",
                                      "sensor_msgs/Image", "x", ""])),
                draw(st.sampled_from(_SCHEMA_ENCODINGS)), draw(st.binary(max_size=32)))
        channel_ids.append(writer.register_channel(draw(st.sampled_from(_TOPICS)), draw(st.sampled_from(_MESSAGE_ENCODINGS)),
                                                   schema_id, draw(st.dictionaries(st.text(max_size=4), st.text(max_size=4),
                                                                                   max_size=2))))
    if channel_ids:
        for _ in range(draw(st.integers(0, 8))):
            payload = draw(st.one_of(st.binary(max_size=64), st.sampled_from([b"{}", b"[]", b'{"source": 1}', b"null"])))
            writer.add_message(draw(st.sampled_from(channel_ids)), log_time=draw(st.integers(0, 2**64 - 1)),
                               data=payload, publish_time=0, sequence=draw(st.integers(0, 2**32 - 1)))
    writer.finish()
    return Blob(out.getvalue())
