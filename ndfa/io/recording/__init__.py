"""The recording contract: one MCAP file per session, written by every importer, read by every stage.

See channels.py for what the file holds, frame.py for the in-memory frame, writer.py and reader.py.
"""

from ndfa.core.frame import Frame
from ndfa.io.recording.channels import (
    CALIBRATION,
    COLOR,
    DEPTH,
    GROUND_TRUTH,
    GROUND_TRUTH_POSE,
    INSTANCES,
    META,
    TF,
)
from ndfa.io.recording.reader import RecordingReader
from ndfa.io.recording.writer import RecordingWriter

__all__ = [
    "CALIBRATION",
    "COLOR",
    "DEPTH",
    "GROUND_TRUTH",
    "GROUND_TRUTH_POSE",
    "INSTANCES",
    "META",
    "TF",
    "Frame",
    "RecordingReader",
    "RecordingWriter",
]
