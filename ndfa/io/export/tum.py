"""`ndfa export tum`: write an ndfa recording out as a TUM RGB-D folder.

So that TUM tools (evaluate_ate.py, associate.py, viewers) can read ndfa data, and so that the
TUM importer can be tested on a round trip: `ndfa ingest tum` on the folder gives the recording
back (depth to the millimetre, colour, masks, K, poses to 1e-9, ground truth).

The folder: rgb/ and depth/ PNGs named by their timestamp (as TUM does), rgb.txt, depth.txt,
groundtruth.txt (the recording's /tf pose_world_camera, 9 decimals), and ndfa's extensions:
calibration.txt ("fx fy cx cy", which the importer uses when no intrinsics are given), masks/
(16-bit instance PNGs, named as the depth PNGs) when the recording has instances,
ndfa_ground_truth.json when it has ground truth, ndfa_true_poses.txt when it has true poses.
The folder is written under a temporary name and renamed when complete; an existing non-empty
folder is never written into.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

import ndfa
from ndfa.core.errors import ExportError
from ndfa.core.progress import Progress
from ndfa.io.atomic import atomic_dir
from ndfa.io.ingest.tum_layout import (
    CALIBRATION,
    DEPTH_LIST,
    DEPTH_SCALE,
    GROUND_TRUTH_JSON,
    GROUNDTRUTH,
    RGB_LIST,
    TRUE_POSES,
)
from ndfa.io.recording import RecordingReader
from ndfa.io.tum_format import POSE_FIELDS, pose_line

_POSE_HEADER = f"# {POSE_FIELDS} (pose_world_camera: camera optical frame in world)"


@dataclass(frozen=True)
class TumExportSummary:
    """frames: frames written; with_rgb: frames with a colour image; depth_clipped: depth pixels beyond
    the 16-bit range at this depth_scale (65535 / depth_scale metres), written as 0 (invalid)."""

    folder: Path
    frames: int
    with_rgb: int
    with_masks: bool
    with_ground_truth: bool
    depth_clipped: int


def export_tum(recording_path: str | Path, folder: str | Path, depth_scale: float = DEPTH_SCALE,
               on_progress: Progress | None = None) -> TumExportSummary:
    """Write the recording at `recording_path` as a TUM RGB-D folder `folder` (which must not exist,
    or be empty). depth_scale: depth PNG units per metre (TUM: 5000, i.e. 0.2 mm)."""
    if not depth_scale > 0:
        raise ExportError(f"depth scale must be > 0 units per metre, got {depth_scale}")
    folder = Path(folder)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise ExportError(f"{folder} already exists and is not an empty directory; choose a new one")
    reader = RecordingReader(recording_path)
    try:
        with atomic_dir(folder) as temporary:  # renamed over an empty `folder`
            summary = _write_folder(reader, temporary, depth_scale, on_progress)
    except OSError as error:
        raise ExportError(f"cannot write {folder}: {error.strerror or error}") from None
    return TumExportSummary(folder, *summary)


def _write_folder(reader: RecordingReader, out: Path, depth_scale: float,
                  on_progress: Progress | None) -> tuple[int, int, bool, bool, int]:
    for name in ("rgb", "depth") + (("masks",) if reader.has_instances else ()):
        (out / name).mkdir()
    origin = f"# exported from {reader.path.name} by ndfa {ndfa.__version__}"
    rgb_lines = [f"# color images\n{origin}\n# timestamp filename"]
    depth_lines = [f"# depth images, {depth_scale:g} units per metre, 0 = invalid\n{origin}\n# timestamp filename"]
    pose_lines = [f"# ground truth trajectory\n{origin}\n{_POSE_HEADER}"]
    true_pose_lines = [f"# true camera poses (groundtruth.txt holds the recording's, possibly perturbed ones)\n"
                       f"{origin}\n{_POSE_HEADER}"]
    K, names, clipped, frames, with_rgb = None, set(), 0, 0, 0
    for frame in reader.frames():
        stamp = f"{frame.timestamp:.6f}"
        if stamp in names:
            raise ExportError(f"{reader.path}: two frames at t = {stamp} s; TUM file names (microseconds) cannot "
                              "tell them apart")
        names.add(stamp)
        if K is None:
            K = frame.K
        elif not np.array_equal(frame.K, K):
            raise ExportError(f"{reader.path}: frame {frame.index} has other intrinsics than the first frame; "
                              "a TUM folder has one calibration")

        depth_units = np.round(frame.depth.astype(np.float64) * depth_scale)
        too_far = depth_units > np.iinfo(np.uint16).max
        clipped += int(too_far.sum())
        depth_units[too_far] = 0
        _write_png(out / "depth" / f"{stamp}.png", depth_units.astype(np.uint16))
        depth_lines.append(f"{stamp} depth/{stamp}.png")
        if frame.rgb is not None:
            _write_png(out / "rgb" / f"{stamp}.png", frame.rgb)
            rgb_lines.append(f"{stamp} rgb/{stamp}.png")
            with_rgb += 1
        if frame.instances is not None:
            _write_png(out / "masks" / f"{stamp}.png", frame.instances)
        pose_lines.append(pose_line(frame.timestamp, frame.pose_world_camera))
        if frame.pose_world_camera_true is not None:
            true_pose_lines.append(pose_line(frame.timestamp, frame.pose_world_camera_true))
        frames += 1
        if on_progress is not None:
            on_progress(frames, len(reader))

    for name, lines in ((RGB_LIST, rgb_lines), (DEPTH_LIST, depth_lines), (GROUNDTRUTH, pose_lines)):
        (out / name).write_text("\n".join(lines) + "\n")
    if len(true_pose_lines) > 1:
        (out / TRUE_POSES).write_text("\n".join(true_pose_lines) + "\n")
    if K is not None:
        (out / CALIBRATION).write_text(
            f"# pinhole intrinsics in pixels, from {reader.path.name}; `ndfa ingest tum` reads this file when no "
            f"--intrinsics is given\n# fx fy cx cy\n"
            + " ".join(repr(float(v)) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2])) + "\n")
    truth = reader.ground_truth
    if truth is not None:
        (out / GROUND_TRUTH_JSON).write_text(json.dumps(truth, indent=1))
    return frames, with_rgb, reader.has_instances, truth is not None, clipped


def _write_png(path: Path, pixels: np.ndarray) -> None:
    try:
        Image.fromarray(pixels).save(path)
    except OSError as error:
        raise ExportError(f"cannot write {path}: {error.strerror or error}") from None
