"""The real sequence `ndfa ndf-eval --real DIR` measures: its frames, with the given poses, in a
world turned z-up (the core's convention, `ndfa.core.conventions`), one frame at a time.

DIR is a TUM RGB-D folder (read by the TUM importer's `TumFolder`) or an ndfa recording (.mcap,
e.g. `ndfa ingest tum`'s output). The protocol needs the sequence's own poses (it measures how
steady the NDF's centers are in the world those poses define), so a folder without
groundtruth.txt or a recording without poses is refused rather than given estimated ones.

7-Scenes laid out as a TUM folder (as `../shared/data/redkitchen_7scenes`) carries two files of its
own, used when present: `camera-intrinsics.txt` (the 3 x 3 K; 7-Scenes' depth PNGs are then in
millimetres) and `gravity-direction.txt` (gravity in the poses' world: up is minus it; checked
against the planes' estimate in docs/world_up.md, 1.3 degrees apart). Without a gravity file, up
is estimated from the support planes as `ndfa detect` does (`ndfa.run.world`).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ndfa.core.errors import IngestError, RecordingError
from ndfa.core.frame import Frame
from ndfa.io.ingest.tum_folder import TumFolder
from ndfa.io.ingest.tum_layout import DEPTH_LIST, GROUNDTRUTH
from ndfa.io.recording import RecordingReader
from ndfa.run.world import LEVEL_ABOVE_DEG, UP_FRAMES, prepare_session
from ndfa.trajectory.level import level_frame, levelling_rotation
from ndfa.trajectory.up import angle_deg, estimate_up

SEVEN_SCENES_INTRINSICS = "camera-intrinsics.txt"
SEVEN_SCENES_GRAVITY = "gravity-direction.txt"
SEVEN_SCENES_DEPTH_SCALE = 1000.0  # 7-Scenes' depth PNGs: millimetres


@dataclass
class RealSequence:
    """A real RGB-D sequence with given poses, levelled to z-up.

    path: the folder or recording. frames: how many it has. up: how the world was turned z-up
    (one line). levelling: the (3, 3) rotation applied to every pose, or None (already z-up).
    """

    path: Path
    frame_count: int
    up: str
    levelling: np.ndarray | None
    _tum: TumFolder | None = None
    _reader: RecordingReader | None = None

    def frames(self, step: int = 1) -> Iterator[Frame]:
        """Every `step`-th frame, levelled."""
        if self._reader is not None:
            frames: Iterator[Frame] = self._reader.frames(step=step)
        else:
            assert self._tum is not None
            frames = _tum_frames(self._tum, step)
        for frame in frames:
            yield frame if self.levelling is None else level_frame(frame, self.levelling)


def open_sequence(path: Path) -> RealSequence:
    """The sequence at `path` (a TUM folder or an ndfa .mcap), levelled; one-line errors
    (`IngestError`, `RecordingError`) name the path and the problem."""
    path = Path(path)
    if path.is_dir():
        return _open_tum(path)
    if path.is_file() and path.suffix == ".mcap":
        return _open_recording(path)
    if path.exists():
        raise IngestError(f"{path}: not a TUM RGB-D folder (with {DEPTH_LIST}) nor an ndfa recording (.mcap)")
    raise IngestError(f"{path}: no such folder or recording")


def _open_tum(folder: Path) -> RealSequence:
    intrinsics_file = folder / SEVEN_SCENES_INTRINSICS
    if intrinsics_file.is_file():
        K = _read_matrix(intrinsics_file, (3, 3))
        tum = TumFolder(folder, intrinsics=(K[0, 0], K[1, 1], K[0, 2], K[1, 2]), depth_scale=SEVEN_SCENES_DEPTH_SCALE)
    else:
        tum = TumFolder(folder)
    if tum.needs_poses:
        raise IngestError(f"{folder}: no {GROUNDTRUTH}: the protocol measures the NDF in the world of the "
                          "sequence's given poses")
    if not tum.entries:
        raise IngestError(f"{folder}: no frame of {DEPTH_LIST} can be read ({dict(tum.dropped) or 'none listed'})")
    gravity_file = folder / SEVEN_SCENES_GRAVITY
    if gravity_file.is_file():
        up_world = -_read_matrix(gravity_file, (3,))
        tilt = angle_deg(up_world, np.array([0.0, 0.0, 1.0]))
        levelling = levelling_rotation(up_world) if tilt > LEVEL_ABOVE_DEG else None
        up = f"minus {SEVEN_SCENES_GRAVITY} ({tilt:.1f} deg from the poses' z)"
    else:
        step = max(1, len(tum.entries) // UP_FRAMES)
        estimate = estimate_up(_tum_frames(tum, step))
        if not estimate.ok:
            raise IngestError(f"{folder}: no world up found ({estimate.reason})")
        levelling = estimate.levelling() if estimate.tilt_deg > LEVEL_ABOVE_DEG else None
        up = f"estimated from the support planes ({estimate.tilt_deg:.1f} deg from the poses' z)"
    return RealSequence(folder, len(tum.entries), up, levelling, _tum=tum)


def _open_recording(path: Path) -> RealSequence:
    reader = RecordingReader(path)
    if not reader.has_poses:
        raise RecordingError(f"{path}: has no camera poses: the protocol measures the NDF in the world of "
                             "the sequence's given poses")
    if len(reader) == 0:
        raise RecordingError(f"{path}: has no frames")
    world = prepare_session(reader, str(reader.meta.get("session", path.stem)), poses="given")
    return RealSequence(path, len(reader), world.describe_up(), world.levelling, _reader=reader)


def _tum_frames(tum: TumFolder, step: int) -> Iterator[Frame]:
    """Every `step`-th frame of the folder, numbered as in the whole folder; the others are not
    decoded (a copy of the index keeps every `step`-th entry)."""
    subset = copy.copy(tum)
    subset.entries = tum.entries[::step]
    for frame in subset.frames():
        yield dataclasses.replace(frame, index=frame.index * step)


def _read_matrix(path: Path, shape: tuple[int, ...]) -> np.ndarray:
    try:
        values = np.loadtxt(path, dtype=np.float64)
    except (OSError, ValueError) as error:
        raise IngestError(f"{path}: cannot be read as numbers: {error}") from None
    if values.size != int(np.prod(shape)) or not np.all(np.isfinite(values)):
        raise IngestError(f"{path}: expected {int(np.prod(shape))} finite numbers, got {values.size}")
    return values.reshape(shape)
