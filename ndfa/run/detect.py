"""`ndfa detect SOURCE TARGET`: the session pass (`ndfa.run.sessions`) over two recordings, and its
result as the two-session commands report it.

The pass opens and checks the recordings, streams their frames (source first, then target), hands
every event to every sink, and keeps what the detector reported. Before the target pass it may
hand the detector a scene-level hypothesis of T_rel (`ndfa.run.align`: the sessions' shared world,
or the alignment of their scene clouds), which the object pairs verify; the result says which
registration was used and with how many inliers. The result is not scored here: with ground truth
in the target recording, `ndfa.eval.runs.score_detection` scores it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ndfa.core.events import SESSIONS, DecisionEvent
from ndfa.core.progress import LabelledProgress
from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
from ndfa.run.align import SceneAlignment
from ndfa.run.pair import PairResult
from ndfa.run.sessions import SessionsResult, session_pass
from ndfa.run.stream import RunOptions, SessionCounts, Sink, change_summary, staged
from ndfa.run.world import SessionWorld


@dataclass
class DetectionResult:
    """A pass over two sessions, named "source" and "target", as `ndfa detect SOURCE TARGET` reports it."""

    run: SessionsResult
    score: object | None = None  # `Score` (masks) or `PositionScore` (segmented): `ndfa.eval.runs.score_detection`

    @property
    def pair(self) -> PairResult:
        return self.run.pairs[0]

    @property
    def changes(self) -> list[DecisionEvent]:
        """Reported changes: added / moved / rotated (target), removed (source)."""
        return self.pair.changes

    @property
    def frames(self) -> dict[str, int]:
        return self.run.frames

    @property
    def seconds(self) -> dict[str, float]:
        """Wall time per session pass."""
        return self.run.seconds

    @property
    def objects(self) -> dict[str, int]:
        return self.run.objects

    @property
    def stage_ms(self) -> dict[str, float]:
        """Mean ms per target frame, per stage."""
        return {stage: total / max(self.frames["target"], 1) for stage, total in self.run.stage_totals["target"].items()}

    @property
    def notes(self) -> list[str]:
        return self.run.notes

    @property
    def worlds(self) -> dict[str, SessionWorld]:
        """The poses and up each session ran on."""
        return self.run.worlds

    @property
    def registration(self) -> dict | None:
        """The accepted T_rel: method, inliers, frame (None: none found)."""
        return self.pair.registration

    @property
    def alignment(self) -> SceneAlignment | None:
        """The scene-level hypothesis offered to the detector, if any."""
        return self.pair.alignment

    @property
    def object_centers(self) -> dict[str, np.ndarray]:
        """Session -> (n, 3) its objects' centers, in its own world."""
        return {name: np.array([o.center_world for o in m.objects.values()]).reshape(-1, 3)
                for name, m in zip(SESSIONS, self.run.maps)}

    @property
    def object_measurements(self) -> dict[str, np.ndarray]:
        """Session -> (n,) the measurements each of its objects took."""
        return {name: np.array([o.n_measurements for o in m.objects.values()], dtype=int)
                for name, m in zip(SESSIONS, self.run.maps)}

    @property
    def target_fps(self) -> float:
        return self.frames["target"] / self.seconds["target"] if self.seconds.get("target") else float("nan")

    def summary(self) -> dict:
        """The `--json` summary."""
        out = {}
        if self.score is not None:
            out |= self.score.as_dict()  # type: ignore[attr-defined]
        out |= {
            "frames": self.frames["source"] + self.frames["target"],
            "frames_source": self.frames["source"], "frames_target": self.frames["target"],
            "objects_source": self.objects["source"], "objects_target": self.objects["target"],
            "fps": self.target_fps,
            "stage_ms": self.stage_ms,
            "changes": [change_summary(c) for c in self.changes],
            "notes": self.notes,
            "world": {session: world.as_dict() for session, world in self.worlds.items()},
            "registration": self.registration,
            "scene_alignment": None if self.alignment is None else self.alignment.as_dict(),
            "pose_verdict": self.pair.as_dict()["pose_verdict"],
            "withheld_changes": self.pair.as_dict()["withheld_changes"],
        }
        return out

    def describe_registration(self) -> str:
        """One line: which registration the target was tested with."""
        if self.registration is None:
            return "registration: none found"
        r = self.registration
        residual = "" if r["residual_m"] is None else f", residual {r['residual_m'] * 100:.1f} cm"
        evidence = f" ({r['evidence']})" if r.get("evidence") else ""
        return (f"registration: {r['method']}{evidence}, {r['inliers']} inlier object pairs of {r['pairs']}{residual}, "
                f"from target frame {r['frame']}")


def run_detection(
    source: Path,
    target: Path,
    config: PipelineConfig = PipelineConfig(),
    sinks: list[Sink] = (),  # type: ignore[assignment]
    options: RunOptions = RunOptions(),
    on_frame: LabelledProgress | None = None,  # (session, frames done, frames in session)
    pipeline: ChangeDetectionPipeline | None = None,
    on_world: Callable[[SessionWorld], None] | None = None,
    on_alignment: Callable[[SceneAlignment], None] | None = None,
    full_reconstruction: bool | None = None,
    overlap: bool = True,
) -> DetectionResult:
    """Source pass, target pass, finish (`ndfa.run.sessions.session_pass`, which says what the
    arguments do). Sinks are closed at the end, also when interrupted."""
    run = session_pass([source, target], SESSIONS, config, sinks, options, on_frame, pipeline, on_world,
                       None if on_alignment is None else (lambda _, alignment: on_alignment(alignment)),
                       full_reconstruction, overlap, session_events=False)
    return DetectionResult(run)


__all__ = ["DetectionResult", "RunOptions", "SessionCounts", "Sink", "change_summary", "run_detection", "staged"]
