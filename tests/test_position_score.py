"""A segmented run scored by position (`ndfa.eval.position_score`): each reported object mapped to the
true world by the cameras of the frames that saw it, so that drifting poses put it at its item."""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ndfa.change.associate import Measurement
from ndfa.change.config import DetectorConfig, EvidenceConfig
from ndfa.change.detector import ChangeDetector
from ndfa.core.events import DecisionEvent
from ndfa.core.frame import Frame
from ndfa.core.geometry import make_pose, transform_points
from ndfa.eval.position_match import ReportedObject, align_worlds, score_by_position
from ndfa.eval.position_score import score_segmented_run
from ndfa.run.world import SessionWorld
from tests.test_position_match import route, truth

FRAMES = 40
# The fake recordings' 8 x 8 frames show no place well enough (`ndfa.eval.shown`): these tests are
# about where a report lands, so the sight rule (and with it the scoring's scope) is off
WITHOUT_SIGHT = DetectorConfig(evidence=EvidenceConfig(sight_radius_m=0.0))


def removal_truth() -> dict:
    """`truth()` with one change: mug 3 removed (mug 1 stays, and the box)."""
    gt = truth()
    gt["objects"] = [o for o in gt["objects"] if o["instance_id"] in (1, 3)]
    return gt
K = np.array([[50.0, 0, 4], [0, 50.0, 4], [0, 0, 1]])


def drift(k: int) -> np.ndarray:
    """The odometry's error at frame k: 6 mm more per frame (24 cm at the end; after a session-wide
    fit 5.8 cm RMSE over the cameras, 10 cm at the mug seen last)."""
    return make_pose(np.eye(3), np.array([0.006 * k, 0.0, 0.0]))


def removed(object_id: int, center: np.ndarray) -> DecisionEvent:
    return DecisionEvent(frame_index=FRAMES - 1, session="source", object_id=object_id, kind="removed",
                         reason="observed but never matched", center_world=center, center_source=center)


@dataclass
class Recording:
    """What the scorer reads of a recording: its frames' true poses and its ground truth."""

    poses: np.ndarray
    ground_truth: dict
    path: Path = Path("fake.mcap")
    has_poses: bool = True
    read: list[int] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.poses)

    def frames(self, step: int = 1):
        for k in range(0, len(self), step):
            self.read.append(k)
            yield Frame(k, float(k), None, np.zeros((8, 8), np.float32), K, self.poses[k])


def test_each_reported_object_is_mapped_by_the_cameras_that_saw_it():
    true_poses = route(FRAMES)
    run_poses = {k: drift(k) @ true_poses[k] for k in range(FRAMES)}  # what odometry made of them
    worlds = {s: SessionWorld(s, "odometry", "z (synthetic)", poses=run_poses) for s in ("source", "target")}
    recordings = {s: Recording(true_poses, removal_truth()) for s in ("source", "target")}
    # Removed mug 3 (true (0, 0.5)), seen in the last ten source frames, where the drift is largest:
    # each view's center lies where that frame's drifted pose puts it.
    detector = ChangeDetector(WITHOUT_SIGHT)
    mug = np.array([0.0, 0.5, 0.8])
    for k in range(30, FRAMES):
        detector.source.update(Measurement(k, 1, np.ones(8), transform_points(drift(k), mug[None])[0], 0.6))
    (object_id,) = detector.source.objects
    assert detector.source.objects[object_id].frames == list(range(30, FRAMES))
    center = detector.source.objects[object_id].center_world
    removal = removed(object_id, center)

    notes: list[str] = []
    result = score_segmented_run([removal], detector, recordings, worlds, notes)
    assert result is not None and (result.tp, result.fp, result.fn) == (1, 0, 0)
    assert result.local_alignment and "each object by the cameras that saw it" in notes[-1]
    assert result.as_dict()["alignment"] == "per object"
    assert recordings["source"].read == list(range(FRAMES))  # every frame, for the frames that saw it

    # One fit of the whole session leaves the drift of these frames in the position: the mug is missed
    # and a phantom reported where nothing stands (the scoring of before, which the score carries).
    assert result.session_wide == (0, 1, 1) and result.as_dict()["session_wide"] == {"tp": 0, "fp": 1, "fn": 1}
    assert "aligned per session instead: TP 0 / FP 1 / FN 1" in notes[-1]
    session_wide, rmse = align_worlds([run_poses[k] for k in range(FRAMES)], true_poses)
    before, _ = score_by_position([[ReportedObject("source", object_id, center)]], removal_truth(),
                                  {"source": session_wide, "target": session_wide})
    assert (before.tp, before.fp, before.fn) == (0, 1, 1) and rmse > 0.05


def test_exact_poses_score_as_one_session_wide_fit_does():
    """Poses off by one rigid motion (a levelled or shifted world): every camera's fit is that motion."""
    true_poses = route(FRAMES)
    motion = make_pose(np.eye(3), np.array([1.0, -2.0, 0.0]))
    worlds = {s: SessionWorld(s, "given", "z (synthetic)", poses={k: motion @ true_poses[k] for k in range(FRAMES)})
              for s in ("source", "target")}
    detector = ChangeDetector(WITHOUT_SIGHT)
    for k in range(5):
        detector.source.update(Measurement(k, 1, np.ones(8), transform_points(motion, np.array([[0.0, 0.5, 0.8]]))[0], 0.6))
        # a phantom where nothing stands, 30 cm from every item
        detector.source.update(Measurement(k, 2, -np.ones(8), transform_points(motion, np.array([[-0.3, 0.5, 0.8]]))[0], 0.6))
    changes = [removed(i, o.center_world) for i, o in detector.source.objects.items()]
    result = score_segmented_run(changes, detector, {s: Recording(true_poses, removal_truth()) for s in worlds}, worlds, [])
    assert result is not None and (result.tp, result.fp, result.fn) == (1, 1, 0) == result.session_wide
    assert result.alignment_rmse_m["source"] < 1e-9
