"""The reader checks the format, the version and every meta field it uses (issue 31): a recording
whose meta is not what ndfa writes fails on open, in one line naming the file and the field."""

import json
import math
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from ndfa.cli import main
from ndfa.core.errors import RecordingError
from ndfa.io.recording import RecordingReader, channels

SAMPLE = Path(__file__).parents[1] / "recordings" / "sample" / "target.mcap"


def with_meta(path: Path, change) -> Path:
    """The sample recording, its meta replaced by `change(meta)` (a dict, or anything JSON)."""
    with open(SAMPLE, "rb") as file, open(path, "wb") as out:
        writer = Writer(out)
        writer.start(profile="ndfa", library="test")
        schemas: dict[int, int] = {}
        ids: dict[int, int] = {}
        for schema, channel, message in make_reader(file).iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in ids:
                ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                          schemas.get(channel.schema_id, 0), channel.metadata)
            data = message.data
            if channel.topic == channels.META:
                data = json.dumps(change(json.loads(data)), allow_nan=True).encode()
            writer.add_message(ids[channel.id], log_time=message.log_time, data=data,
                               publish_time=message.publish_time, sequence=message.sequence)
        writer.finish()
    return path


def replaced(**fields):
    return lambda meta: {**meta, **fields}


@pytest.mark.parametrize("change, fragment", [
    (replaced(depth_scale=math.nan), "depth_scale must be a finite number from 1e-06 to 1"),
    (replaced(depth_scale=math.inf), "depth_scale must be a finite number"),
    (replaced(depth_scale=1e300), "got 1e+300"),
    (replaced(depth_scale=1e-300), "got 1e-300"),
    (replaced(depth_scale="0.001"), "depth_scale must be"),
    (replaced(format_version=99), "format_version 99 is newer than this ndfa reads (1)"),
    (replaced(format_version=True), "format_version must be a positive integer"),
    (replaced(format="other"), "format must be 'ndfa.recording', got 'other'"),
    (lambda meta: {}, "is empty"),
    (replaced(frame_rate_hz="fast"), "frame_rate_hz must be a finite number"),
    (replaced(frame_rate_hz=-5), "frame_rate_hz must be"),
    (replaced(session=""), "session must be a non-empty string"),
    (replaced(poses=0), "poses must be a string"),
])
def test_a_meta_ndfa_did_not_write_fails_on_open_naming_the_field(tmp_path, change, fragment):
    path = with_meta(tmp_path / "odd.mcap", change)
    with pytest.raises(RecordingError) as error:
        RecordingReader(path)
    assert str(error.value).startswith(f"{path}: channel {channels.META}: ")
    assert fragment in str(error.value)


def test_info_and_detect_say_it_in_one_line(tmp_path, monkeypatch, capsys):
    path = with_meta(tmp_path / "odd.mcap", replaced(depth_scale=math.nan))
    for args in (["info", path], ["detect", path, SAMPLE]):
        monkeypatch.setattr(sys, "argv", ["ndfa", *map(str, args)])
        with pytest.raises(SystemExit) as done:
            main()
        err = capsys.readouterr().err
        assert done.value.code == 2 and [line for line in err.splitlines() if line.startswith("error:")] == [
            f"error: {path}: channel {channels.META}: depth_scale must be a finite number from 1e-06 to 1 (metres per "
            "depth unit), got nan"], err


def test_what_ndfa_writes_passes(tmp_path):
    path = with_meta(tmp_path / "same.mcap", lambda meta: meta)
    assert RecordingReader(path).meta["format_version"] == 1
