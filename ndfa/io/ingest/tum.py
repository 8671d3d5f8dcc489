"""`ndfa ingest tum`: turn a TUM RGB-D folder into one recording.

Reading the folder (association, pose interpolation, PNG decoding, and every decision about what
to keep) is `ndfa.io.ingest.tum_folder`'s; this module writes what it yields and says what was
dropped and why, so a user can tell a short recording from a broken folder.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import ndfa
from ndfa.core.color_camera import META_KEY as COLOR_CAMERA_KEY
from ndfa.core.color_camera import ColorCamera
from ndfa.core.errors import IngestError, NdfaError
from ndfa.core.progress import Progress
from ndfa.io.ingest import MAX_DT_S, PoseEstimator
from ndfa.io.ingest.tum_folder import TumFolder
from ndfa.io.ingest.tum_layout import DEPTH_LIST, DEPTH_SCALE, GROUNDTRUTH, Intrinsics
from ndfa.io.recording import RecordingWriter

# What an import without groundtruth.txt says (the summary's notes, the recording's meta "poses_note").
NO_POSES_NOTE = ("{folder} has no " + GROUNDTRUTH + ": the recording keeps no camera poses (as a sensor records); "
                 "`ndfa detect` estimates them (RGB-D odometry), or `--poses estimate` does it once now")


class TumWarning(UserWarning):
    """Something in a TUM folder was off but could be worked around (see the message)."""


@dataclass(frozen=True)
class TumSummary:
    """What `ingest_tum` wrote.

    indexed: depth frames listed in depth.txt; written: frames in the recording;
    dropped: reason -> frames left out; depth_without_rgb: depth frames with no rgb partner within
    max_dt (kept, without colour); warnings: what was worked around; notes: what the user should
    know about the recording (e.g. that it has no poses and who estimates them).
    """

    path: Path
    session: str
    indexed: int
    written: int
    dropped: dict[str, int]
    depth_without_rgb: int
    poses: str
    intrinsics: str
    timestamps: str
    has_instances: bool
    has_ground_truth: bool
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    selected: str = ""  # "start:stop of N paired frames" when only part of the folder was imported


def ingest_tum(
    folder: str | Path,
    out: str | Path,
    *,
    intrinsics: Intrinsics = None,
    depth_scale: float = DEPTH_SCALE,
    masks: str | Path | None = None,
    max_dt: float = MAX_DT_S,
    session: str | None = None,
    estimate_poses: PoseEstimator | None = None,
    frames: tuple[int, int | None] | None = None,
    color_camera: ColorCamera | None = None,
    on_progress: Progress | None = None,  # (frames written, frames to write)
) -> TumSummary:
    """Write the TUM RGB-D folder `folder` into the recording `out` (.mcap).

    intrinsics: None (the folder's calibration.txt if any, else TUM's ROS default 525, 525, 319.5,
        239.5), a TUM preset "fr1" | "fr2" | "fr3", or (fx, fy, cx, cy) in pixels.
    depth_scale: depth PNG units per metre (TUM: 5000). masks: folder of 16-bit instance PNGs named
        as the depth PNGs (default: the folder's masks/ if any). max_dt: largest rgb-depth stamp difference to pair them, seconds.
    session: the recording's session name (default: the folder's name).
    estimate_poses: when given, the recording's poses are estimated with it (e.g. ndfa.trajectory's
        KISS-ICP) and groundtruth.txt's, if any, are kept as the true poses (/ndfa/ground_truth/pose).
        Without it, a folder without groundtruth.txt (a sensor's recording) is kept without poses
        (meta "poses": "none", as a sensor records): `ndfa detect` estimates them (ndfa.run.world).
    frames: (start, stop) of the paired frames to write, as a Python slice (stop None: to the end), e.g.
        the first and the last part of one walk as two sessions. Poses are estimated on these frames only.
    color_camera: the colour camera, when the colour images are not registered to the depth (7-Scenes);
        kept in the meta (`ndfa.core.color_camera`), the images as they are.
    Problems the reader works around are warned about (TumWarning) and listed in the summary.
    """
    tum = TumFolder(Path(folder), intrinsics=intrinsics, depth_scale=depth_scale,
                    masks=Path(masks) if masks is not None else None, max_dt=max_dt)
    out = Path(out)
    session = session or tum.folder.resolve().name
    indexed = len(tum.entries) + sum(tum.dropped.values())
    if frames is not None:
        tum.keep_frames(*frames)
    poses = tum.info.get("poses", "")
    if not tum.entries:  # "empty results are errors": a recording of no frames would only fail later
        raise IngestError(_nothing_to_import(tum.folder, indexed, tum.dropped))
    if tum.needs_poses and estimate_poses is None:
        poses = "none"
    if estimate_poses is not None:
        try:
            # Frames without rgb and instances (the estimator needs depth and K), one at a time.
            tum.set_poses([np.asarray(estimate_poses(frame), dtype=np.float64) for frame in tum.frames(images=False)])
        except NdfaError:
            raise
        except Exception as error:  # the estimator is someone else's code: name it in the message
            name = getattr(estimate_poses, "__module__", "") + "." + getattr(estimate_poses, "__name__", "estimator")
            raise IngestError(f"{tum.folder}: pose estimation ({name}) failed: {error}") from error
        poses = f"estimated ({getattr(estimate_poses, '__module__', 'estimator')})"
        if tum.has_groundtruth:
            poses += f"; {GROUNDTRUTH} kept as the true poses"
    for message in tum.warnings:
        warnings.warn(message, TumWarning, stacklevel=2)

    ground_truth = tum.ground_truth
    meta = {
        "source": "tum",
        "session": session,
        "generator": f"ndfa {ndfa.__version__} ingest tum",
        **tum.info,
        "poses": poses,
        **({"poses_note": NO_POSES_NOTE.format(folder=tum.folder)} if poses == "none" else {}),
        "frames_indexed": indexed,
        "dropped": dict(tum.dropped),
        **({COLOR_CAMERA_KEY: color_camera.to_meta()} if color_camera is not None else {}),
    }
    written = 0
    has_instances = False
    with RecordingWriter(out, meta) as writer:
        if ground_truth is not None:
            writer.write_ground_truth(ground_truth)
        for frame in tum.frames():
            writer.write_frame(frame)
            written += 1
            has_instances = has_instances or frame.instances is not None
            if on_progress is not None:
                on_progress(written, len(tum.entries))
        if written == 0:  # raised inside the block: the writer discards the recording
            raise IngestError(_nothing_to_import(tum.folder, indexed, tum.dropped))
    return TumSummary(
        path=out, session=session, indexed=indexed, written=written, dropped=dict(tum.dropped),
        depth_without_rgb=tum.info["depth_without_rgb"], poses=poses, intrinsics=tum.info["intrinsics"]["source"],
        timestamps=tum.info["timestamps"], has_instances=has_instances, has_ground_truth=ground_truth is not None,
        warnings=list(tum.warnings), notes=[meta["poses_note"]] if "poses_note" in meta else [],
        selected=_selected(tum.info.get("frames_selected")),
    )


def _selected(frames: dict | None) -> str:
    return "" if frames is None else f"{frames['start']}:{frames['stop']} of {frames['of']} paired frames"


def _nothing_to_import(folder: Path, indexed: int, dropped: dict[str, int]) -> str:
    """The one line of an import that would write no frame: what depth.txt listed and why each was dropped."""
    if indexed == 0:
        return f"{folder}: no frames to import: {DEPTH_LIST} lists no depth images"
    reasons = ", ".join(f"{count} {reason}" for reason, count in dropped.items() if count)
    return f"{folder}: no frames to import: all {indexed} depth images of {DEPTH_LIST} were dropped ({reasons})"
