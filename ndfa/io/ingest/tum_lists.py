"""The text files of a TUM RGB-D folder: list files parsed, rgb paired with depth, poses placed at stamps.

rgb.txt and depth.txt hold lines "timestamp relative/path.png", groundtruth.txt (and ndfa's
ndfa_true_poses.txt) lines "timestamp tx ty tz qx qy qz qw"; '#' starts a comment line.

Timestamps are seconds. A converter may have written them in milliseconds, microseconds or
nanoseconds instead (a realistic unit mistake), since 1970 or since the recording's start. The unit
is told first by the lines' median interval, which puts a camera at 0.2 to 300 frames per second
and a pose source (motion capture, keyframes) at 0.2 to 2000 poses per second in one unit only
(seconds where that fits, then the unit the depth list turned out to have); failing that, by the
stamps' size (beyond 1.8e10 s, the latest time an MCAP recording holds: from 1e11, 1e14, 1e17).
Stamps not in seconds are read as seconds, with a warning; stamps that no unit makes such seconds
are refused. A list whose lines are out of time order is sorted by stamp, with a warning
(`StampedList.in_time_order`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ndfa.core.errors import IngestError
from ndfa.core.geometry import interpolate_pose
from ndfa.io.ingest.tum_layout import GROUNDTRUTH, TRUE_POSES
from ndfa.io.recording.writer import MAX_TIMESTAMP_S

# A depth frame between two groundtruth poses further apart than this is dropped: the motion
# capture lost the camera there, and interpolating across the gap would invent a pose.
MAX_POSE_GAP_S = 0.1
# Two stamps closer than this are the same moment (TUM files print 4 to 6 decimals).
SAME_STAMP_S = 1e-6
# Stamps this large are no seconds since 1970: (threshold, units per second, unit), largest first.
OTHER_UNITS = ((1e17, 1e9, "nanoseconds"), (1e14, 1e6, "microseconds"), (1e11, 1e3, "milliseconds"))
# The units a list may hold, seconds first, and the plausible time between two of its lines in
# seconds (from the frame rates above): each range spans more than 1000 times, so the ranges of
# neighbouring units overlap only at their ends.
UNITS = ((1.0, "seconds"), (1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds"))
CAMERA_INTERVAL_S = (1 / 300, 5.0)
POSE_INTERVAL_S = (1 / 2000, 5.0)


@dataclass
class StampedList:
    """A parsed TUM list file: stamps and the rest of each data line."""

    path: Path
    stamps: np.ndarray  # (N,) float64 seconds
    fields: list[list[str]]
    line_numbers: list[int]  # 1-based line numbers in the file, for messages
    warnings: list[str] = field(default_factory=list)  # what reading it worked around
    per_second: float = 1.0  # the file's stamps per second of `stamps`: its unit

    @property
    def increasing(self) -> bool:
        return bool(np.all(np.diff(self.stamps) > 0))

    def disorder(self, negative_ok: bool) -> str:
        """Where the stamps first go wrong, for messages."""
        for k, stamp in enumerate(self.stamps):
            if stamp < 0 and not negative_ok:
                return f"line {self.line_numbers[k]} has the negative timestamp {stamp}"
            if k > 0 and stamp <= self.stamps[k - 1]:
                return (f"line {self.line_numbers[k]} ({stamp}) is not after line "
                        f"{self.line_numbers[k - 1]} ({self.stamps[k - 1]})")
        return "none"

    def in_time_order(self, negative_ok: bool) -> StampedList:
        """This list, its lines sorted by stamp when they are out of order but the stamps are usable
        (distinct; none negative unless `negative_ok`), with a warning; otherwise as it is (the caller
        falls back to file order)."""
        if self.increasing:
            return self
        order = np.argsort(self.stamps, kind="stable")
        stamps = self.stamps[order]
        if not (np.all(np.diff(stamps) > 0) and (negative_ok or np.all(stamps >= 0))):
            return self
        moved = int(np.sum(order != np.arange(len(order))))
        return replace(self, stamps=stamps, fields=[self.fields[k] for k in order],
                       line_numbers=[self.line_numbers[k] for k in order],
                       warnings=[*self.warnings, f"{self.path}: lines not in time order ({self.disorder(True)}); "
                                 f"sorted by timestamp ({moved} of {len(order)} lines moved)"])


def read_list(folder: Path, name: str, required: bool, likely_per_second: float = 1.0) -> StampedList | None:
    """Parse the list file `name` of `folder`: '#' comments and blank lines skipped, a number first
    on every other line (then 7 more for the pose files). None when it is missing and not required.
    `likely_per_second`: the unit to prefer where the interval fits more than one (the depth list's)."""
    path = folder / name
    if path.exists() and not path.is_file():
        raise IngestError(f"{path}: is {'a directory' if path.is_dir() else 'not a regular file'}, not a list file "
                          f"(lines 'timestamp PATH')")
    if not path.is_file():
        if required:
            raise IngestError(f"{path}: no such file; a TUM RGB-D folder needs {name} "
                              f"(lines 'timestamp depth/NAME.png')")
        return None
    columns = 8 if name in (GROUNDTRUTH, TRUE_POSES) else 2
    stamps, rows, numbers = [], [], []
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()  # a byte order mark (some editors write one) skipped
    except (OSError, UnicodeDecodeError) as error:
        raise IngestError(f"{path} cannot be read: {error}") from error
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        try:
            if len(parts) < columns:
                raise ValueError(f"expected {columns} fields, got {len(parts)}")
            stamp = float(parts[0])
            values = [float(v) for v in parts[1:columns]] if columns == 8 else None
            if not np.isfinite(stamp) or (values is not None and not np.all(np.isfinite(values))):
                raise ValueError("not a finite number")
            if values is not None:
                _check_quaternion(values[3:7])
        except ValueError as error:
            raise IngestError(f"{path}, line {number}: cannot read {text!r}: {error}") from None
        stamps.append(stamp)
        rows.append(parts[1:columns])
        numbers.append(number)
    interval = POSE_INTERVAL_S if columns == 8 else CAMERA_INTERVAL_S
    raw = np.array(stamps, dtype=np.float64)
    per_second, warnings = _unit(path, raw, interval, likely_per_second)
    return StampedList(path, raw / per_second, rows, numbers, warnings, per_second)


def _unit(path: Path, stamps: np.ndarray, interval_s: tuple[float, float], likely_per_second: float
          ) -> tuple[float, list[str]]:
    """The stamps' units per second (see the module docstring), and the warning when they are not seconds."""
    top = float(np.max(np.abs(stamps))) if len(stamps) else 0.0
    steps = np.diff(np.unique(stamps))
    if len(steps):
        step = float(np.median(steps))
        fitting = [(per_second, unit) for per_second, unit in UNITS
                   if top / per_second < MAX_TIMESTAMP_S and interval_s[0] <= step / per_second <= interval_s[1]]
        if fitting:
            per_second, unit = next((f for f in fitting if f[0] == likely_per_second), fitting[0])
            if per_second == 1.0:
                return 1.0, []
            return per_second, [
                f"{path}: timestamps {float(stamps.min()):.6g} to {float(stamps.max()):.6g}, {step:.6g} apart (median), look like {unit}, "
                f"not seconds ({per_second / step:.3g} lines per second, where seconds would give {1 / step:.3g}); "
                f"read as seconds ({unit} / {per_second:g})"]
    if top < MAX_TIMESTAMP_S:
        return 1.0, []
    for threshold, per_second, unit in OTHER_UNITS:
        if top >= threshold and top / per_second < MAX_TIMESTAMP_S:
            return per_second, [f"{path}: timestamps up to {top:.6g} look like {unit}, not seconds; read "
                                f"as seconds ({unit} / {per_second:g})"]
    raise IngestError(f"{path}: timestamps up to {top:.6g} are no time in seconds (nor in milliseconds, microseconds "
                      f"or nanoseconds): TUM lists hold seconds, up to {MAX_TIMESTAMP_S:.4g} (what MCAP can hold)")


def _check_quaternion(q: list[float]) -> None:
    """A ValueError unless (qx, qy, qz, qw) can be normalised into a rotation: a zero (or, past
    floating point, an infinite) length has no direction, and would make every pose element NaN."""
    with np.errstate(over="ignore", under="ignore"):
        length = float(np.linalg.norm(q))
    if not 1e-12 < length < np.inf:
        raise ValueError(f"the quaternion qx qy qz qw has length {length:g}: it is no rotation")


def associate(depth_stamps: np.ndarray, rgb_stamps: np.ndarray, max_dt: float) -> dict[int, int]:
    """depth index -> rgb index: closest pairs within max_dt first, each frame used once (TUM's associate.py)."""
    candidates = []
    for i, stamp in enumerate(depth_stamps):
        lo, hi = np.searchsorted(rgb_stamps, [stamp - max_dt, stamp + max_dt], side="left")
        for j in range(lo, min(hi + 1, len(rgb_stamps))):
            dt = abs(rgb_stamps[j] - stamp)
            if dt <= max_dt:
                candidates.append((dt, i, j))
    pairs, used_rgb = {}, set()
    for _, i, j in sorted(candidates):
        if i not in pairs and j not in used_rgb:
            pairs[i] = j
            used_rgb.add(j)
    return pairs


def poses_at(pose_stamps: np.ndarray, poses: np.ndarray, stamps: np.ndarray
             ) -> list[tuple[np.ndarray | None, str | None]]:
    """Pose at each stamp (interpolated between its two neighbours), or (None, why not): outside
    the poses' time span, or in a gap between them over `MAX_POSE_GAP_S`."""
    placed = []
    for stamp in stamps:
        k = int(np.searchsorted(pose_stamps, stamp))
        for near in (k - 1, k):
            if 0 <= near < len(pose_stamps) and abs(pose_stamps[near] - stamp) <= SAME_STAMP_S:
                placed.append((poses[near], None))
                break
        else:
            if k == 0 or k == len(pose_stamps):
                placed.append((None, "outside the groundtruth time span"))
            elif pose_stamps[k] - pose_stamps[k - 1] > MAX_POSE_GAP_S:
                placed.append((None, f"in a groundtruth gap over {MAX_POSE_GAP_S:g} s"))
            else:
                t0, t1 = pose_stamps[k - 1], pose_stamps[k]
                placed.append((interpolate_pose(poses[k - 1], poses[k], (stamp - t0) / (t1 - t0)), None))
    return placed
