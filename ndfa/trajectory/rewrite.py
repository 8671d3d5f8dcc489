"""`rewrite_poses`: a copy of a recording whose camera poses (/tf) are estimated from its depth.

The copy is the input frame for frame (images, calibration, instances, ground-truth JSON), except
for the pose. The truth is never lost: a recording that already has true poses keeps them; one that
has none keeps its original poses as the true ones. So `ndfa detect` on the copy runs on estimated
poses and still knows the truth, and `rewrite_poses` on the copy measures the estimate again.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ndfa.core.errors import TrajectoryError
from ndfa.core.progress import Progress
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.trajectory.kiss import DepthOdometry, OdometryConfig
from ndfa.trajectory.metrics import AbsoluteError, RelativeError, absolute_trajectory_error, relative_pose_error

METHODS = ("kiss-icp",)

# The RPE distances reported: one frame (drift per step) and one metre travelled (drift per metre).
RPE_DELTAS: tuple[tuple[float, str], ...] = ((1, "frames"), (1.0, "m"))



@dataclass
class PoseReport:
    """What `rewrite_poses` did and how good the estimate is.

    truth: where the reference poses came from: "true poses" (the recording's true-pose channel)
        or "given poses" (its /tf, when it has no true poses: the error is then against whatever
        the recording held, e.g. a dataset's ground truth or another odometry).
    ate, rpe: errors of the estimate against that reference (None when there are fewer than 3
        frames, or an RPE distance longer than the trajectory).
    ms_per_frame: mean odometry time per frame (back-projection and registration; not reading,
        decoding or writing the recording).
    starved_frames: frames with too little valid depth to register (their pose is predicted).
    refinements_rejected: frames where the point-to-plane refinement was not trusted.
    timestamps (N,) seconds and estimate (N, 4, 4): the estimated trajectory.
    """

    recording_in: Path
    recording_out: Path
    method: str
    config: OdometryConfig
    frames: int
    truth: str
    ms_per_frame: float
    starved_frames: int
    refinements_rejected: int
    ate: AbsoluteError | None = None
    rpe: list[RelativeError] = field(default_factory=list)
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    estimate: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))


def rewrite_poses(recording_in: str | Path, recording_out: str | Path, method: str = "kiss-icp",
                  config: OdometryConfig = OdometryConfig(), on_progress: Progress | None = None) -> PoseReport:
    """Estimate the camera poses of `recording_in` with `method` and write `recording_out`: the same
    recording with /tf replaced by the estimate (see the module docstring). One pass, one frame in
    memory at a time; the output appears only when complete. Returns the `PoseReport`."""
    recording_in, recording_out = Path(recording_in), Path(recording_out)
    if method not in METHODS:
        raise TrajectoryError(f"unknown pose method {method!r}; expected one of {', '.join(METHODS)}")
    if recording_out.resolve() == recording_in.resolve():
        raise TrajectoryError(f"{recording_out}: the output must not replace the input recording")
    reader = RecordingReader(recording_in)
    meta = _output_meta(reader.meta, method, config)

    odometry = DepthOdometry(config)
    timestamps, estimate, reference = [], [], []
    truth_kinds: set[str] = set()
    with RecordingWriter(recording_out, meta) as writer:
        if reader.ground_truth is not None:
            writer.write_ground_truth(reader.ground_truth)
        for frame in reader.frames():
            pose = odometry.update(frame)
            true_pose = frame.pose_world_camera_true
            truth_kinds.add("true poses" if true_pose is not None else "given poses")
            if true_pose is None:
                true_pose = frame.pose_world_camera
            writer.write_frame(dataclasses.replace(frame, pose_world_camera=pose, pose_world_camera_true=true_pose))
            timestamps.append(frame.timestamp)
            estimate.append(pose)
            reference.append(true_pose)
            if on_progress is not None:
                on_progress(len(estimate), len(reader))

    report = PoseReport(recording_in, recording_out, method, config, frames=len(estimate),
                        truth=" and ".join(sorted(truth_kinds)) or "none", ms_per_frame=odometry.ms_per_frame,
                        starved_frames=odometry.starved_frames, refinements_rejected=odometry.refinements_rejected,
                        timestamps=np.array(timestamps), estimate=np.array(estimate).reshape(-1, 4, 4))
    if len(estimate) >= 3:
        report.ate = absolute_trajectory_error(estimate, reference)
        for delta, unit in RPE_DELTAS:
            try:
                report.rpe.append(relative_pose_error(estimate, reference, delta, unit))
            except TrajectoryError:
                pass  # the trajectory is shorter than this distance
    return report


def _output_meta(meta: dict, method: str, config: OdometryConfig) -> dict:
    """The input's meta (less what the writer sets itself), with the poses' provenance."""
    from ndfa.io.recording.writer import _WRITER_META_KEYS

    output = {key: value for key, value in meta.items() if key not in _WRITER_META_KEYS}
    output["poses"] = method
    output["pose_estimation"] = {"method": method, "config": config.to_dict(), "input_poses": meta.get("poses"),
                                 "true_poses": "kept from the input, or the input's poses where it had none"}
    return output
