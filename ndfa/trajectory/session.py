"""One session's camera poses from its images: the input checks, the odometry and the frames it
could not track, in one pass over the frames.

`ndfa detect` (on a recording without poses), `ndfa poses` and the importers' `--poses` all
estimate a session here, so that they give the same pose to every frame:

- every frame is checked on the way (`ndfa.trajectory.checks`); a session none of whose frames can
  be tracked stops with one line naming the source;
- the odometry sees the frames from the first one with usable depth on; it still sees later frames
  without depth, so that its motion model carries on across them (re-acquiring after a hole went
  better so than restarting from the last tracked frame: docs/input_checks.md);
- the poses of frames without usable depth are interpolated between the tracked frames around them
  (`fill_untracked`), not the odometry's extrapolation.

Methods: "rgbd" (colour and depth, loop-closed over the whole session, rgbd.py) and "kiss-icp"
(depth alone, kiss.py); `choose_method` picks rgbd when a recording has colour.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from ndfa.core.color_camera import ColorCamera
from ndfa.core.frame import Frame
from ndfa.io.recording import RecordingReader
from ndfa.trajectory.checks import InputCheckConfig, InputMonitor, InputReport, fill_untracked
from ndfa.trajectory.consistency import DepthSketch, sketch_depth
from ndfa.trajectory.kiss import DepthOdometry, OdometryConfig
from ndfa.trajectory.metrics import one_break_error
from ndfa.trajectory.open3d_threads import open3d_threads
from ndfa.trajectory.quality import PoseEvidence, gather_evidence, judge
from ndfa.trajectory.rgbd import RgbdOdometry, RgbdOdometryConfig

SESSION_METHODS = ("rgbd", "kiss-icp")
UNTRACKED_POSES = "interpolated between the tracked frames around them"  # what the warnings say of them


@dataclass
class SessionPoses:
    """A session's estimated poses, frame by frame, with what the odometry and the checks found.

    poses: (4, 4) camera-to-world per frame, in the frames' order; timestamps, indices: theirs.
    odometry: the estimator after the session (its counters: keyframes, loops, ms per frame, ...).
    input_report: the input checks' findings (`InputReport.warnings(UNTRACKED_POSES)`).
    evidence: how far the poses can be trusted, without ground truth (`ndfa.trajectory.quality`).
    """

    method: str
    poses: list[np.ndarray]
    timestamps: list[float]
    indices: list[int]
    odometry: RgbdOdometry | DepthOdometry
    input_report: InputReport
    evidence: PoseEvidence | None = None

    def describe_method(self) -> str:
        return "rgbd odometry, loop-closed" if self.method == "rgbd" else "kiss-icp, depth only"


def choose_method(first_frame: Frame | None) -> str:
    """"rgbd" when the session's first frame has colour, otherwise "kiss-icp"."""
    return "rgbd" if first_frame is not None and first_frame.rgb is not None else "kiss-icp"


def rgbd_config_for(meta: dict, config: RgbdOdometryConfig = RgbdOdometryConfig()) -> RgbdOdometryConfig:
    """`config` for a recording of this `meta`: with its colour camera when its colour is not
    registered to its depth (`ndfa.core.color_camera`)."""
    camera = ColorCamera.from_meta(meta)
    return config if camera is None else dataclasses.replace(config, color_camera=camera)


def estimate_session_poses(frames: Iterable[Frame], method: str, source: object,
                           kiss_config: OdometryConfig = OdometryConfig(),
                           rgbd_config: RgbdOdometryConfig = RgbdOdometryConfig(),
                           check_config: InputCheckConfig = InputCheckConfig(),
                           on_frame: Callable[[Frame], None] | None = None,
                           backward_frames: Iterable[Frame] | None = None) -> SessionPoses:
    """Estimate every frame's pose (see the module docstring). `source` names the session in the
    one-line error when nothing can be tracked; `on_frame` sees each frame as it is read.
    backward_frames: the same frames in reverse order (`frames_backwards`): with rgbd, a second
    estimate from them, whose disagreement with the first is evidence of drift (`_backward_disagreement`;
    it doubles the odometry's time)."""
    if method not in SESSION_METHODS:
        raise ValueError(f"method must be one of {SESSION_METHODS}, got {method!r}")
    monitor = InputMonitor(check_config)
    fed: list[int] = []  # positions (in the session) of the frames given to the odometry
    timestamps: list[float] = []
    indices: list[int] = []
    sketches: dict[int, DepthSketch] = {}  # by position, the frames with usable depth

    def tracked_frames() -> Iterable[Frame]:
        for position, frame in enumerate(frames):
            if on_frame is not None:
                on_frame(frame)
            timestamps.append(frame.timestamp)
            indices.append(frame.index)
            has_depth = monitor.observe(frame).has_depth
            if has_depth:
                sketches[position] = sketch_depth(frame)
            if has_depth or fed:
                fed.append(position)
                yield frame

    odometry: RgbdOdometry | DepthOdometry
    if method == "rgbd":
        odometry = RgbdOdometry(rgbd_config)
        with open3d_threads():  # the same frames, the same poses (`ndfa.trajectory.open3d_threads`)
            for frame in tracked_frames():
                odometry.update(frame)
            estimate = odometry.finish()
    else:
        odometry = DepthOdometry(kiss_config)
        estimate = [odometry.update(frame) for frame in tracked_frames()]
    report = monitor.report(uses_colour=method == "rgbd")
    if not monitor.checks:
        return SessionPoses(method, [], [], [], odometry, report)
    report.raise_if_untrackable(source)
    poses: list[np.ndarray | None] = [None] * len(monitor.checks)
    for position, pose in zip(fed, estimate, strict=True):
        poses[position] = pose if monitor.checks[position].has_depth else None
    filled = fill_untracked(timestamps, poses)
    evidence = gather_evidence(filled, sketches, odometry, fed)
    if backward_frames is not None and method == "rgbd":
        disagreement = _backward_disagreement(backward_frames, poses, timestamps, rgbd_config, sketches)
        evidence = dataclasses.replace(evidence, backward_disagreement_cm=disagreement)
    return SessionPoses(method, filled, timestamps, indices, odometry, report, evidence)


def frames_backwards(reader: RecordingReader, step: int = 1, chunk: int = 48,
                     positions: Sequence[int] | None = None) -> Iterator[Frame]:
    """`reader.frames(step=step)` (or the frames at `positions`) last first, `chunk` frames at a time in memory."""
    if positions is None:
        positions = range(0, len(reader), step)
    for end in range(len(positions), 0, -chunk):
        start = max(0, end - chunk)
        yield from reversed(list(reader.frames(positions=positions[start:end])))


def _backward_disagreement(frames: Iterable[Frame], poses: list[np.ndarray | None], timestamps: list[float],
                           config: RgbdOdometryConfig, sketches: dict[int, DepthSketch] | None = None) -> float:
    """RMSE (cm, after SE(3) alignment, one break allowed: `metrics.one_break_error`) between
    `poses` (forward, None where not tracked) and the same odometry's estimate from `frames`, the
    session's frames last first. The reverse run chooses its own keyframes, so its drift is its own:
    where the two part along the path, at least one drifted (where they part at one place, one of
    them lost its way there: the step conflicts' matter). Time runs forward for it too (mirrored
    timestamps), so its motion model sees no gap.

    With the frames' depth `sketches`, the backward estimate is judged as the forward one is: when
    it contradicts itself (not good), it broke where the forward run held, and says nothing of it
    (NaN; a textured session at every 2nd frame lost its way backwards at 7.8 cm ATE)."""
    odometry = RgbdOdometry(config)
    end = timestamps[-1] if timestamps else 0.0
    fed: list[int] = []
    with open3d_threads():
        for back, frame in enumerate(frames):
            position = len(poses) - 1 - back
            if position < 0 or poses[position] is None:
                continue  # not tracked forward: nothing to compare
            odometry.update(dataclasses.replace(frame, timestamp=end - frame.timestamp + timestamps[0]))
            fed.append(position)
        backward = odometry.finish() if fed else []
    if len(fed) < 3:
        return float("nan")
    forward = [poses[position] for position in fed]
    if sketches is not None:
        by_position = dict(zip(fed, backward, strict=True))
        judged = gather_evidence([by_position.get(p, np.eye(4)) for p in range(len(poses))],
                                 {p: sketch for p, sketch in sketches.items() if p in by_position}, odometry, fed)
        if not judge(judged).good:
            return float("nan")
    return 100.0 * one_break_error(backward, forward)
