"""TUM trajectory files: one pose per line, "timestamp tx ty tz qx qy qz qw" (seconds, metres,
unit quaternion), '#' starts a comment. The format of the TUM RGB-D benchmark's groundtruth.txt,
read by `evo` (`evo_ape tum truth.txt estimate.txt`), so ndfa's estimates can be checked with it.

Poses are camera-to-world, as everywhere in ndfa. `pose_line` and `pose_from_fields` are the one
writer and reader of a pose line; the TUM folder importer and exporter use them too.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ndfa.core.errors import TrajectoryError
from ndfa.core.geometry import make_pose, matrix_from_quaternion_xyzw, quaternion_xyzw_from_matrix
from ndfa.io.atomic import atomic_path

POSE_FIELDS = "timestamp tx ty tz qx qy qz qw"


def pose_line(timestamp: float, pose: np.ndarray) -> str:
    """One line "timestamp tx ty tz qx qy qz qw" of a (4, 4) pose. 6 decimals of seconds
    (microseconds, as TUM's file names) and 9 of metres and quaternions: below any sensor's precision."""
    values = [*pose[:3, 3], *quaternion_xyzw_from_matrix(pose[:3, :3])]
    return f"{timestamp:.6f} " + " ".join(f"{value:.9f}" for value in values)


def pose_from_fields(fields) -> np.ndarray:
    """The (4, 4) pose of a line's "tx ty tz qx qy qz qw" (7 numbers or number strings; the
    quaternion is normalised)."""
    values = np.asarray(fields, dtype=float)
    return make_pose(matrix_from_quaternion_xyzw(values[3:7]), values[0:3])


def write_tum(path: str | Path, timestamps: Sequence[float] | np.ndarray,
              poses: Sequence[np.ndarray] | np.ndarray) -> None:
    """Write poses (N, 4, 4) at `timestamps` (N,) seconds to `path`, through a temporary file that
    replaces `path` only once it is complete."""
    path = Path(path)
    timestamps, poses = np.asarray(timestamps, dtype=float), np.asarray(poses, dtype=float)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or timestamps.shape != (len(poses),):
        raise TrajectoryError(f"{path}: need N timestamps and (N, 4, 4) poses, got {timestamps.shape} and {poses.shape}")
    lines = [f"# {POSE_FIELDS}"] + [pose_line(stamp, pose) for stamp, pose in zip(timestamps, poses)]
    try:
        with atomic_path(path) as temporary:
            temporary.write_text("\n".join(lines) + "\n")
    except OSError as error:
        raise TrajectoryError(f"cannot write trajectory {path}: {error.strerror or error}") from error


def read_tum(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps (N,) seconds and camera-to-world poses (N, 4, 4) from a TUM trajectory file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as error:
        raise TrajectoryError(f"cannot read trajectory {path}: {error.strerror or error}") from error
    timestamps, poses = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        try:
            values = [float(field) for field in fields]
        except ValueError:
            raise TrajectoryError(f"{path}, line {number}: not numbers: {line!r}") from None
        if len(values) != 8 or not np.all(np.isfinite(values)):
            raise TrajectoryError(f"{path}, line {number}: expected 8 finite numbers "
                                  f"(timestamp tx ty tz qx qy qz qw), got {len(values)}")
        norm = np.linalg.norm(values[4:])
        if not 0.9 < norm < 1.1:
            raise TrajectoryError(f"{path}, line {number}: quaternion norm {norm:.3f} is not 1")
        timestamps.append(values[0])
        poses.append(pose_from_fields(values[1:]))
    if not poses:
        raise TrajectoryError(f"{path}: no poses in the file")
    return np.array(timestamps), np.array(poses)
