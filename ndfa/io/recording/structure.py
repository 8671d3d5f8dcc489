"""The record structure of an MCAP file, checked before the mcap library reads it.

The library trusts the length and size fields it reads: a record, chunk or summary header whose
length is huge, zero or "negative" (a small negative number read as an unsigned 64-bit one) makes it
ask for exabytes (`OverflowError`, `MemoryError`) or read the wrong bytes as the next record. So the
reader first walks the file's records, reading only their headers (a few bytes each, with seeks
between them), and checks that every record ends inside the file, that the records end exactly at
the footer, and that every chunk's sizes agree with each other and stay below a bound. The walk
costs one small read per record: milliseconds for a recording of a few GB in 4 MiB chunks.

Every problem is a `RecordingError` naming the file, the record (by its byte offset) and the field.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import zstandard

from ndfa.core.errors import RecordingError

MAGIC = b"\x89MCAP0\r\n"
FOOTER_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, record length, summary start, summary offset start, summary CRC
_RECORD_HEADER = struct.Struct("<BQ")
_CHUNK_HEADER = struct.Struct("<QQQII")  # start time, end time, uncompressed size, CRC, compression length
_CHUNK_OPCODE, _FOOTER_OPCODE = 0x06, 0x02

# The largest uncompressed chunk the reader decompresses. ndfa writes 4 MiB chunks and other tools
# 1 to 64 MiB; a bigger declared size is a damaged header, which would otherwise be allocated.
MAX_CHUNK_BYTES = 1 << 30
_COMPRESSIONS = ("", "zstd", "lz4")


@dataclass(frozen=True)
class ChunkRecord:
    """Where a chunk record lies (its opcode's offset, its whole length) and what its header says."""

    offset: int
    length: int
    uncompressed_size: int
    compressed_size: int


def check_structure(path: Path, file: BinaryIO, size: int) -> dict[int, ChunkRecord]:
    """Walk the records of `file` (`size` bytes, starting and ending with the magic, footer checked);
    return its chunks by offset. Raise RecordingError at the first record that does not fit."""
    footer_at = size - len(MAGIC) - FOOTER_SIZE
    file.seek(footer_at + _RECORD_HEADER.size)
    summary_start, summary_offset_start = struct.unpack("<QQ", file.read(16))
    chunks: dict[int, ChunkRecord] = {}
    starts: set[int] = set()
    offset = len(MAGIC)
    while offset < footer_at:
        starts.add(offset)
        if offset + _RECORD_HEADER.size > footer_at:
            raise RecordingError(f"{path} is corrupt: a record at byte {offset} is cut off by the footer")
        file.seek(offset)
        opcode, length = _RECORD_HEADER.unpack(file.read(_RECORD_HEADER.size))
        end = offset + _RECORD_HEADER.size + length
        if end > footer_at:
            raise RecordingError(
                f"{path} is corrupt: the record at byte {offset} (opcode 0x{opcode:02x}) says it is {length} bytes "
                f"long, past the end of its section at byte {footer_at}"
            )
        if opcode == _CHUNK_OPCODE:
            chunks[offset] = _check_chunk(path, file, offset, length)
        elif opcode == _FOOTER_OPCODE:
            raise RecordingError(f"{path} is corrupt: a footer record at byte {offset}, before the end of the file")
        offset = end
    if offset != footer_at:
        raise RecordingError(f"{path} is corrupt: its records do not end at its footer (byte {footer_at})")
    for name, start in (("summary", summary_start), ("summary offset", summary_offset_start)):
        if start != 0 and start not in starts and start != footer_at:
            raise RecordingError(f"{path} is corrupt: its footer puts the {name} section at byte {start}, "
                                 "where no record starts")
    return chunks


def check_chunk_indexes(path: Path, chunks: dict[int, ChunkRecord], indexes: list) -> None:
    """Each chunk index of the summary (mcap.records.ChunkIndex) must point at a chunk record of the
    file and agree with its header: the library seeks to the index's offset and reads what it finds."""
    for index in indexes:
        chunk = chunks.get(index.chunk_start_offset)
        if chunk is None:
            raise RecordingError(f"{path} is corrupt: its summary lists a chunk at byte {index.chunk_start_offset}, "
                                 "where there is none")
        if (index.chunk_length, index.uncompressed_size, index.compressed_size) != (
                chunk.length, chunk.uncompressed_size, chunk.compressed_size):
            raise RecordingError(f"{path} is corrupt: the summary's sizes of the chunk at byte {chunk.offset} "
                                 "differ from the chunk's own")


def _check_chunk(path: Path, file: BinaryIO, offset: int, length: int) -> ChunkRecord:
    """The header of the chunk record at `offset` (file positioned at its body): its compression,
    its sizes, and, for zstd, the size the compressed frame itself declares."""
    where = f"{path} is corrupt: the chunk at byte {offset}"
    if length < _CHUNK_HEADER.size + 8:
        raise RecordingError(f"{where} is {length} bytes long, too short for a chunk header")
    _, _, uncompressed_size, _, compression_length = _CHUNK_HEADER.unpack(file.read(_CHUNK_HEADER.size))
    if compression_length > min(length - _CHUNK_HEADER.size - 8, 64):
        raise RecordingError(f"{where} names a compression {compression_length} bytes long")
    compression = file.read(compression_length).decode("utf-8", errors="replace")
    if compression not in _COMPRESSIONS:
        raise RecordingError(f"{where} has compression {compression!r}; ndfa reads zstd, lz4 or none")
    (records_length,) = struct.unpack("<Q", file.read(8))
    if records_length != length - _CHUNK_HEADER.size - compression_length - 8:
        raise RecordingError(
            f"{where} holds {records_length} bytes of records by its header, but its record leaves room for "
            f"{length - _CHUNK_HEADER.size - compression_length - 8}"
        )
    if uncompressed_size > MAX_CHUNK_BYTES:
        raise RecordingError(
            f"{where} says it holds {uncompressed_size} bytes uncompressed, more than ndfa reads in one chunk "
            f"({MAX_CHUNK_BYTES})"
        )
    if compression == "" and uncompressed_size != records_length:
        raise RecordingError(
            f"{where} is uncompressed but says it holds {uncompressed_size} bytes, not its {records_length}"
        )
    if compression == "zstd":
        try:
            declared = zstandard.frame_content_size(file.read(min(records_length, 18)))
        except zstandard.ZstdError as error:
            raise RecordingError(f"{where} does not hold zstd data ({error})") from error
        if declared >= 0 and declared != uncompressed_size:
            raise RecordingError(
                f"{where} says it holds {uncompressed_size} bytes uncompressed, its zstd data {declared}"
            )
    return ChunkRecord(offset, _RECORD_HEADER.size + length, uncompressed_size, records_length)
