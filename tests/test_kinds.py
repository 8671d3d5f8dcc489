"""The right kind: a "moved" report needs the same object at both ends (`EvidenceConfig.move_similarity`,
`ndfa.change.detector.moves`), and the scoring says per kind how many reports were right
(`ndfa.eval.scoring.KindReport`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ndfa.change.associate import Measurement
from ndfa.change.config import DetectorConfig
from ndfa.change.detector import ChangeDetector, reported_changes
from ndfa.change.register import RegistrationPrior
from ndfa.core.events import DecisionEvent
from ndfa.eval.scoring import KindReport, score


def _unit(i: int, n: int = 16) -> np.ndarray:
    code = np.zeros(n)
    code[i] = 1.0
    return code


def _run(codes_source: dict[int, np.ndarray], centers_source: dict[int, np.ndarray],
         codes_target: dict[int, np.ndarray], centers_target: dict[int, np.ndarray],
         first_codes_target: dict[int, np.ndarray] | None = None, target_frames: int = 10,
         config: DetectorConfig = DetectorConfig()) -> list:
    """Both sessions in one world (a shared-world prior the unchanged mugs confirm); changes reported.
    `first_codes_target`: the codes some target objects show in their first 3 frames instead."""
    detector = ChangeDetector(config)
    detector.add_registration_prior(RegistrationPrior("shared world", np.eye(4)))
    for f in range(10):
        detector.add_source([Measurement(f, i, codes_source[i], centers_source[i], 0.8) for i in codes_source])
    events = []
    for f in range(target_frames):
        codes = codes_target | (first_codes_target or {}) if f < 3 else codes_target
        events += detector.add_target([Measurement(f, i, codes[i], centers_target[i], 0.8) for i in codes_target])
    events += detector.finish()
    decisions = [e for e in events if isinstance(e, DecisionEvent)]
    return sorted((c.kind, c.session, c.instance_ids[0], c.partner_instance_ids[:1]) for c in reported_changes(decisions))


def test_a_removed_mug_and_a_different_mug_added_elsewhere_are_not_a_move():
    stay = {2: np.array([0.3, 0.1, 0.8]), 3: np.array([-0.2, 0.4, 0.8])}
    removed = np.array([0.0, 0.0, 0.8])
    codes = {1: _unit(0), 2: _unit(2), 3: _unit(3)}
    different = 0.5 * _unit(0) + np.sqrt(0.75) * _unit(1)  # cosine 0.5 with mug 1: above delta_s (0.35)
    far = np.array([0.9, 0.5, 0.8])
    reports = _run(codes, {1: removed} | stay, {2: codes[2], 3: codes[3], 4: different}, stay | {4: far})
    assert reports == [("added", "target", 4, ()), ("removed", "source", 1, ())]
    # The same mug, there: a move (its codes agree as one mug's do, cosine 0.98).
    same = 0.98 * _unit(0) + np.sqrt(1 - 0.98**2) * _unit(1)
    reports = _run(codes, {1: removed} | stay, {2: codes[2], 3: codes[3], 1: same}, stay | {1: far})
    assert reports == [("moved", "target", 1, (1,))]


def test_a_source_object_matched_only_by_first_views_a_later_test_overturned_can_be_the_start_of_a_move():
    # Mug 1 moved far; mug 5 took its place, its first three views (a side that looks like mug 1)
    # consistent with mug 1, its later ones not: the end of its test is "changed", so mug 1 was
    # matched by nothing and its move is found (the sample's switched mug 9, whose report once
    # depended on whether a few views too small to encode fell within reach: docs/detector.md).
    stay = {2: np.array([0.3, 0.1, 0.8]), 3: np.array([-0.2, 0.4, 0.8])}
    place_1, far = np.array([0.0, 0.0, 0.8]), np.array([0.9, 0.5, 0.8])
    codes = {1: _unit(0), 2: _unit(2), 3: _unit(3)}
    target = {2: codes[2], 3: codes[3], 1: codes[1], 5: _unit(6)}
    reports = _run(codes, {1: place_1} | stay, target, stay | {1: far, 5: place_1}, first_codes_target={5: codes[1]},
                   target_frames=20)
    assert reports == [("added", "target", 5, ()), ("moved", "target", 1, (1,))]


def test_moves_pair_the_most_similar_first():
    # Two similar mugs (cosine 0.9) both moved. Mug 4's new code leans towards mug 1's; mug 1's is
    # its own. Pairing in object order would give mug 1's old place to mug 4 (seen first).
    stay = {2: np.array([0.3, 0.1, 0.8]), 3: np.array([-0.2, 0.4, 0.8])}
    code_1, code_4 = _unit(0), 0.9 * _unit(0) + np.sqrt(0.19) * _unit(4)
    source = {1: code_1, 2: _unit(2), 3: _unit(3), 4: code_4}
    leaning = 1.2 * code_1 + code_4
    target = {2: source[2], 3: source[3], 4: leaning / np.linalg.norm(leaning),
              1: 0.999 * code_1 + np.sqrt(1 - 0.999**2) * _unit(5)}
    places = stay | {1: np.array([0.0, 0.0, 0.8]), 4: np.array([0.1, 0.5, 0.8])}
    reports = _run(source, places, target, stay | {4: np.array([0.8, 0.6, 0.8]), 1: np.array([-0.7, 0.3, 0.8])})
    assert reports == [("moved", "target", 1, (1,)), ("moved", "target", 4, (4,))]


def test_kinds_are_scored_per_kind():
    truth = {"objects": [{"instance_id": 1, "change": "removed"}, {"instance_id": 2, "change": "added"},
                         {"instance_id": 3, "change": "moved"}, {"instance_id": 4, "change": "switched"},
                         {"instance_id": 5, "change": "unchanged"}]}
    kinds = [KindReport("moved", 2, 1),       # a removal and a different mug's addition: wrong kind
             KindReport("moved", 3, 3),       # the same mug at both ends: right
             KindReport("added", 4, None),    # a switched mug appeared here: right
             KindReport("removed", 5, None)]  # nothing changed: wrong (and an FP)
    result = score([2, 1, 3, 4, 5], truth, kinds=kinds)
    assert (result.tp, result.fp, result.fn) == (4, 1, 0)
    assert result.kinds == {"moved": (2, 1), "added": (1, 1), "removed": (1, 0)}
    assert result.kind_precision("moved") == 0.5 and result.kind_precision("rotated") == 1.0
    assert result.as_dict()["kinds"]["moved"] == {"reports": 2, "right": 1, "precision": 0.5}
    # per true change: mugs named by a report of a right kind (mug 1, removed, only as another's move: not)
    assert result.kinds_found == {"removed": (1, 0), "added": (1, 0), "moved": (1, 1), "switched": (1, 1)}
    assert result.kind_recall("added") == 0.0 and result.kind_recall("rotated") == 1.0
    assert result.as_dict()["kinds_found"]["moved"] == {"mugs": 1, "found": 1, "recall": 1.0}
    assert not {"kinds", "kinds_found"} & score([2], truth).as_dict().keys()  # no kinds given: the summary as it was


def test_the_decisions_table_says_whether_each_change_is_of_the_right_kind(tmp_path):
    import polars as pl

    from ndfa.log.table_sink import TableSink

    truth = {1: "removed", 2: "added", 3: "moved"}  # mug 4: unchanged
    sink = TableSink(tmp_path, truth)
    here = np.zeros(3)
    for kind, session, ids, partner in (("added", "target", (2,), ()),     # first found changed; at the end ...
                                        ("moved", "target", (2,), (1,)),   # ... a removal and another mug's addition
                                        ("moved", "target", (3,), (3,)),   # one mug at both ends
                                        ("removed", "source", (1,), ()),
                                        ("added", "target", (4,), ()),     # nothing changed there
                                        ("unchanged", "target", (4,), ())):
        sink.log(DecisionEvent(frame_index=0, session=session, object_id=ids[0], kind=kind, reason="", center_world=here,
                               center_source=here, instance_ids=ids, partner_instance_ids=partner, score=0.7))
    sink.close()
    decisions = pl.read_parquet(tmp_path / "decisions.parquet")
    assert decisions["kind_right"].to_list() == [True, False, True, True, False, None]
    assert decisions["reported"].to_list() == [False, True, True, True, True, False]  # the "added" became a move
    per_kind = decisions.filter("reported").group_by("kind").agg(pl.len(), pl.col("kind_right").sum()).sort("kind")
    assert per_kind.rows() == [("added", 1, 0), ("moved", 2, 1), ("removed", 1, 1)]
    assert decisions["partner_instance_ids"].to_list()[1:3] == [[1], [3]]


def test_a_removed_mug_and_an_added_mug_of_one_model_are_a_move_to_any_observer(tmp_path):
    import polars as pl

    from ndfa.io.recording.ground_truth import REAL_MODEL, identical_moves
    from ndfa.log.table_sink import TableSink

    # Mugs 1 and 2 are one model (as the random preset draws a model for several places), 3 another,
    # 5 and 6 the recording's own objects (`ndfa plant`), which are no one's twins.
    truth = {"objects": [{"instance_id": 1, "model_id": "mug-7", "change": "removed"},
                         {"instance_id": 2, "model_id": "mug-7", "change": "added"},
                         {"instance_id": 3, "model_id": "mug-8", "change": "added"},
                         {"instance_id": 4, "model_id": "mug-7", "change": "unchanged"},
                         {"instance_id": 5, "model_id": REAL_MODEL, "change": "removed"},
                         {"instance_id": 6, "model_id": REAL_MODEL, "change": "added"}]}
    assert identical_moves(truth) == {(1, 2)}
    # A mug of the model that moved (or switched) left its place as a removed one does.
    moved = {"objects": truth["objects"] + [{"instance_id": 7, "model_id": "mug-8", "change": "moved"}]}
    assert identical_moves(moved) == {(1, 2), (7, 3)}
    kinds = [KindReport("moved", 2, 1),   # mug 1's twin where mug 1 was not: a move as far as any view says
             KindReport("moved", 3, 1),   # another model: not a move
             KindReport("moved", 6, 5)]   # two real objects: not a move
    result = score([2, 3, 6], truth, kinds=kinds)
    assert result.kinds == {"moved": (3, 1)}
    assert result.kinds_found == {"removed": (2, 1), "added": (3, 1)}  # mugs 1 and 2 named rightly, by one move

    sink = TableSink(tmp_path, {1: "removed", 2: "added", 3: "added"}, identical_moves=identical_moves(truth))
    here = np.zeros(3)
    for ids, partner in (((2,), (1,)), ((3,), (1,))):
        sink.log(DecisionEvent(frame_index=0, session="target", object_id=ids[0], kind="moved", reason="",
                               center_world=here, center_source=here, instance_ids=ids, partner_instance_ids=partner,
                               score=0.7))
    sink.close()
    assert pl.read_parquet(tmp_path / "decisions.parquet")["kind_right"].to_list() == [True, False]


def _code(degrees: float) -> np.ndarray:
    """A unit code in the plane of `_unit(0)` and `_unit(1)`, this many degrees from `_unit(0)`."""
    return np.cos(np.radians(degrees)) * _unit(0) + np.sin(np.radians(degrees)) * _unit(1)


def test_two_similar_objects_that_swapped_places_are_both_moved():
    # A bowl (1) and a mug-like bowl (4) a hand apart swap places. Their codes agree to 0.79, above
    # delta_s (0.35), so each is consistent with what stood in its new place; but each is nearer its
    # own source object (0.996) than its place's (0.84), and that is the swap.
    stay = {2: np.array([0.3, 0.1, 0.8]), 3: np.array([-0.2, 0.4, 0.8])}
    bowl, mug = _code(0.0), _code(37.8)
    assert 0.7 < float(bowl @ mug) < 0.8
    here, there = np.array([0.0, 0.0, 0.8]), np.array([0.0, 0.2, 0.8])
    source = {1: bowl, 2: _unit(2), 3: _unit(3), 4: mug}
    target = {1: _code(5.0), 2: _unit(2), 3: _unit(3), 4: _code(32.8)}
    reports = _run(source, stay | {1: here, 4: there}, target, stay | {1: there, 4: here})
    assert reports == [("moved", "target", 1, (1,)), ("moved", "target", 4, (4,))]
    # Unchanged, the same codes are each nearest their own: nothing to report.
    assert _run(source, stay | {1: here, 4: there}, target, stay | {1: here, 4: there}) == []
    # Off: each is consistent with what stands in its place, and the swap goes unseen.
    off = DetectorConfig(evidence=replace(DetectorConfig().evidence, swap_margin=None))
    assert _run(source, stay | {1: here, 4: there}, target, stay | {1: there, 4: here}, config=off) == []
