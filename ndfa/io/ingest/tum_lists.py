"""The text files of a TUM RGB-D folder: list files parsed, rgb paired with depth, poses placed at stamps.

rgb.txt and depth.txt hold lines "timestamp relative/path.png", groundtruth.txt (and ndfa's
ndfa_true_poses.txt) lines "timestamp tx ty tz qx qy qz qw"; '#' starts a comment line.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ndfa.core.errors import IngestError
from ndfa.core.geometry import interpolate_pose
from ndfa.io.ingest.tum_layout import GROUNDTRUTH, TRUE_POSES

# A depth frame between two groundtruth poses further apart than this is dropped: the motion
# capture lost the camera there, and interpolating across the gap would invent a pose.
MAX_POSE_GAP_S = 0.1
# Two stamps closer than this are the same moment (TUM files print 4 to 6 decimals).
SAME_STAMP_S = 1e-6


@dataclass
class StampedList:
    """A parsed TUM list file: stamps and the rest of each data line."""

    path: Path
    stamps: np.ndarray  # (N,) float64 seconds
    fields: list[list[str]]
    line_numbers: list[int]  # 1-based line numbers in the file, for messages

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


def read_list(folder: Path, name: str, required: bool) -> StampedList | None:
    """Parse the list file `name` of `folder`: '#' comments and blank lines skipped, a number first
    on every other line (then 7 more for the pose files). None when it is missing and not required."""
    path = folder / name
    if not path.is_file():
        if required:
            raise IngestError(f"{path}: no such file; a TUM RGB-D folder needs {name} "
                              f"(lines 'timestamp depth/NAME.png')")
        return None
    columns = 8 if name in (GROUNDTRUTH, TRUE_POSES) else 2
    stamps, rows, numbers = [], [], []
    try:
        lines = path.read_text().splitlines()
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
    return StampedList(path, np.array(stamps, dtype=np.float64), rows, numbers)


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
