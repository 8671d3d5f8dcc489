"""Input checks for pose estimation: what in a session's frames leaves the odometry guessing, named
frame by frame, so that a bad recording gives a warning (or one clean error) instead of a quietly
wrong trajectory and an empty detection run.

Three kinds of input defeat odometry without it failing outright:

- **time gaps** (a dropped stretch of a stream, a paused recording): the camera's motion across
  the gap is not observed, and a motion prediction made per frame does not know that more time
  passed than usual;
- **frames without depth** (lens covered, too close, too far, a sensor hiccup): nothing to register;
- **flat views** (only a wall, a wall and the floor): the depth term cannot see the camera's slide
  along the planes; colour can pin it where the surfaces are textured, nothing can where they are
  not (docs/odometry.md).

`InputMonitor.observe(frame)` looks at one frame (its timestamp, depth, colour; a few ms at 320 px
wide), `InputMonitor.report()` judges the session. A session none of whose frames can be tracked
(no usable depth anywhere, or only flat untextured views) is `InputReport.untrackable`; callers
stop there with one line naming the file. The poses of frames without depth are not the odometry's
extrapolation: every estimate of a session's poses (`ndfa.trajectory.session`) interpolates them
between the tracked frames around them (`fill_untracked`).

Pure: frames in, a report out (no file I/O). docs/input_checks.md shows the warnings.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M, depth_in_range
from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import interpolate_pose
from ndfa.trajectory.degeneracy import depth_degeneracy, plane_information, textured_fraction


class InputWarning(UserWarning):
    """A session's frames will give poor poses in places (the message names the frames)."""


@dataclass(frozen=True)
class InputCheckConfig:
    """Thresholds of the input checks (docs/input_checks.md).

    gap_s, gap_factor: a time gap is a step between consecutive frames longer than both `gap_s`
        seconds and `gap_factor` times the session's median step. 0.5 s is 15 dropped frames at
        30 Hz; the factor keeps a slowly sampled session (a few frames per second) from being
        flagged throughout.
    min_depth_fraction: a frame has usable depth when at least this fraction of its pixels lies in
        the method's depth range (the RGB-D odometry's own `min_valid_fraction`, so the frames named
        are the ones it cannot register).
    flat_ratio: a view is flat when the degeneracy ratio of its point-to-plane information matrix
        (`degeneracy.depth_degeneracy`) is below this: the RGB-D odometry's `degenerate_ratio`
        (a wall and the floor: 0.0007; the synthetic rooms' views with tables: 0.005-0.03).
    gradient_threshold, textured_fraction: a view is textured when at least `textured_fraction` of
        its valid-depth pixels have an intensity gradient above `gradient_threshold` (as the RGB-D
        odometry judges it).
    max_width: images are looked at subsampled to at most this width (the odometry's 320 px).
    """

    gap_s: float = 0.5
    gap_factor: float = 10.0
    min_depth_fraction: float = 0.05
    flat_ratio: float = 0.003
    gradient_threshold: float = 0.02
    textured_fraction: float = 0.003
    max_width: int = 320

    def __post_init__(self) -> None:
        for name in ("gap_s", "gap_factor", "flat_ratio", "max_width"):
            if not getattr(self, name) > 0:
                raise TrajectoryError(f"input check {name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.min_depth_fraction <= 1.0:
            raise TrajectoryError(f"input check min_depth_fraction must be in [0, 1], got {self.min_depth_fraction}")


@dataclass(frozen=True)
class FrameCheck:
    """What one frame offers the odometry.

    depth_fraction: fraction of its pixels with depth in the method's range.
    has_depth: depth_fraction reaches the threshold (the frame can be registered).
    flat: it has depth and its view is flat (see `InputCheckConfig.flat_ratio`).
    textured: its colour is textured; None when it has no colour.
    """

    index: int
    timestamp: float
    depth_fraction: float
    has_depth: bool
    flat: bool
    textured: bool | None


@dataclass(frozen=True)
class Gap:
    """A time gap between two consecutive frames; times in seconds since the session's first frame."""

    before: int
    after: int
    time_before: float
    time_after: float

    @property
    def seconds(self) -> float:
        return self.time_after - self.time_before


@dataclass
class InputReport:
    """A session's input, judged for pose estimation.

    gaps: time gaps; median_step_s: the session's median time step (nan with fewer than 2 frames).
    without_depth: frames without usable depth; flat: frames whose view is flat; flat_untextured:
        those of them with no texture to fix the slide (or no colour, or colour not used).
    untrackable: why no frame of the session can be tracked, or None.
    """

    frames: int
    median_step_s: float
    gaps: list[Gap] = field(default_factory=list)
    without_depth: list[int] = field(default_factory=list)
    flat: list[int] = field(default_factory=list)
    flat_untextured: list[int] = field(default_factory=list)
    untrackable: str | None = None
    config: InputCheckConfig = field(default_factory=InputCheckConfig)

    def warnings(self, untracked_poses: str = "the odometry's guess, not measured") -> list[str]:
        """One line per finding; `untracked_poses` says what the caller gives the frames without depth."""
        config, lines = self.config, []
        shown = self.gaps[:MAX_GAPS_LISTED]
        for gap in shown:
            lines.append(f"time gap of {gap.seconds:.2f} s between frames {gap.before} (at {gap.time_before:.2f} s) and "
                         f"{gap.after} (at {gap.time_after:.2f} s; median step {1000 * self.median_step_s:.0f} ms): "
                         "the camera's motion across it is not observed, poses after it may jump")
        if len(self.gaps) > len(shown):
            rest = self.gaps[len(shown):]
            lines.append(f"{len(rest)} more time gaps (> {max(config.gap_s, config.gap_factor * self.median_step_s):.2f} s), "
                         f"after frames {describe_frames([gap.before for gap in rest])}")
        if self.without_depth:
            lines.append(f"frames {describe_frames(self.without_depth)} ({len(self.without_depth)} of {self.frames}) have "
                         f"no usable depth (< {config.min_depth_fraction:.0%} of pixels within {MIN_DEPTH_M:g}-"
                         f"{MAX_DEPTH_M:g} m): not registered; their poses are {untracked_poses}")
        if self.flat:
            textured = len(self.flat) - len(self.flat_untextured)
            line = (f"frames {describe_frames(self.flat)} ({len(self.flat)} of {self.frames}) see only flat surfaces "
                    "(walls, floor): depth alone leaves the camera's slide along them free")
            if self.flat_untextured:
                line += (f"; {describe_frames(self.flat_untextured)} have no texture to fix it either "
                         "(or no colour): their poses there are a guess")
            if textured:
                line += f"; {'the other ' if self.flat_untextured else ''}{textured} rest on their colour"
            lines.append(line)
        return lines

    def raise_if_untrackable(self, path: object) -> None:
        """A TrajectoryError naming `path` when no frame of the session can be tracked."""
        if self.untrackable is not None:
            raise TrajectoryError(f"{path}: {self.untrackable}")


MAX_GAPS_LISTED = 3  # gaps listed one per line; the rest in one line
MAX_RUNS_LISTED = 8  # runs of frame indices listed by `describe_frames`


def describe_frames(indices: Iterable[int]) -> str:
    """Frame indices as runs: "3, 40-59, 70" (the first MAX_RUNS_LISTED runs, then "and N more")."""
    runs: list[list[int]] = []
    for index in sorted(set(indices)):
        if runs and index == runs[-1][1] + 1:
            runs[-1][1] = index
        else:
            runs.append([index, index])
    text = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs[:MAX_RUNS_LISTED])
    if len(runs) > MAX_RUNS_LISTED:
        text += f" and {sum(b - a + 1 for a, b in runs[MAX_RUNS_LISTED:])} more"
    return text


def inspect_frame(frame: Frame, config: InputCheckConfig = InputCheckConfig()) -> FrameCheck:
    """What `frame` offers the odometry (see `FrameCheck`)."""
    depth_fraction = float(depth_in_range(frame.depth).mean()) if frame.depth.size else 0.0
    has_depth = depth_fraction >= config.min_depth_fraction and depth_fraction > 0.0
    flat, textured = False, None
    step = max(1, math.ceil(frame.depth.shape[1] / config.max_width))
    depth = frame.depth[::step, ::step].astype(np.float64)
    valid = depth_in_range(depth)
    if has_depth:
        K = frame.K.copy()
        K[:2] /= step
        information = plane_information(np.where(valid, depth, np.nan), K)
        flat = depth_degeneracy(information, float(np.median(depth[valid]))) < config.flat_ratio
    if frame.rgb is not None:
        textured = textured_fraction(_block_mean(frame.rgb, step, depth.shape), valid,
                                     config.gradient_threshold) >= config.textured_fraction
    return FrameCheck(frame.index, frame.timestamp, depth_fraction, has_depth, flat, textured)


def _block_mean(rgb: np.ndarray, step: int, shape: tuple[int, ...]) -> np.ndarray:
    """The colour image averaged over step x step blocks, (rows, cols, 3) for the subsampled depth's
    (rows, cols): the odometry's view of it (a sum of strided views; numpy's mean over reshaped
    axes is ten times slower)."""
    rows, cols = shape[0], shape[1]
    if rgb.shape[:2] == (rows * step, cols * step) and step & (step - 1) == 0:
        import cv2

        # Whole blocks and a power-of-two step: OpenCV's area resize gives the same float32 values
        # (whole numbers summed, scaled by a power of two: no rounding either way), for less work.
        return cv2.resize(rgb.astype(np.float32), (cols, rows), interpolation=cv2.INTER_AREA)
    total = np.zeros((rows, cols, 3), np.float32)
    for dy in range(step):
        for dx in range(step):
            block = rgb[dy::step, dx::step][:rows, :cols]
            total[:block.shape[0], :block.shape[1]] += block
    return total / (step * step)


def gap_limit_s(median_step_s: float, config: InputCheckConfig = InputCheckConfig()) -> float:
    """The longest step between two frames that is not a time gap (see `InputCheckConfig`)."""
    return max(config.gap_s, config.gap_factor * median_step_s)


class GapClock:
    """Frame by frame, whether a frame comes after a time gap: the odometry's motion prediction
    (one more step of the last motion) does not hold across one, since more time passed."""

    def __init__(self, config: InputCheckConfig = InputCheckConfig()) -> None:
        self.config = config
        self._last: float | None = None
        self._steps: list[float] = []

    def after_gap(self, timestamp: float) -> bool:
        last, self._last = self._last, timestamp
        if last is None:
            return False
        step = timestamp - last
        gap = bool(self._steps) and step > gap_limit_s(float(np.median(self._steps[-50:])), self.config)
        if not gap:
            self._steps.append(step)
        return gap


def check_frames(checks: Sequence[FrameCheck], config: InputCheckConfig = InputCheckConfig(),
                 uses_colour: bool = True) -> InputReport:
    """Judge a session from its frames' checks (in time order). `uses_colour`: whether the odometry
    uses colour (rgbd does, kiss-icp does not): a flat view is then fixed by texture alone."""
    times = np.array([check.timestamp for check in checks], dtype=np.float64)
    steps = np.diff(times)
    median = float(np.median(steps)) if len(steps) else float("nan")
    report = InputReport(frames=len(checks), median_step_s=median, config=config)
    if len(steps):
        limit = gap_limit_s(median, config)
        for i in np.flatnonzero(steps > limit):
            report.gaps.append(Gap(checks[i].index, checks[i + 1].index, float(times[i] - times[0]),
                                   float(times[i + 1] - times[0])))
    report.without_depth = [check.index for check in checks if not check.has_depth]
    report.flat = [check.index for check in checks if check.flat]
    report.flat_untextured = [check.index for check in checks if check.flat and not (uses_colour and check.textured)]
    with_depth = len(checks) - len(report.without_depth)
    if checks and with_depth == 0:
        report.untrackable = (f"no frame can be tracked: none of its {len(checks)} frames has usable depth "
                              f"(>= {config.min_depth_fraction:.0%} of pixels within {MIN_DEPTH_M:g}-{MAX_DEPTH_M:g} m)")
    elif len(checks) >= 2 and len(report.flat_untextured) == with_depth:
        # One frame needs no tracking (it is the origin); from two on, something must fix the motion.
        report.untrackable = (f"no frame can be tracked: each of its {with_depth} frames with depth sees only flat "
                              "surfaces (walls, floor) and nothing fixes the camera's slide along them ("
                              + ("no texture" if uses_colour else "colour not used") + ")")
    return report


class InputMonitor:
    """The input checks of one session, fed frame by frame as a pose estimate streams them."""

    def __init__(self, config: InputCheckConfig = InputCheckConfig()) -> None:
        self.config = config
        self.checks: list[FrameCheck] = []

    def observe(self, frame: Frame) -> FrameCheck:
        check = inspect_frame(frame, self.config)
        self.checks.append(check)
        return check

    def report(self, uses_colour: bool = True) -> InputReport:
        return check_frames(self.checks, self.config, uses_colour)


class _Recording(Protocol):
    path: object

    def frames(self) -> Iterable[Frame]: ...


def check_recording(reader: _Recording, uses_colour: bool = True,
                    config: InputCheckConfig = InputCheckConfig()) -> InputReport:
    """Check every frame of a recording (a `RecordingReader`) before its poses are estimated: stop
    with one line naming the file when no frame can be tracked, warn (`InputWarning`) about the rest."""
    monitor = InputMonitor(config)
    for frame in reader.frames():
        monitor.observe(frame)
    report = monitor.report(uses_colour)
    report.raise_if_untrackable(reader.path)
    for line in report.warnings():
        warnings.warn(f"{reader.path}: {line}", InputWarning, stacklevel=2)
    return report


def fill_untracked(timestamps: Sequence[float], poses: Sequence[np.ndarray | None]) -> list[np.ndarray]:
    """Poses for the frames that have none (None: not tracked), interpolated in time between the
    tracked frames on either side (translation linearly, rotation by slerp), held at the nearest
    tracked frame before the first or after the last one. Raises when no frame has a pose."""
    tracked = [i for i, pose in enumerate(poses) if pose is not None]
    if not tracked:
        raise TrajectoryError("no frame has a pose to fill the others from")
    filled: list[np.ndarray] = []
    position = 0  # index into `tracked` of the first tracked frame at or after i
    for i, pose in enumerate(poses):
        while position < len(tracked) and tracked[position] < i:
            position += 1
        if pose is not None:
            filled.append(np.asarray(pose, dtype=np.float64))
            continue
        before = tracked[position - 1] if position > 0 else None
        after = tracked[position] if position < len(tracked) else None
        if before is None or after is None:
            nearest = after if before is None else before
            filled.append(np.asarray(poses[nearest], dtype=np.float64).copy())
            continue
        span = timestamps[after] - timestamps[before]
        weight = (timestamps[i] - timestamps[before]) / span if span > 0 else (i - before) / (after - before)
        filled.append(interpolate_pose(poses[before], poses[after], float(np.clip(weight, 0.0, 1.0))))
    return filled
