"""Which frames of a recording a run uses: every frame, every n-th (`--frame-step`), or frames at
most so often by their timestamps (`--rate`).

The frames a run uses are the only frames it reads for anything: the pass perceives them, and a
session whose poses are estimated has them estimated on these frames alone (`ndfa.run.world`: the
odometry then sees the motion between used frames, n times a frame's at `--frame-step n`). The
others are skipped: read through in the file, never decoded. Why and what it costs in accuracy:
docs/speed.md ("The processing rate").
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ndfa.io.recording import RecordingReader

# Frames a second of a recording's own clock a run uses unless told otherwise (`RunOptions.rate_hz`,
# `ndfa detect --rate`; a slower recording keeps every frame). A camera carried at a walking pace
# (0.4 m/s) moves 8 cm between two such frames: the simulator's recordings, on which the method's
# rules and counts of views were measured, are recorded at it, and a 30 Hz camera's neighbouring
# frames add near-copies of a view, not evidence. It also keeps the raw pass ahead of the camera on
# 2 cores. What other rates gave: docs/speed.md ("A default rate").
DEFAULT_RATE_HZ = 5.0

# ... and where a session's poses are estimated, the odometry tracks at most this many frames a
# second (every frame the pass uses among them): a hand-held camera turns up to 90 deg/s, and at 5 Hz
# a simulated office's target facing a faint wall was lost; faster than this the same walk drifted
# more (docs/speed.md, "A default rate").
ODOMETRY_RATE_HZ = 10.0

# Share of the period by which two used frames may be closer than 1 / rate: a recording's
# timestamps jitter (a 30 Hz stream's 33.3 ms steps by a millisecond or more), and at `--rate 15`
# every second frame of it (66.7 ms apart, give or take) should be used, not every third.
RATE_TOLERANCE = 0.1


def at_rate(timestamps: Sequence[float], rate_hz: float) -> list[int]:
    """The positions of the frames used at `rate_hz`: the first frame, then each frame at least
    (1 - RATE_TOLERANCE) / rate_hz seconds after the last one used. A recording at or below the
    rate keeps every frame; one at 30 Hz keeps every 2nd at 15 Hz, every 3rd at 10 Hz, every 2nd at
    20 Hz (at most so often: 15 Hz)."""
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    least = (1.0 - RATE_TOLERANCE) / rate_hz
    used: list[int] = []
    last = 0.0
    for position, timestamp in enumerate(timestamps):
        if not used or timestamp - last >= least:
            used.append(position)
            last = timestamp
    return used


def chosen_rate(rate_hz: float | None, frame_step: int = 1) -> float | None:
    """The rate a run uses for the options given (`ndfa detect --rate`, `--frame-step`): None (no
    rate: every frame, or every `frame_step`-th) for a step above 1 or a rate of 0, else the rate,
    `DEFAULT_RATE_HZ` where none is given."""
    if frame_step > 1 or rate_hz == 0:
        return None
    return DEFAULT_RATE_HZ if rate_hz is None else rate_hz


def used_positions(reader: RecordingReader, frame_step: int = 1, rate_hz: float | None = None) -> Sequence[int]:
    """The positions (`RecordingReader.frames`) of the frames a run uses: every `frame_step`-th
    (a range, the file not read), or, with `rate_hz`, those `at_rate` picks from the recording's
    timestamps (the file read through once). Not both."""
    if frame_step < 1:
        raise ValueError(f"frame_step must be >= 1, got {frame_step}")
    if rate_hz is None:
        return range(0, len(reader), frame_step)
    if frame_step != 1:
        raise ValueError("a frame step and a rate: give one of them")
    return at_rate(reader.timestamps(), rate_hz)


def recorded_seconds(timestamps: Sequence[float]) -> float:
    """How long a recording took to record, seconds: its first to its last frame plus one frame's
    period (the median step), so that 300 frames at 30 Hz are 10 s. What "real time" means for it:
    a run over it in less wall time than this kept up with its camera."""
    times = np.asarray(timestamps, dtype=float)
    if len(times) < 2:
        return 0.0
    return float(times[-1] - times[0] + np.median(np.diff(times)))


def tracked_and_used(reader: RecordingReader, frame_step: int = 1, rate_hz: float | None = None,
                     odometry_rate_hz: float | None = None) -> tuple[Sequence[int], Sequence[int]]:
    """The positions of the frames the odometry tracks (where a session's poses are estimated) and
    of those the pass uses, a subset of them. A frame step above 1 gives both every
    `frame_step`-th frame (the rates play no part); a rate and a faster `odometry_rate_hz` give the
    odometry's frames at that rate and the pass's picked among them at `rate_hz`; otherwise both
    are `used_positions`."""
    if frame_step > 1 or rate_hz is None or odometry_rate_hz is None or odometry_rate_hz <= rate_hz:
        used = used_positions(reader, frame_step, None if frame_step > 1 else rate_hz)
        return used, used
    times = reader.timestamps()
    tracked = at_rate(times, odometry_rate_hz)
    return tracked, [tracked[i] for i in at_rate([times[p] for p in tracked], rate_hz)]


def describe_use(used: Sequence[int], length: int) -> str:
    """How many of a session's frames a run uses, for its notes: "170 of 339 frames"."""
    return f"{len(used)} of {length} frames"
