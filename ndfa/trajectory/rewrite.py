"""`rewrite_poses`: a copy of a recording whose camera poses (/tf) are estimated from its images.

Methods: "kiss-icp" (depth alone, kiss.py), "rgbd" (colour and depth, with loop closure, rgbd.py),
"estimate" (rgbd when the recording has colour, otherwise kiss-icp).

The copy is the input frame for frame (images, calibration, instances, ground-truth JSON), except
for the pose. The truth is never lost: a recording that already has true poses keeps them; one that
has none keeps its original poses as the true ones. So `ndfa detect` on the copy runs on estimated
poses and still knows the truth, and `rewrite_poses` on the copy measures the estimate again.

`estimate_poses_in_place` is the importers' `--poses estimate|rgbd|kiss-icp`: an import writes
placeholder poses frame by frame, then the whole-session estimate (with loop closure, which needs
every frame) replaces them in the same file.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ndfa.core.errors import TrajectoryError
from ndfa.core.progress import Progress
from ndfa.io.atomic import Staged
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.io.recording.writer import _WRITER_META_KEYS
from ndfa.trajectory.checks import InputWarning
from ndfa.trajectory.kiss import OdometryConfig
from ndfa.trajectory.metrics import AbsoluteError, RelativeError, absolute_trajectory_error, relative_pose_error
from ndfa.trajectory.quality import PoseQuality, judge
from ndfa.trajectory.rgbd import RgbdOdometry, RgbdOdometryConfig
from ndfa.trajectory.session import UNTRACKED_POSES, choose_method, estimate_session_poses, rgbd_config_for

METHODS = ("estimate", "rgbd", "kiss-icp")

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
    refinements_rejected: frames where the point-to-plane refinement (kiss-icp) or the registration
        (rgbd) was not trusted.
    terms: per frame, the residuals it was registered with (rgbd: hybrid, intensity, point-to-plane
        or none; kiss-icp: point-to-plane throughout).
    degenerate_frames: indices of the frames whose depth alone was ambiguous (rgbd).
    keyframes, loop_closures: the rgbd odometry's keyframes and accepted loop edges.
    timestamps (N,) seconds and estimate (N, 4, 4): the estimated trajectory.
    quality: the estimate judged without ground truth (`ndfa.trajectory.quality`).
    """

    recording_in: Path
    recording_out: Path
    method: str
    config: OdometryConfig | RgbdOdometryConfig
    frames: int
    truth: str
    ms_per_frame: float
    starved_frames: int
    refinements_rejected: int
    terms: list[str] = field(default_factory=list)
    degenerate_frames: list[int] = field(default_factory=list)
    keyframes: int = 0
    loop_closures: int = 0
    ate: AbsoluteError | None = None
    rpe: list[RelativeError] = field(default_factory=list)
    timestamps: np.ndarray = field(default_factory=lambda: np.zeros(0))
    estimate: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    quality: PoseQuality | None = None

    def rows(self) -> list[tuple[str, str]]:
        """(figure, value) pairs for a terminal table: errors, time and what the odometry did."""
        rows = []
        if self.ate is not None:
            rows += [("ATE RMSE (SE(3)-aligned)", f"{100 * self.ate.rmse_m:.2f} cm"), ("ATE max", f"{100 * self.ate.max_m:.2f} cm")]
        for rpe in self.rpe:
            delta = f"{rpe.delta:g} {'frame' if rpe.unit == 'frames' else 'm'}"
            rows += [(f"RPE per {delta}: translation RMSE", f"{1000 * rpe.translation_rmse_m:.1f} mm"),
                     (f"RPE per {delta}: rotation RMSE", f"{rpe.rotation_rmse_deg:.3f} deg")]
        rows += [("odometry time", f"{self.ms_per_frame:.0f} ms / frame"),
                 ("frames with too little depth", str(self.starved_frames)),
                 ("registrations rejected" if self.method == "rgbd" else "refinements rejected", str(self.refinements_rejected))]
        if self.method == "rgbd":
            terms = Counter(self.terms).most_common()
            rows += [("terms used", ", ".join(f"{term} {n}" for term, n in terms)),
                     ("degenerate depth frames", str(len(self.degenerate_frames))),
                     ("keyframes, loop closures", f"{self.keyframes}, {self.loop_closures}")]
        if self.quality is not None:
            rows.append(("pose quality (without truth)", self.quality.describe().removeprefix("pose quality ")))
        return rows


def rewrite_poses(recording_in: str | Path, recording_out: str | Path, method: str = "kiss-icp",
                  config: OdometryConfig = OdometryConfig(), on_progress: Progress | None = None,
                  rgbd_config: RgbdOdometryConfig = RgbdOdometryConfig(), given_poses_are_true: bool = True,
                  check_input: bool = True) -> PoseReport:
    """Estimate the camera poses of `recording_in` with `method` and write `recording_out`: the same
    recording with /tf replaced by the estimate (see the module docstring). A pass to estimate
    (`ndfa.trajectory.session`, as `ndfa detect` does), then a pass to write. The output appears
    only when complete. Returns the `PoseReport`.

    given_poses_are_true: where a frame has no true pose, its given pose becomes the true one (and
    the errors are taken against it); False when the given poses are placeholders (an import that
    estimates its poses), so that only real true poses are kept and scored. check_input: warn
    (`InputWarning`) about the input checks' findings; False where the caller already has. A
    recording none of whose frames can be tracked always stops with one line."""
    recording_in, recording_out = Path(recording_in), Path(recording_out)
    if method not in METHODS:
        raise TrajectoryError(f"unknown pose method {method!r}; expected one of {', '.join(METHODS)}")
    if recording_out.resolve() == recording_in.resolve():
        raise TrajectoryError(f"{recording_out}: the output must not replace the input recording")
    reader = RecordingReader(recording_in)
    if method == "estimate":
        method = choose_method(next(iter(reader.frames(stop=1)), None))
    total = 2 * len(reader)
    reference: list[np.ndarray | None] = []
    truth_kinds: set[str] = set()

    def read(frame) -> None:
        reference.append(_true_pose(frame, given_poses_are_true, truth_kinds))
        if on_progress is not None:
            on_progress(len(reference), total)

    rgbd_config = rgbd_config_for(reader.meta, rgbd_config)
    session = estimate_session_poses(reader.frames(), method, recording_in, config, rgbd_config, on_frame=read)
    if check_input:
        for line in session.input_report.warnings(untracked_poses=UNTRACKED_POSES):
            warnings.warn(f"{recording_in}: {line}", InputWarning, stacklevel=2)
    used_config = rgbd_config if method == "rgbd" else config
    with RecordingWriter(recording_out, _output_meta(reader.meta, method, used_config)) as writer:
        if reader.ground_truth is not None:
            writer.write_ground_truth(reader.ground_truth)
        for written, (frame, pose, true_pose) in enumerate(zip(reader.frames(), session.poses, reference, strict=True),
                                                           start=1):
            writer.write_frame(dataclasses.replace(frame, pose_world_camera=pose, pose_world_camera_true=true_pose))
            if on_progress is not None:
                on_progress(len(reference) + written, total)

    odometry = session.odometry
    report = PoseReport(recording_in, recording_out, method, used_config, frames=len(session.poses),
                        truth=" and ".join(sorted(truth_kinds)) or "none", ms_per_frame=odometry.ms_per_frame,
                        starved_frames=odometry.starved_frames, refinements_rejected=0,
                        timestamps=np.array(session.timestamps), estimate=np.array(session.poses).reshape(-1, 4, 4),
                        quality=None if session.evidence is None else judge(session.evidence))
    if isinstance(odometry, RgbdOdometry):
        report.refinements_rejected, report.terms = odometry.rejected_frames, list(odometry.terms)
        report.degenerate_frames, report.keyframes = odometry.degenerate_frames, len(odometry.keyframes)
        report.loop_closures = odometry.loop_closures
    else:
        report.refinements_rejected, report.terms = odometry.refinements_rejected, ["point-to-plane"] * odometry.frames
    _add_errors(report, session.poses, reference)
    return report


def estimate_poses_in_place(recording: str | Path, method: str = "estimate", on_progress: Progress | None = None,
                            rgbd_config: RgbdOdometryConfig = RgbdOdometryConfig(), check_input: bool = True) -> PoseReport:
    """Replace the poses of `recording` (placeholders written by an import) by the whole-session
    estimate of `method`, loop closure included, atomically: the recording is either the old one or
    the complete new one. Its true poses, if any, are kept and scored; its given ones are not."""
    recording = Path(recording)
    staged = Staged(recording)
    try:
        report = rewrite_poses(recording, staged.temporary, method, on_progress=on_progress, rgbd_config=rgbd_config,
                               given_poses_are_true=False, check_input=check_input)
        staged.commit()
    finally:
        staged.discard()
    report.recording_out = recording
    return report


def _true_pose(frame, given_poses_are_true: bool, kinds: set[str]) -> np.ndarray | None:
    """The frame's true pose: its own, else its given one when those count as true (None when not);
    `kinds` collects which it was."""
    if frame.pose_world_camera_true is not None:
        kinds.add("true poses")
        return frame.pose_world_camera_true
    if given_poses_are_true:
        kinds.add("given poses")
        return frame.pose_world_camera
    return None


def _add_errors(report: PoseReport, estimate: list[np.ndarray], reference: list[np.ndarray | None]) -> None:
    """ATE and RPE of the estimate against the reference poses, where there are enough frames and
    every frame has one."""
    if len(estimate) >= 3 and all(pose is not None for pose in reference):
        report.ate = absolute_trajectory_error(estimate, reference)
        for delta, unit in RPE_DELTAS:
            try:
                report.rpe.append(relative_pose_error(estimate, reference, delta, unit))
            except TrajectoryError:
                pass  # the trajectory is shorter than this distance


def _output_meta(meta: dict, method: str, config: OdometryConfig | RgbdOdometryConfig) -> dict:
    """The input's meta (less what the writer sets itself), with the poses' provenance."""
    output = {key: value for key, value in meta.items() if key not in _WRITER_META_KEYS}
    output["poses"] = method
    output["pose_estimation"] = {"method": method, "config": config.to_dict(), "input_poses": meta.get("poses"),
                                 "true_poses": "kept from the input, or the input's poses where it had none"}
    return output
