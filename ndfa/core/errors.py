"""Error types. Each package raises its own subclass; the CLI turns any `NdfaError` into a one-line
message and a non-zero exit code, so a user never sees a traceback for bad input."""


class NdfaError(Exception):
    """Base class of every error ndfa raises on purpose."""


class RecordingError(NdfaError):
    """A recording (MCAP file) is missing, unreadable, truncated or breaks the recording contract."""


class SimError(NdfaError):
    """The synthetic world cannot be built as asked (unknown preset, bad mesh, impossible layout)."""


class IngestError(NdfaError):
    """An importer cannot turn its input into a recording."""


class ModelError(NdfaError):
    """An NDF model cannot be built or loaded (bad config, missing or corrupt checkpoint)."""


class DataError(NdfaError):
    """NDF training data cannot be generated as asked, or a dataset file is missing or corrupt."""


class TrajectoryError(NdfaError):
    """Poses cannot be estimated, compared or read/written as asked (bad config, unknown method,
    trajectories of different lengths, a malformed TUM trajectory file)."""


class ExportError(NdfaError):
    """A recording cannot be written out in another format (a ROS bag, a TUM folder)."""


class OptionError(NdfaError):
    """A command-line option's value is out of its range, or names an output path that cannot be written."""


class OutputError(NdfaError):
    """An output cannot be written where asked (a directory or special file in the way, no writable folder)."""


class SweepError(NdfaError):
    """A sweep (`ndfa eval --sweep`) cannot be set up, resumed or run as asked."""


class ViewerError(NdfaError):
    """A recording cannot be shown: no display for the desktop viewer, or the web viewer cannot serve."""
