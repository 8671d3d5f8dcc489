"""Scoring by position (`ndfa.eval.position_match`): runs without masks, matched in the true world."""

import numpy as np
import pytest

from ndfa.core.geometry import axis_angle_to_matrix, invert_pose, look_at, make_pose
from ndfa.eval.position_match import (
    MATCH_RADIUS_M,
    ReportedObject,
    align_worlds,
    match_object,
    score_by_position,
)


def placed(x, y, z=0.75):
    return {"table_id": 0, "pose_world_object": make_pose(np.eye(3), np.array([x, y, z])).tolist()}


def truth(visible=None, tilt=None):
    """Mug 1 unchanged, mug 2 moved, mug 3 removed, mug 4 added; one box of clutter (id 1001)."""
    gt = {
        "objects": [
            {"instance_id": 1, "source": placed(0.0, 0.0), "target": placed(0.0, 0.0), "change": "unchanged"},
            {"instance_id": 2, "source": placed(0.5, 0.0), "target": placed(1.0, 0.5), "change": "moved"},
            {"instance_id": 3, "source": placed(0.0, 0.5), "target": None, "change": "removed"},
            {"instance_id": 4, "source": None, "target": placed(-0.5, 0.0), "change": "added"},
        ],
        "clutter": [{"instance_id": 1001, "kind": "box", "table_id": 0, "pose_world_object": placed(0.3, 0.3)["pose_world_object"]}],
    }
    if visible is not None:
        gt["visible"] = visible
    if tilt is not None:
        gt["world_tilt"] = {"degrees": 10.0, "pose_world_level": tilt.tolist()}
    return gt


EVERYTHING = {"source": [1, 2, 3, 1001], "target": [1, 2, 4, 1001]}
IDENTITY = {"source": np.eye(4), "target": np.eye(4)}


def obj(session, object_id, x, y, z=0.8):
    return ReportedObject(session, object_id, np.array([x, y, z]))


def route(n=40):
    """Camera poses on a circle around a table, looking at it."""
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.array([look_at(np.array([2 * np.cos(a), 2 * np.sin(a), 1.4]), np.array([0.0, 0.0, 0.75])) for a in angles])


def rigid(rotvec, translation):
    return make_pose(axis_angle_to_matrix(np.array(rotvec, dtype=float)), np.array(translation, dtype=float))


@pytest.mark.parametrize("poses", [route(), np.array([look_at(np.array([x, 0.0, 1.4]), np.array([x, 1.0, 0.75]))
                                                       for x in np.linspace(0, 3, 20)])], ids=["circle", "straight"])
def test_alignment_maps_a_shifted_and_rotated_world_back(poses):
    pose_true_run = rigid([0.1, -0.2, 1.3], [0.4, -2.0, 0.3])
    run = invert_pose(pose_true_run) @ poses  # the run's world: its cameras, somewhere else
    found, rmse = align_worlds(run, poses)
    # On the straight route the positions are on a line: the orientations fix the rotation about it.
    assert np.allclose(found, pose_true_run, atol=1e-9) and rmse < 1e-9
    # A mug seen at its place in the run's world is matched to it.
    center_run = invert_pose(pose_true_run) @ np.array([0.5, 0.0, 0.8, 1.0])
    match = match_object(ReportedObject("source", 0, center_run[:3]), truth(), found)
    assert match.instance_id == 2 and match.distance_m < 1e-9
    # Without the alignment it is not.
    assert match_object(ReportedObject("source", 0, center_run[:3]), truth(), np.eye(4)).instance_id != 2


def test_alignment_of_noisy_poses_reports_what_is_left():
    poses = route()
    rng = np.random.default_rng(0)
    run = poses.copy()
    run[:, :3, 3] += rng.normal(0, 0.02, (len(run), 3))
    found, rmse = align_worlds(run, poses)
    assert np.allclose(found[:3, 3], 0, atol=0.02) and 0.02 < rmse < 0.05


def test_a_mug_within_the_radius_is_its_change_and_a_move_names_both_places():
    reports = [
        [obj("target", 0, 1.0 + 0.05, 0.5), obj("source", 7, 0.5, 0.03)],  # mug 2 moved, both places found
        [obj("source", 8, 0.0, 0.5)],                                        # mug 3 removed
        [obj("target", 1, -0.5, 0.04, z=1.5)],                                # mug 4 added: height does not matter
    ]
    result, matches = score_by_position(reports, truth(EVERYTHING), IDENTITY)
    assert (result.tp, result.fp, result.fn) == (3, 0, 0)
    assert [m.instance_id for m in matches] == [2, 2, 3, 4]
    assert result.as_dict()["scored_by"] == "position"


def test_clutter_and_nothing_are_false_positives():
    reports = [
        [obj("target", 0, 0.31, 0.29)],              # the box: clutter is never a change
        [obj("source", 3, 0.31, 0.3)],               # the same box from the other session: one FP
        [obj("target", 5, 2.0, 2.0)],                # where nothing stands
        [obj("target", 6, 0.0, MATCH_RADIUS_M + 0.01)],  # just beyond mug 1's reach
        [obj("target", 6, 0.0, MATCH_RADIUS_M + 0.01)],  # the same object again: one FP
        [obj("target", 9, 0.0, 0.0)],                # mug 1, unchanged
    ]
    result, _ = score_by_position(reports, truth(EVERYTHING), IDENTITY)
    assert result.clutter_ids == (1001,) and len(result.unmatched) == 2
    assert "nearest mug 1 at 0.08 m" in result.unmatched[1]
    assert (result.tp, result.fp, result.fn) == (0, 4, 3)  # box, two phantoms, mug 1
    assert set(result.false_positive_ids) >= {1, 1001}
    assert "FP on clutter: 1001" in result.describe()


def test_a_mug_a_session_did_not_see_is_unscored():
    # Mug 3 was removed where the source never looked: it cannot be missed, nor found.
    visible = {"source": [1, 2], "target": [1, 2, 4]}
    reports = [[obj("target", 0, 1.0, 0.5), obj("source", 1, 0.5, 0.0)], [obj("target", 1, -0.5, 0.0)]]
    result, _ = score_by_position(reports, truth(visible), IDENTITY)
    assert (result.tp, result.fp, result.fn) == (2, 0, 0) and result.unscored_ids == (3,)
    found_anyway, _ = score_by_position(reports + [[obj("source", 2, 0.0, 0.5)]], truth(visible), IDENTITY)
    assert (found_anyway.tp, found_anyway.fp) == (2, 0) and found_anyway.visibility_known
    # Without visibility in the ground truth every mug is scored, and the note says so.
    unknown, _ = score_by_position(reports, truth(), IDENTITY)
    assert unknown.fn == 1 and not unknown.visibility_known and "every mug is scored" in unknown.describe()


def test_a_tilted_truth_is_compared_horizontally_in_its_level_world():
    tilt = rigid([np.radians(10), 0, 0], [0, 0, 0])
    gt = truth(EVERYTHING, tilt)
    for o in gt["objects"]:  # the recorded poses are in the tilted world
        for s in ("source", "target"):
            if o[s]:
                o[s]["pose_world_object"] = (tilt @ np.array(o[s]["pose_world_object"])).tolist()
    # 30 cm above mug 1 (a centre's height is no evidence), expressed in the tilted world.
    above = tilt @ np.array([0.0, 0.0, 1.05, 1.0])
    assert match_object(ReportedObject("target", 0, above[:3]), gt, np.eye(4)).instance_id == 1


def test_a_report_is_matched_on_its_own_level_not_to_the_item_on_the_board_below():
    """Shelves: mug 1 on a board at 0.20 m, mug 2 on the board above (0.50 m), 2 cm aside of it. A
    report at mug 2's center (5 cm above its base) is mug 2, though mug 1 stands nearer horizontally;
    one at mug 1's is mug 1; one between the boards, 15 cm above mug 1's base, still mug 1's level.
    (With one item within reach, height decides nothing: the tests above.)"""
    gt = {"objects": [{"instance_id": 1, "source": placed(0.0, 0.0, 0.20), "target": placed(0.0, 0.0, 0.20), "change": "unchanged"},
                      {"instance_id": 2, "source": placed(0.02, 0.0, 0.50), "target": placed(0.02, 0.0, 0.50), "change": "unchanged"}]}
    assert match_object(obj("target", 0, 0.0, 0.0, 0.55), gt, np.eye(4)).instance_id == 2
    assert match_object(obj("target", 1, 0.02, 0.0, 0.25), gt, np.eye(4)).instance_id == 1
    assert match_object(obj("target", 2, 0.0, 0.0, 0.35), gt, np.eye(4)).instance_id == 1
    # and a bottle's center, 18 cm above its table, is the bottle's
    assert match_object(obj("target", 3, 0.0, 0.0, 0.38), gt, np.eye(4)).instance_id == 1
