"""What the baselines share: decisions, the streaming protocol, true poses, mask checks and the
free-space test of a source object's location in a target frame.

No I/O: the baselines take `Frame`s, whoever reads them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ndfa.core.conventions import MIN_DEPTH_M
from ndfa.core.errors import NdfaError
from ndfa.core.geometry import invert_pose, project
from ndfa.io.recording import Frame


class BaselineError(NdfaError):
    """A baseline cannot run on its input (no instance masks, no ground truth, bad parameters)."""


@dataclass(frozen=True)
class BaselineDecision:
    """One object a baseline calls changed, when (the target frame that decided it; the last
    target frame for decisions taken at the end) and why.

    session: the session the object was seen in: "target" for an object tested on its target
        views, "source" for a source object tested against the target (removed / absent).
    kind: "added" (no source object with its id), "changed" (its target views disagree with the
        source), "removed" (NN: its place was seen empty and it never appeared) or "absent"
        (TSDF: its surface lies in the target's free space or inside another object).
    """

    session: str
    frame_index: int
    instance_id: int
    kind: str
    reason: str


class Baseline(Protocol):
    """A change detector fed one session after the other, like ndfa's pipeline.

    After a run, `candidate_scores()` gives every object it judged (by instance id) the baseline's
    own continuous score, on the scale of its threshold: the object is reported exactly when its
    score is at least the threshold (`threshold`, the configured one), so other thresholds give
    its precision/recall curve (`ndfa.eval.pr_curve`).
    """

    name: str

    @property
    def threshold(self) -> float: ...
    def candidate_scores(self) -> dict[int, float]: ...

    def add_source(self, frame: Frame) -> None: ...
    def end_source(self) -> None: ...
    def add_target(self, frame: Frame) -> list[BaselineDecision]: ...
    def finish(self) -> list[BaselineDecision]: ...


def run_baseline(baseline: Baseline, source_frames: Iterable[Frame], target_frames: Iterable[Frame]
                 ) -> list[BaselineDecision]:
    """Stream the source, then the target; every decision, in the order taken."""
    for frame in source_frames:
        baseline.add_source(frame)
    baseline.end_source()
    decisions = []
    for frame in target_frames:
        decisions += baseline.add_target(frame)
    return decisions + baseline.finish()


def true_pose(frame: Frame) -> np.ndarray:
    """The frame's true camera-to-world pose: the baselines need aligned sessions (the paper fed
    them the simulator's poses)."""
    return frame.pose_world_camera if frame.pose_world_camera_true is None else frame.pose_world_camera_true


def require_masks(frame: Frame, session: str) -> np.ndarray:
    """The frame's instance mask, or a BaselineError: the baselines take their associations from it."""
    if frame.instances is None:
        raise BaselineError(f"{session} frame {frame.index} has no instance mask: the baselines need "
                            "ground-truth associations (instance masks with one id per object in both sessions)")
    return frame.instances


def free_fraction(points_world: np.ndarray, frame: Frame, margin_m: float, max_depth_m: float) -> float:
    """Share of `points_world` (N, 3) that the frame saw through: they project into the image, in
    front of the camera and within `max_depth_m`, onto a valid depth more than `margin_m` beyond
    them. An object still in place hides its own points (measured depth at or before them); an
    object gone lets the camera see the table or wall behind. 0 when no point projects into view.
    """
    if len(points_world) == 0:
        return 0.0
    world_camera = invert_pose(true_pose(frame))
    camera = points_world @ world_camera[:3, :3].T + world_camera[:3, 3]
    z = camera[:, 2]
    height, width = frame.depth.shape
    cols, rows = np.round(project(frame.K, camera)).T
    inside = (z > MIN_DEPTH_M) & (z < max_depth_m) & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    if not inside.any():
        return 0.0
    measured = frame.depth[rows[inside].astype(int), cols[inside].astype(int)]
    seen_through = (measured > 0) & (measured > z[inside] + margin_m)
    return float(seen_through.sum()) / len(points_world)
