"""Pose quality without ground truth (`ndfa.trajectory.quality`) and what its verdict does to the
reports (`ndfa.run.pose_verdict`)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from ndfa.core.events import CHANGE_SCORE, DecisionEvent
from ndfa.core.geometry import axis_angle_to_matrix, make_pose
from ndfa.run.pose_verdict import DOUBTFUL_SCORE_PULL, weigh_changes
from ndfa.run.world import SessionWorld, up_under_poses
from ndfa.trajectory.consistency import check_pair, make_sketch
from ndfa.trajectory.quality import (
    DOUBTFUL,
    GOOD,
    UNUSABLE,
    PoseEvidence,
    PoseQuality,
    gather_evidence,
    judge,
    up_disagreement,
)
from ndfa.trajectory.up import UpEstimate

ROOM = (np.array([-2.0, -1.5, 0.0]), np.array([2.0, 1.5, 2.5]))  # an empty box room, metres
K = np.array([[60.0, 0.0, 40.0], [0.0, 60.0, 30.0], [0.0, 0.0, 1.0]])  # 80 x 60 pixels


def _room_depth(pose: np.ndarray) -> np.ndarray:
    """Depth (z along the optical axis) of the box room seen from inside, by ray casting."""
    rows, cols = np.mgrid[0:60, 0:80]
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(cols.shape)], axis=-1)
    directions = rays @ pose[:3, :3].T
    origin = pose[:3, 3]
    with np.errstate(divide="ignore"):
        exits = np.where(directions > 0, (ROOM[1] - origin) / directions, (ROOM[0] - origin) / directions)
    return exits.min(axis=-1)  # distance along the ray in units of z: the depth


def _circling(frames: int = 48, turns: float = 2.0) -> list[np.ndarray]:
    """A camera at 1.2 m walking a 0.4 m circle and looking outwards, level: every place twice."""
    poses = []
    level = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical axis x, image down -z
    for k in range(frames):
        angle = 2 * np.pi * turns * k / frames
        rotation = axis_angle_to_matrix(np.array([0.0, 0.0, angle])) @ level
        poses.append(make_pose(rotation, np.array([0.4 * np.cos(angle), 0.4 * np.sin(angle), 1.2])))
    return poses


def _evidence(true_poses: list[np.ndarray], estimate: list[np.ndarray]) -> PoseEvidence:
    sketches = {k: make_sketch(_room_depth(pose).astype(np.float32), K) for k, pose in enumerate(true_poses)}
    return gather_evidence(estimate, sketches, object(), list(range(len(estimate))))


def test_a_sketch_keeps_the_nearest_valid_depth_around_each_pixel():
    depth = np.full((6, 8), 2.0, np.float32)
    depth[2, 3], depth[4, 6] = 1.0, np.nan
    depth[0:2, 0:2] = np.nan
    nearest = make_sketch(depth, np.eye(3)).nearest
    assert nearest[3, 4] == 1.0 and nearest[1, 2] == 1.0 and nearest[3, 5] == 2.0  # 1.0 reaches its 3x3 only
    assert nearest[4, 6] == 2.0  # an invalid pixel among valid ones: theirs
    assert nearest[0, 0] == np.inf  # no valid depth around


def test_a_pair_check_reads_only_the_points_ahead_of_the_camera_and_inside_its_image():
    # j sees a wall 2 m ahead; i's points: 3 on it (one of them 5 cm before it), one behind j's
    # camera, one at z = 0, one beyond the image's edge, one on the image's outermost column.
    sketch_j = make_sketch(np.full((60, 80), 2.0, np.float32), K)
    sketch_i = make_sketch(np.full((60, 80), 2.0, np.float32), K)
    points = np.array([[0.0, 0.0, 2.0], [0.1, 0.1, 2.0], [0.0, 0.1, 1.95], [0.0, 0.0, -1.0], [0.1, 0.0, 0.0],
                       [5.0, 0.0, 2.0], [(79.0 - K[0, 2]) / K[0, 0] * 2.0, 0.0, 2.0]], np.float32)
    check = check_pair(dataclasses.replace(sketch_i, points=points), sketch_j, np.eye(4), tau_m=0.04)
    assert check is not None and check.overlap == 3 and check.violating == 1
    assert check.conflict_m == pytest.approx(np.quantile([0.0, 0.0, 0.05], 0.95), abs=1e-6)
    behind = dataclasses.replace(sketch_i, points=points[3:5])
    assert check_pair(behind, sketch_j, np.eye(4), tau_m=0.04) is None


def test_right_poses_are_good_and_drifting_ones_unusable():
    truth = _circling()
    right = _evidence(truth, truth)
    assert right.revisit_pairs >= 10 and right.revisit_violation < 0.01
    verdict = judge(right)
    assert verdict.verdict == GOOD and verdict.error_cm < 1.0 and verdict.basis == "revisits and neighbours"
    # Odometry that turns 1 deg and slides 2 cm too far each frame: 47 deg and 94 cm at the end.
    step = make_pose(axis_angle_to_matrix(np.radians([0.0, 0.0, 1.0])), np.array([0.02, 0.0, 0.0]))
    drifting = [np.linalg.matrix_power(step, k) @ pose for k, pose in enumerate(truth)]
    wrong = judge(_evidence(truth, drifting))
    assert wrong.verdict == UNUSABLE and wrong.error_cm > 25.0
    assert wrong.evidence.revisit_violation > 0.05 and wrong.evidence.jumps == 0  # smooth drift: seen at the revisits
    assert "UNUSABLE" in wrong.describe() and wrong.to_dict()["verdict"] == UNUSABLE
    # A slight drift (0.05 deg and 1 mm a frame, ATE 1.4 cm) stays good, its figure a few cm at most.
    step = make_pose(axis_angle_to_matrix(np.radians([0.0, 0.0, 0.05])), np.array([0.001, 0.0, 0.0]))
    slight = judge(_evidence(truth, [np.linalg.matrix_power(step, k) @ pose for k, pose in enumerate(truth)]))
    assert slight.verdict == GOOD and verdict.error_cm < slight.error_cm < 5.0 < wrong.error_cm


def test_good_poses_whose_frames_disagree_on_up_are_doubtful():
    # A 30 Hz walk tracked frame by frame drifted 20-37 cm while its depths' conflicts read 1.3 cm
    # (the drifted frames never met again); its up's frames agreed 12 and 34 of 62 where every right
    # session of the validation sets agreed in 95-100 % of them (docs/pose_quality.md).
    truth = _circling()
    good = judge(_evidence(truth, truth))
    assert up_disagreement(good, 61, 61) is good and up_disagreement(good, 58, 61) is good
    doubted = up_disagreement(good, 34, 62)
    assert doubted.verdict == DOUBTFUL and doubted.error_cm == good.error_cm
    assert "only 34 of 62 frames' own horizontal planes agree on up" in doubted.describe()
    assert doubted.to_dict()["doubt"] == doubted.doubt and "doubt" not in good.to_dict()
    # It only ever lowers a good verdict: unusable poses stay unusable, and no frames say nothing.
    step = make_pose(axis_angle_to_matrix(np.radians([0.0, 0.0, 1.0])), np.array([0.02, 0.0, 0.0]))
    wrong = judge(_evidence(truth, [np.linalg.matrix_power(step, k) @ pose for k, pose in enumerate(truth)]))
    assert up_disagreement(wrong, 10, 62).verdict == UNUSABLE and up_disagreement(good, 0, 0) is good


def _with_screen(pose: np.ndarray) -> np.ndarray:
    """The box room's depth with a screen on the +x wall (0.8 x 0.6 m at eye height) whose depth is
    a reflection 0.6 m behind the glass along each camera's view: it moves with the viewpoint."""
    depth = _room_depth(pose)
    rows, cols = np.mgrid[0:60, 0:80]
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(cols.shape)], axis=-1)
    with np.errstate(invalid="ignore"):  # the rays along a wall have no depth (-inf, left out by the sketch)
        world = (rays * depth[..., None]) @ pose[:3, :3].T + pose[:3, 3]
    screen = (world[..., 0] > 1.99) & (np.abs(world[..., 1]) < 0.4) & (np.abs(world[..., 2] - 1.2) < 0.3)
    return np.where(screen, depth + 0.6, depth)


def test_one_surface_disagreeing_alone_is_not_a_pose_error():
    # Right poses; the screen is dark on the first pass (frames 0-11: its glass in depth) and
    # reflects from frame 12 on: where the two passes meet at it, the glass of one stands in space
    # the other saw empty, on a tenth of the view. The deepest 5 % of the pairs read that; the
    # depth a quarter of the overlap reaches does not.
    truth = _circling()
    sketches = {k: make_sketch((_with_screen(pose) if k >= 12 else _room_depth(pose)).astype(np.float32), K)
                for k, pose in enumerate(truth)}
    screen = gather_evidence(truth, sketches, object(), list(range(len(truth))))
    # A drift whose deepest 5 % read alike: it moves every surface, so the bulk of the overlap too.
    step = make_pose(axis_angle_to_matrix(np.radians([0.0, 0.0, 0.2])), np.array([0.005, 0.0, 0.0]))
    drift = _evidence(truth, [np.linalg.matrix_power(step, k) @ pose for k, pose in enumerate(truth)])
    assert screen.revisit_local_conflict_cm > 2.0 and drift.revisit_local_conflict_cm > 2.0
    assert screen.revisit_conflict_cm < 0.5 < 10.0 < drift.revisit_conflict_cm
    assert judge(screen).verdict == GOOD and judge(drift).verdict == DOUBTFUL
    # But surfaces decimetres deep in space seen empty, however few, are a doubled wall or worse.
    doubled = judge(dataclasses.replace(screen, revisit_local_conflict_cm=36.0))
    assert doubled.verdict == DOUBTFUL and doubled.error_cm < 10.0 and "doubled surface" in doubled.describe()


@pytest.mark.parametrize("towards", [0.3, -0.3])
def test_a_jump_between_two_frames_is_unusable(towards):
    # Frame 30 looks along +y: a jump towards the wall in view, or away from it (each shows one way).
    # (A slide along that wall is invisible in an empty box: nothing in view pins it.)
    truth = _circling()
    shifted = make_pose(np.eye(3), np.array([0.0, towards, 0.0]))
    jumped = judge(_evidence(truth, [pose if k < 30 else shifted @ pose for k, pose in enumerate(truth)]))
    assert jumped.verdict == UNUSABLE and jumped.evidence.jumps >= 1 and jumped.evidence.step_conflict_cm > 20.0


PILLARS = [(1.1 * np.cos(angle), 1.1 * np.sin(angle)) for angle in np.linspace(0.0, 2 * np.pi, 12, endpoint=False)]


def _pillared_depth(pose: np.ndarray) -> np.ndarray:
    """The box room's depth with twelve 12 cm square pillars, floor to ceiling, 1.1 m from its centre."""
    rows, cols = np.mgrid[0:60, 0:80]
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(cols.shape)], axis=-1)
    directions, origin = rays @ pose[:3, :3].T, pose[:3, 3]
    depth = _room_depth(pose)
    for x, y in PILLARS:
        with np.errstate(divide="ignore", invalid="ignore"):
            low = (np.array([x - 0.06, y - 0.06, 0.0]) - origin) / directions
            high = (np.array([x + 0.06, y + 0.06, 2.5]) - origin) / directions
        near = np.nanmax(np.minimum(low, high), axis=-1)
        hit = (near <= np.nanmin(np.maximum(low, high), axis=-1)) & (near > 0)
        depth = np.where(hit, np.minimum(depth, near), depth)
    return depth


def test_a_step_short_of_a_jump_counts_by_its_bulk_and_a_jump_by_its_deepest_surfaces():
    # One slip of a right session (random seed 2's raw textured source, cal32: 2.2 cm and 0.5 deg
    # at one step, ATE 1.0 cm): the step's deepest 5 % 3.2 cm, its bulk 0.0. The path absorbs it.
    right = _evidence(_circling(), _circling())
    slipped = judge(dataclasses.replace(right, step_conflict_cm=3.2, step_shared_conflict_cm=0.0, jumps=0))
    assert slipped.verdict == GOOD and slipped.error_cm < 1.0
    towards = judge(dataclasses.replace(right, step_conflict_cm=3.2, step_shared_conflict_cm=3.0, jumps=0))
    assert towards.error_cm == pytest.approx(3.0)  # the bulk moved: it counts
    unknown = judge(dataclasses.replace(right, step_conflict_cm=3.2, step_shared_conflict_cm=float("nan")))  # before cal32
    assert unknown.error_cm == pytest.approx(3.2)
    # A 5 cm slip sideways past the pillars: the walls (the bulk) hide it, the pillars' edges stand
    # 46 cm into space the next frame saw empty, beyond tau: a jump, counted at that depth.
    truth = _circling()
    sketches = {k: make_sketch(_pillared_depth(pose).astype(np.float32), K) for k, pose in enumerate(truth)}
    slide = make_pose(np.eye(3), np.array([0.05, 0.0, 0.0]))
    jumped = gather_evidence([pose if k < 30 else slide @ pose for k, pose in enumerate(truth)], sketches, object(),
                             list(range(len(truth))))
    assert jumped.step_shared_conflict_cm < 1.0 and jumped.jumps >= 1
    assert judge(jumped).verdict == UNUSABLE and judge(jumped).error_cm == jumped.step_conflict_cm
    assert judge(gather_evidence(truth, sketches, object(), list(range(len(truth))))).verdict == GOOD


def test_without_overlapping_frames_nothing_vouches_for_the_poses():
    truth = _circling(frames=2, turns=0.5)   # two frames looking in opposite directions
    quality = judge(_evidence(truth, truth))
    assert quality.verdict == DOUBTFUL and quality.basis == "none" and not np.isfinite(quality.error_cm)


def test_loops_the_optimised_graph_leaves_far_off_raise_the_estimated_error():
    # A right session's loops sit within millimetres of the optimised poses; one that the graph
    # leaves 85 cm off (the office's broken seed-3 target: odometry slid along a wall) is a contradiction.
    right = _evidence(_circling(), _circling())
    assert judge(dataclasses.replace(right, loops=3, loop_residual_cm=0.3)).verdict == GOOD
    contradicted = judge(dataclasses.replace(right, loops=1, loop_residual_cm=85.0))
    assert contradicted.verdict == UNUSABLE and contradicted.error_cm == 85.0
    assert "loop closures lie that far" in contradicted.describe()


def test_the_backward_estimates_disagreement_raises_the_estimated_error():
    right = _evidence(_circling(), _circling())
    assert judge(right).error_cm < 1.0
    agreeing = judge(dataclasses.replace(right, backward_disagreement_cm=1.0))
    assert agreeing.verdict == GOOD and agreeing.error_cm == pytest.approx(2.0)  # twice: they share some error
    drifted = judge(dataclasses.replace(right, backward_disagreement_cm=8.0))
    assert drifted.verdict == DOUBTFUL and drifted.error_cm == pytest.approx(16.0)


def test_a_run_of_frames_whose_motion_was_partly_guessed_is_doubtful_at_best():
    odometry = SimpleNamespace(unseen=[False, True, True, False] + [True] * 6 + [False] * 38)
    truth = _circling()
    sketches = {k: make_sketch(_room_depth(pose).astype(np.float32), K) for k, pose in enumerate(truth)}
    evidence = gather_evidence(truth, sketches, odometry, list(range(len(truth))))
    assert evidence.unseen_run == 6
    quality = judge(evidence)
    assert quality.verdict == DOUBTFUL and quality.error_cm < 10.0 and "guessed" in quality.describe()
    assert judge(dataclasses.replace(evidence, unseen_run=4)).verdict == GOOD  # a few frames: the motion model holds


def _change(kind: str, score: float, object_id: int = 1) -> DecisionEvent:
    return DecisionEvent(frame_index=3, session="target", object_id=object_id, kind=kind, reason="test",
                         center_world=np.zeros(3), center_source=np.zeros(3), score=score)


def _world(session: str, verdict: str | None) -> SessionWorld:
    world = SessionWorld(session, pose_source="estimated", up_source="z")
    if verdict is not None:
        evidence = judge(_evidence(_circling(), _circling())).evidence
        world.pose_quality = PoseQuality(evidence, 1.0, verdict, "revisits and neighbours")
    return world


@pytest.mark.parametrize("verdict", [GOOD, DOUBTFUL, UNUSABLE])
def test_the_worst_verdict_weighs_the_changes(verdict):
    changes = [_change("added", 0.9), _change("moved", 0.6, object_id=2)]
    weighed = weigh_changes(changes, {"source": _world("source", GOOD), "target": _world("target", verdict)})
    assert weighed.verdict == verdict
    if verdict == GOOD:
        assert weighed.confident == changes and not weighed.withheld and not weighed.notes
    elif verdict == DOUBTFUL:
        scores = [c.score for c in weighed.confident]
        assert scores == pytest.approx([CHANGE_SCORE + (1 - DOUBTFUL_SCORE_PULL) * (s - CHANGE_SCORE) for s in (0.9, 0.6)])
        assert all(CHANGE_SCORE <= s < original for s, original in zip(scores, (0.9, 0.6), strict=True))
        assert "doubtful" in weighed.notes[0] and not weighed.withheld
    else:
        assert weighed.confident == [] and weighed.withheld == changes
        assert "target" in weighed.reason and "2 change(s) withheld" in weighed.notes[0]


def test_given_poses_are_not_judged():
    changes = [_change("added", 0.9)]
    weighed = weigh_changes(changes, {"source": _world("source", None), "target": _world("target", None)})
    assert weighed.verdict == GOOD and weighed.confident == changes


def test_the_json_summary_carries_the_verdict_and_the_withheld_changes():
    from ndfa.run.pair import PairResult

    worlds = {"source": _world("source", GOOD), "target": _world("target", UNUSABLE)}
    pair = PairResult(0, "source", "target", detector=None, changes_decided=[_change("added", 0.9)])  # type: ignore[arg-type]
    assert [c.kind for c in pair.changes] == ["added"]   # before the verdict: as the detector decided
    pair.weigh(worlds)
    summary = pair.as_dict()
    assert summary["pose_verdict"] == UNUSABLE and summary["changes"] == [] and pair.reported == []
    assert [c["kind"] for c in summary["withheld_changes"]] == ["added"] and "unusable" in summary["withheld_changes"][0]["reason"]
    assert "withheld" in summary["notes"][0]
    world = worlds["target"].as_dict()
    assert world["pose_quality"]["verdict"] == UNUSABLE
    assert set(world["pose_quality"]["figures"]) >= {"revisit_conflict_cm", "revisit_violation", "jumps"}


def test_up_read_under_poses_that_are_not_good_is_never_high_confidence():
    truth = _circling()
    step = make_pose(axis_angle_to_matrix(np.radians([0.0, 0.0, 1.0])), np.array([0.02, 0.0, 0.0]))
    broken = judge(_evidence(truth, [np.linalg.matrix_power(step, k) @ pose for k, pose in enumerate(truth)]))
    good = judge(_evidence(truth, truth))
    up = UpEstimate(True, "planes", np.array([0.0, 0.0, 1.0]), "planes", 48, 48, 40, 0.8, 1.0, confidence="high")
    assert up_under_poses(up, good) is up and up_under_poses(up, None) is up
    doubted = up_under_poses(up, broken)
    assert doubted.confidence == "low" and "unusable" in doubted.warning
    assert np.array_equal(doubted.up_world, up.up_world)  # the estimate itself is kept, only its trust falls
