"""What a recording lacks and `ndfa detect` estimates before the pipeline sees it: poses and world up.

The core works on frames with camera poses in a z-up world (`ndfa.core.conventions`). Per session:

- **poses**: the recording's own; or, for one without any (a raw sensor recording, meta
  `"poses": "none"`), estimated over the whole session by RGB-D odometry with loop closure
  (`ndfa.trajectory.session`: rgbd odometry; depth-only KISS-ICP when it has no colour). The
  frames are checked on the way: time gaps, frames without depth (their poses interpolated between
  the tracked frames) and flat views become `notes`, which name the frames; a session none of whose
  frames can be tracked stops with one line.
- **up**: a synthetic recording says its world is z-up and is taken at its word (unless its poses
  were estimated: odometry's world starts at the first camera). Any other is
  checked: gravity is taken from the IMU when the importer recorded its still readings (a bag with
  an Imu topic: meta "imu"), checked by the support planes; otherwise it is estimated from the
  support planes with the cameras' axes as prior and fallback (`ndfa.trajectory.up`), on frames
  spread over the session. A "low" confidence up (the cameras' fallback, split or unstable planes)
  is used with a warning that says why. A world tilted by more
  than `LEVEL_ABOVE_DEG` is levelled (every pose rotated about the world origin), one within it is
  left exactly as it is. When no up can be found the run stops with the reason, unless the user
  says the world is z-up (`up="z"`).

`SessionWorld.describe()` (stderr of `ndfa detect`) and `as_dict()` (its JSON "world") carry the notes.

The odometry reads the frames the run uses (`positions`: every frame, or those of `--frame-step`
or `--rate`, `ndfa.run.rate`), and only those get poses; the up estimate and the scene cloud then
look at those frames only (`spread`). `keep_depth` keeps, on the way, the depth of the frames the
scene cloud is fused from (`ndfa.run.align.scene_cloud`), thinned as it thins them, so that the
scene alignment need not read them again (`SessionWorld.kept_depth`). Where the up is to be
estimated from the planes, the odometry finds the planar patches of the up's frames as it reads
them too (`frame_patches`: they need no pose), so the file is not read again for the up.
"""

from __future__ import annotations

import time
from bisect import bisect_left
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ndfa.core.errors import RecordingError
from ndfa.core.frame import Frame
from ndfa.io.recording import RecordingReader
from ndfa.trajectory.level import level_frame, level_poses
from ndfa.trajectory.metrics import absolute_trajectory_error, relative_pose_error
from ndfa.trajectory.quality import PoseQuality, judge, up_disagreement
from ndfa.trajectory.session import (
    UNTRACKED_POSES,
    choose_method,
    estimate_session_poses,
    frames_backwards,
    rgbd_config_for,
)
from ndfa.trajectory.up import UpEstimate, angle_deg, estimate_up, frame_patches, up_from_patches
from ndfa.trajectory.up_imu import imu_gravity, up_from_imu

UpMode = Literal["auto", "z", "estimate"]
PoseMode = Literal["auto", "given", "estimate", "truth"]
UP_MODES: tuple[str, ...] = ("auto", "z", "estimate")
POSE_MODES: tuple[str, ...] = ("auto", "given", "estimate", "truth")

# Below this tilt the estimate cannot tell the world from z-up (0.6 deg on a noisy synthetic scene,
# 1-2 deg on a Kinect sequence: docs/world_up.md), so the recording is used as it is.
LEVEL_ABOVE_DEG = 2.0
UP_FRAMES = 60  # frames the up estimate looks at, spread over the session
# The IMU's up and the planes' agree within this on a level floor: the planes err by 1-2 deg on a
# Kinect sequence (docs/world_up.md), a consumer IMU's accelerometer bias by about as much. A larger
# difference is reported (a sloped floor, a wrong IMU mounting in the bag's tf, wrong poses).
IMU_PLANES_AGREE_DEG = 5.0


def spread(length: int, count: int, among: Sequence[int] | None = None) -> list[int]:
    """About `count` positions spread over a session of `length` frames: every `length // count`-th
    (0, step, ...); with `among` (the positions a run uses, increasing), each moved to the nearest
    of them (the earlier on a tie), none twice. Where `among` holds every grid position (every
    frame, or a frame step that divides the grid's), the same positions."""
    grid = range(0, length, max(1, length // count))
    if among is None or not len(among):
        return list(grid)
    chosen: list[int] = []
    for position in grid:
        at = bisect_left(among, position)
        nearest = min(among[max(0, at - 1):at + 1], key=lambda p: (abs(p - position), p))
        if not chosen or chosen[-1] != nearest:
            chosen.append(nearest)
    return chosen


@dataclass(frozen=True)
class KeepDepth:
    """Which frames' depth the odometry keeps: `frames` spread over the session (`spread`: positions
    0, len // frames, ..., or the nearest used ones), every `pixel_stride`-th pixel along each axis."""

    frames: int
    pixel_stride: int

    def positions(self, length: int, among: Sequence[int] | None = None) -> list[int]:
        return spread(length, self.frames, among)


@dataclass(frozen=True)
class KeptFrame:
    """One frame's depth as `KeepDepth` thinned it, with what back-projecting it needs."""

    index: int                  # `Frame.index`
    K: np.ndarray               # (3, 3)
    pose: np.ndarray            # (4, 4) the recorded camera-to-world pose (what `SessionWorld.camera_pose` takes)
    depth: np.ndarray           # depth[::pixel_stride, ::pixel_stride], a copy


@dataclass
class SessionWorld:
    """How one session's frames are made ready for the core: which poses, which up."""

    session: str
    pose_source: str                        # "given" or the odometry method that estimated them
    up_source: str                          # "z (synthetic)", "z (user)", "estimated" (planes), "imu"
    up: UpEstimate | None = None            # the estimate, when one was made
    up_check: UpEstimate | None = None      # the planes' estimate that checked the IMU's ("imu" only)
    levelling: np.ndarray | None = None     # (3, 3) rotation applied to every pose, or None
    poses: dict[int, np.ndarray] | None = None  # estimated camera-to-world poses by frame index
    notes: list[str] = field(default_factory=list)  # warnings about the input: frames named, one line each
    # How far the estimated poses can be trusted, judged without ground truth (`ndfa.trajectory.quality`).
    pose_quality: PoseQuality | None = None
    # The estimated poses against the recording's true ones (a simulator's ground-truth channel), when
    # it has them: {"ate_rmse_m", "ate_max_m", "rpe_translation_m", "rpe_rotation_deg", "frames"}.
    pose_error: dict | None = None
    # Wall seconds of what was estimated: "odometry" (reading its frames included), "up".
    seconds: dict[str, float] = field(default_factory=dict)
    # The depth the odometry kept for the scene cloud (`prepare_session`'s `keep_depth`), and how; None: not kept.
    kept_depth: tuple[KeepDepth, list[KeptFrame]] | None = field(default=None, repr=False)
    # The positions of the frames whose poses were estimated, when not every frame's (a run that
    # uses fewer: `ndfa.run.rate`): `poses` holds theirs alone. None: every frame's, or none estimated.
    posed: Sequence[int] | None = None

    def apply(self, frame: Frame) -> Frame:
        """`frame` with the estimated pose (if any), levelled (if needed)."""
        if self.poses is not None:
            frame = replace(frame, pose_world_camera=self.poses[frame.index])
        return frame if self.levelling is None else level_frame(frame, self.levelling)

    def camera_pose(self, index: int, recorded: np.ndarray) -> np.ndarray:
        """The camera-to-world pose `apply` gives the frame `index` whose recorded pose is `recorded`."""
        pose = recorded if self.poses is None else self.poses[index]
        return pose if self.levelling is None else level_poses(pose, self.levelling)

    def describe(self) -> str:
        """One line: which poses and which up this session runs on, and how they were found; then one
        indented line per warning about the session's input (`notes`)."""
        error = "" if self.pose_error is None else (
            f" (against the true poses: ATE RMSE {100 * self.pose_error['ate_rmse_m']:.1f} cm, "
            f"max {100 * self.pose_error['ate_max_m']:.1f} cm, RPE {1000 * self.pose_error['rpe_translation_m']:.1f} mm "
            f"/ {self.pose_error['rpe_rotation_deg']:.2f} deg per frame)")
        quality = "" if self.pose_quality is None else f"; {self.pose_quality.describe()}"
        return f"{self.session}: poses {self.pose_source}{error}{quality}; up {self.describe_up()}" + "".join(
            f"\n  warning: {self.session}: {note}" for note in self.notes)

    def describe_up(self) -> str:
        """Which up this session runs on, and how it was found."""
        if self.up is None:
            return self.up_source
        tilt = self.up.tilt_deg
        action = f"levelled by {tilt:.1f} deg" if self.levelling is not None else \
            f"the recording's z (estimate within {tilt:.1f} deg of it)"
        confidence = f"confidence {self.up.confidence} (+-{self.up.uncertainty_deg:.1f} deg)"
        if self.up_source != "imu":
            if self.up.method == "cameras":
                return f"{action}; from the cameras' axes (the planes' fallback), {confidence}"
            return (f"{action}; estimated from horizontal planes, {confidence}, {self.up.frames_agreeing}/"
                    f"{self.up.frames_used} agreeing frames, spread {self.up.spread_deg:.1f} deg")
        check = self.up_check
        if check is None or check.up_world is None or check.method != "planes":
            checked = "not checked by the planes"
        else:
            checked = f"the planes' estimate {angle_deg(check.up_world, self.up.up_world):.1f} deg from it"
        return (f"{action}; from the IMU (still readings at {self.up.frames_used} frames, {self.up.frames_agreeing} "
                f"agreeing, spread {self.up.spread_deg:.1f} deg), {confidence}; {checked}")

    def as_dict(self) -> dict:
        return {"poses": self.pose_source, "up": self.up_source,
                "up_confidence": None if self.up is None else self.up.confidence,
                "up_uncertainty_deg": None if self.up is None else self.up.uncertainty_deg,
                "up_estimate": None if self.up is None else self.up.to_dict(),
                "up_check": None if self.up_check is None else self.up_check.to_dict(),
                "levelled": self.levelling is not None, "notes": list(self.notes),
                "pose_quality": None if self.pose_quality is None else self.pose_quality.to_dict(),
                "pose_error": self.pose_error}


def prepare_session(reader: RecordingReader, session: str, up: UpMode = "auto",
                    poses: PoseMode = "auto", check_poses_backward: bool = False,
                    keep_depth: KeepDepth | None = None, positions: Sequence[int] | None = None) -> SessionWorld:
    """Estimate what `reader`'s recording lacks (see the module docstring). check_poses_backward:
    estimated poses are estimated a second time over the frames last first, and the two estimates'
    disagreement joins their quality figure (`ndfa.trajectory.quality`; twice the odometry's time).
    keep_depth: where the odometry reads the frames, their depth is kept for the scene cloud.
    positions: the frames the run uses (`ndfa.run.rate.used_positions`; None: every frame): poses
    are estimated for these alone."""
    if up not in UP_MODES:
        raise ValueError(f"up must be one of {UP_MODES}, got {up!r}")
    if poses not in POSE_MODES:
        raise ValueError(f"poses must be one of {POSE_MODES}, got {poses!r}")
    world = SessionWorld(session, pose_source="given", up_source="")
    # The up's frames' planar patches in their cameras' frames, by frame index, where the odometry found them.
    patches: dict[int, tuple[np.ndarray, np.ndarray]] | None = None
    if poses == "truth":
        world.poses, world.pose_source = _true_poses(reader), "true (the ground-truth channel)"
    elif poses == "estimate" or (poses == "auto" and not reader.has_poses):
        started = time.perf_counter()
        kept: list[KeptFrame] = []
        if positions is not None and len(positions) < len(reader):
            world.posed = positions
        if up != "z":  # estimated poses: the up is estimated (below)
            patches = {}
        world.poses, world.pose_source, input_notes, truth, world.pose_quality = _estimate_poses(
            reader, world.posed, check_poses_backward, None if keep_depth is None else (keep_depth, kept),
            None if patches is None else (set(_up_positions(reader, world)), patches))
        if keep_depth is not None:
            world.kept_depth = (keep_depth, kept)
        world.seconds["odometry"] = time.perf_counter() - started
        world.notes.extend(input_notes)
        world.pose_error = _pose_error(world.poses, truth)
    elif not reader.has_poses:
        raise RecordingError(f"{reader.path}: has no camera poses and pose estimation is off (--poses given)")

    if up == "z":
        world.up_source = "z (as given: --up z)"
        return world
    # Odometry's world starts at its first camera (whose up is -y), whatever the recording's was.
    estimated = world.poses is not None and poses != "truth"
    if up == "auto" and _known_z_up(reader.meta) and not estimated:
        world.up_source = "z (a synthetic recording's world is z-up)"
        return world
    started = time.perf_counter()
    spread_out = _up_positions(reader, world)
    imu = _up_from_imu(reader, world, spread_out)
    prior_up = None if imu is None else imu.up_world
    if patches is not None and world.poses is not None and len(patches) == len(spread_out):
        # in the order read: the frames at `spread_out`, as `reader.frames` gives them
        planes = up_from_patches(((world.poses[index][:3, :3], *found) for index, found in patches.items()),
                                 prior_up=prior_up, started=started)
    else:
        planes = estimate_up((world.apply(f) for f in reader.frames(positions=spread_out)), prior_up=prior_up)
    if imu is not None:
        # The IMU measures gravity; the planes check it (a wrong mounting in the tf, wrong poses).
        world.up, world.up_source, world.up_check = imu, "imu", planes
        if planes.up_world is None or planes.method != "planes":
            world.notes.append(f"the planes could not check the IMU's up: {planes.reason}")
        elif (difference := angle_deg(imu.up_world, planes.up_world)) > IMU_PLANES_AGREE_DEG:
            world.notes.append(f"up from the IMU and from the planes differ by {difference:.1f} deg (more than "
                               f"{IMU_PLANES_AGREE_DEG:g}): a sloped floor, or the IMU's mounting (tf) or the poses "
                               "wrong? the IMU's is used")
    else:
        world.up, world.up_source = planes, "estimated"
    if estimated and world.pose_quality is not None and planes.method == "planes":
        world.pose_quality = up_disagreement(world.pose_quality, planes.frames_agreeing, planes.frames_used)
    world.up = up_under_poses(world.up, world.pose_quality)
    world.seconds["up"] = time.perf_counter() - started
    if world.up.ok and world.up.confidence == "low":
        world.notes.append(f"world up is doubtful: {world.up.warning}")
    if not world.up.ok:
        raise RecordingError(f"{reader.path}: no world up found ({world.up.reason}); "
                             "if its world is z-up, say so with --up z")
    if world.up.tilt_deg > LEVEL_ABOVE_DEG:
        world.levelling = world.up.levelling()
    return world


def up_under_poses(up: UpEstimate, pose_quality: PoseQuality | None) -> UpEstimate:
    """`up`, its confidence "low" when it was read under estimated poses that are not good: planes
    are seen through the poses, so under broken ones a floor seen twice is two planes and up can be
    confidently wrong (docs/world_up.md: an office session at 1.5 m ATE gave 39 deg off, "high")."""
    if not up.ok or pose_quality is None or pose_quality.good or up.confidence != "high":
        return up
    return replace(up, confidence="low", warning=f"read under {pose_quality.verdict} poses ({pose_quality.describe()})")


def _up_from_imu(reader: RecordingReader, world: SessionWorld, positions: Sequence[int]) -> UpEstimate | None:
    """Up from the still IMU readings the importer recorded (meta["imu"]) and the session's poses at
    those frames (those at `positions`), or None (no IMU, or no estimate: a note says why)."""
    imu = reader.meta.get("imu")
    if not isinstance(imu, dict):
        return None
    gravity = imu_gravity(reader.meta)
    if not gravity:
        world.notes.append(f"IMU {imu.get('topic', '')} not used for up: {imu.get('note', 'no readings')}; "
                           "up from the planes")
        return None
    estimate = up_from_imu(gravity, ((f.timestamp, world.apply(f).pose_world_camera)
                                     for f in reader.frames(positions=positions)))
    if not estimate.ok:
        world.notes.append(f"IMU {imu.get('topic', '')} not used for up: {estimate.reason}; up from the planes")
        return None
    return estimate


def _known_z_up(meta: dict) -> bool:
    """A recording of ndfa's simulator whose world was not tilted on purpose."""
    config = meta.get("config") if isinstance(meta.get("config"), dict) else {}
    return meta.get("source") == "sim" and not config.get("world_tilt_deg")


def _true_poses(reader: RecordingReader) -> dict[int, np.ndarray]:
    """The simulator's true camera poses: an oracle that separates segmentation from odometry."""
    poses: dict[int, np.ndarray] = {}
    for frame in reader.frames():
        if frame.pose_world_camera_true is None:
            raise RecordingError(f"{reader.path}: frame {frame.index} has no true pose (--poses truth needs "
                                 "a recording with a ground-truth channel)")
        poses[frame.index] = frame.pose_world_camera_true
    return poses


def _pose_error(estimate: dict[int, np.ndarray], truth: dict[int, np.ndarray]) -> dict | None:
    """ATE and per-frame RPE of `estimate` against `truth` when every frame has a true pose."""
    if len(estimate) < 3 or set(truth) != set(estimate):
        return None
    indices = sorted(estimate)
    ate = absolute_trajectory_error([estimate[i] for i in indices], [truth[i] for i in indices])
    rpe = relative_pose_error([estimate[i] for i in indices], [truth[i] for i in indices])
    return {"frames": len(indices), "ate_rmse_m": ate.rmse_m, "ate_max_m": ate.max_m,
            "rpe_translation_m": rpe.translation_rmse_m, "rpe_rotation_deg": rpe.rotation_rmse_deg}


def _up_positions(reader: RecordingReader, world: SessionWorld) -> list[int]:
    """The positions of the frames the up is estimated from: `UP_FRAMES` spread among those with poses."""
    return spread(len(reader), UP_FRAMES, world.posed)


def _estimate_poses(reader: RecordingReader, positions: Sequence[int] | None = None, backward: bool = False,
                    keep: tuple[KeepDepth, list[KeptFrame]] | None = None,
                    patches: tuple[set[int], dict[int, tuple[np.ndarray, np.ndarray]]] | None = None,
                    ) -> tuple[dict[int, np.ndarray], str, list[str], dict[int, np.ndarray], PoseQuality | None]:
    """The pose of every frame at `positions` (None: every frame) by odometry over the whole
    session (`ndfa.trajectory.session`) on those frames alone, how they were estimated, warnings
    about the input, the frames' true poses (those it has) and the poses' quality judged without
    them. keep: the depth of the frames it picks is added to its list. patches: the planar patches
    (`frame_patches`) of the frames at these positions are added to the dict, by frame index."""
    truth: dict[int, np.ndarray] = {}
    used = range(len(reader)) if positions is None else positions
    kept_at = set() if keep is None else set(keep[0].positions(len(reader), positions))
    count = 0

    def seen(frame: Frame) -> None:
        nonlocal count
        if frame.pose_world_camera_true is not None:
            truth[frame.index] = frame.pose_world_camera_true
        if keep is not None and used[count] in kept_at:
            stride = keep[0].pixel_stride
            keep[1].append(KeptFrame(frame.index, frame.K, frame.pose_world_camera,
                                     frame.depth[::stride, ::stride].copy()))
        if patches is not None and used[count] in patches[0]:
            patches[1][frame.index] = frame_patches(frame)
        count += 1

    backward_frames = frames_backwards(reader, positions=positions) if backward else None
    session = estimate_session_poses(reader.frames(positions=positions), choose_method(next(iter(reader.frames(stop=1)), None)),
                                     reader.path, rgbd_config=rgbd_config_for(reader.meta), on_frame=seen,
                                     backward_frames=backward_frames)
    notes = session.input_report.warnings(untracked_poses=UNTRACKED_POSES) if session.poses else []
    quality = None if session.evidence is None else judge(session.evidence)
    return (dict(zip(session.indices, session.poses, strict=True)), f"estimated ({session.describe_method()})", notes,
            truth, quality)
