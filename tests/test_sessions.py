"""Many sessions: the history linking on hand-made pair decisions, its score, the simulator's N
sessions, and a four-session run end to end (`ndfa ingest sim --sessions 4`, `ndfa detect` of the
four, `ndfa eval --history`)."""

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.events import DecisionEvent
from ndfa.core.geometry import make_pose
from ndfa.core.sessions import HistoryRow
from ndfa.eval.history import score_history
from ndfa.run.history import LinkConfig, PairOutcome, SessionObjects, compose_placements, link_history
from ndfa.sim.presets import make_config
from ndfa.sim.sessions import _fresh_ids, build_sessions
from ndfa.sim.world import Change, Placement, build_world, procedural_models

NAMES = ["session_0", "session_1", "session_2"]
SAMPLE = Path(__file__).parents[1] / "recordings" / "sample"


def decision(session, object_id, kind, partner=None, score=0.9):
    return DecisionEvent(frame_index=0, session=session, object_id=object_id, kind=kind, reason=kind,
                         center_world=np.zeros(3), center_source=np.zeros(3), partner_id=partner, score=score)


def objects(centers, code_of=None):
    """Session objects at x = centers[i] (metres), each with a code that names its shape."""
    code_of = code_of or {}
    return SessionObjects({i: np.array([x, 0.0, 0.8]) for i, x in enumerate(centers)},
                          {i: _code(code_of.get(i, i)) for i in range(len(centers))},
                          {i: 100 + i for i in range(len(centers))},
                          {i: ("bowl", "cup", "box")[i % 3] for i in range(len(centers))})


def _code(shape: int) -> np.ndarray:
    code = np.zeros(8)
    code[shape % 8] = 1.0
    return code


def rows_by_object(rows: list[HistoryRow]) -> dict[int, list[HistoryRow]]:
    out: dict[int, list[HistoryRow]] = {}
    for row in rows:
        out.setdefault(row.object, []).append(row)
    return out


def test_pair_decisions_link_the_objects_over_the_sessions():
    # session 0: mugs a (x 0), b (x 1), c (x 2). Pair 0-1: a unchanged, b moved to x 3, c removed,
    # d added at x 4. Pair 1-2: a unchanged, d unchanged; b's place not looked at.
    sessions = [objects([0, 1, 2]), objects([0, 3, 4], {1: 1, 2: 3}), objects([0, 4], {1: 3})]
    pairs = [[decision("target", 0, "unchanged", 0), decision("target", 1, "added"), decision("target", 2, "added"),
              decision("target", 1, "moved", 1), decision("source", 2, "removed", score=0.7)],
             [decision("target", 0, "unchanged", 0), decision("target", 1, "unchanged", 2)]]
    shift = make_pose(np.eye(3), np.array([0.0, 10.0, 0.0]))  # session 1's world is 10 m off the first's
    rows = link_history(NAMES, sessions, [np.eye(4), shift, shift], pairs)
    assert len(rows) == 4 * 3  # one row per object per session
    a, b, c, d = (rows_by_object(rows)[h] for h in range(4))
    assert [r.present for r in a] == [True, True, True] and [r.decision for r in a] == [None, "unchanged", "unchanged"]
    assert [r.present for r in b] == [True, True, None] and b[1].decision == "moved" and b[1].partner == 1
    np.testing.assert_allclose(b[1].center_first, [3.0, 10.0, 0.8])  # in the first session's world
    assert [r.present for r in c] == [True, False, False] and c[1].decision == "removed" and c[1].score == 0.7
    assert [r.present for r in d] == [False, True, True] and d[1].decision == "added"
    assert [r.session_object for r in d] == [None, 2, 1] and [r.instance_id for r in d] == [None, 102, 101]
    assert b[2].reason == "not looked at"
    # each present row has its session object's category, as_dict and the table carry it
    assert [r.category for r in d] == ["unknown", "box", "cup"] and d[1].as_dict()["category"] == "box"


def test_objects_no_decision_links_continue_what_stands_at_their_place():
    # Pair 0-1: object 0 (same shape, same place as source 0) undecided -> continues it; object 1 at
    # source 1's place but another shape -> new; object 2 "added" at source 2's place -> new (the
    # pair's word). Pair 1-2: source 0 not looked at ... and pair 2-... seen again below.
    sessions = [objects([0, 1, 2]), objects([0.01, 1, 2.0], {1: 5}), objects([0.02])]
    pairs = [[decision("target", 2, "added")], []]
    rows = rows_by_object(link_history(NAMES, sessions, [np.eye(4)] * 3, pairs))
    assert rows[0][1].present and rows[0][1].session_object == 0 and "by place and shape" in rows[0][1].reason
    assert [r.present for r in rows[1]] == [True, None, None]   # its place now holds another shape
    assert [r.present for r in rows[2]] == [True, None, None]   # "added" there: the pair says it is not it
    assert rows[0][2].present and rows[0][2].session_object == 0  # undecided again in pair 1-2: still it
    assert len(rows) == 5


def test_an_untested_object_at_a_removed_objects_place_is_that_object():
    # The pair decided source object 0 removed (observed, never matched), but a target object with
    # its shape stands at its place that was never tested (too few views): it is object 0.
    sessions = [objects([0, 1]), objects([0.01, 1]), objects([])]
    pairs = [[decision("target", 1, "unchanged", 1), decision("source", 0, "removed")], []]
    rows = rows_by_object(link_history(NAMES, sessions, [np.eye(4)] * 3, pairs))
    assert len(rows) == 2 and rows[0][1].present and rows[0][1].decision is None
    # an "added" one there is not: the pair tested it against object 0
    pairs[0].append(decision("target", 0, "added"))
    rows = rows_by_object(link_history(NAMES, sessions, [np.eye(4)] * 3, pairs))
    assert len(rows) == 3 and rows[0][1].present is False and rows[0][1].decision == "removed"


def test_an_added_object_continues_one_the_session_before_did_not_see():
    # Object 0 of session 0 is not looked at by session 1 (no decision about it), then session 2's pair
    # calls an object at its place "added" (session 1 had nothing there): it is object 0 again.
    sessions = [objects([0, 1]), objects([1], {0: 1}), objects([1, 0.01], {0: 1, 1: 0})]
    pairs = [[decision("target", 0, "unchanged", 1)], [decision("target", 0, "unchanged", 0),
                                                       decision("target", 1, "added")]]
    rows = rows_by_object(link_history(NAMES, sessions, [np.eye(4)] * 3, pairs))
    assert [r.present for r in rows[0]] == [True, None, True]
    assert "last seen in session_0" in rows[0][2].reason and rows[0][2].decision == "added"
    assert len(rows) == 2
    # farther than the link distance: a new object
    far = link_history(NAMES, sessions, [np.eye(4)] * 3, pairs, LinkConfig(place_m=0.005))
    assert len(rows_by_object(far)) == 3


def test_two_objects_naming_one_partner_do_not_merge():
    sessions = [objects([0]), objects([0, 0.02], {1: 0}), objects([])]
    pairs = [[decision("target", 0, "unchanged", 0), decision("target", 1, "unchanged", 0)], []]
    rows = rows_by_object(link_history(NAMES, sessions, [np.eye(4)] * 3, pairs))
    assert rows[0][1].session_object == 0
    assert rows[1][1].session_object == 1 and "continued by target object 0" in rows[1][1].reason


def test_a_move_between_different_shapes_is_a_removal_and_a_new_object():
    # the pair's "moved" pairs target object 1 with removed source object 1, but their codes differ
    sessions = [objects([0, 1]), objects([0, 3], {1: 4}), objects([])]
    pairs = [[decision("target", 0, "unchanged", 0), decision("target", 1, "moved", 1)], []]
    rows = rows_by_object(link_history(NAMES, sessions, [np.eye(4)] * 3, pairs))
    assert len(rows) == 3
    assert rows[1][1].present is False and rows[1][1].decision == "removed" and "shapes differ" in rows[1][1].reason
    assert rows[2][1].present and rows[2][1].decision == "moved" and "kept apart" in rows[2][1].reason
    # the detector's own threshold links them
    loose = link_history(NAMES, sessions, [np.eye(4)] * 3, pairs, LinkConfig(moved_similarity=-1.0))
    assert len(rows_by_object(loose)) == 2


def test_a_target_object_is_linked_by_its_final_decision():
    outcome = PairOutcome.of([decision("target", 0, "unchanged", 3), decision("target", 0, "added"),
                              decision("target", 0, "unchanged", 4),  # a change is never retracted
                              decision("target", 1, "added"), decision("target", 1, "moved", 2),
                              decision("target", 2, "unchanged", 5), decision("target", 2, "unchanged", 6)])
    assert outcome.target[0].kind == "added"
    assert outcome.target[1].kind == "moved" and outcome.target[1].partner_id == 2
    assert outcome.target[2].partner_id == 6


def test_a_session_without_registration_has_no_positions_after_it():
    t = make_pose(np.eye(3), np.array([1.0, 0, 0]))
    placements = compose_placements([t, None, t])
    assert np.allclose(placements[1], t) and placements[2] is None and placements[3] is None
    rows = link_history(NAMES, [objects([0]), objects([0]), objects([0])], [np.eye(4), t, None],
                        [[decision("target", 0, "unchanged", 0)], [decision("target", 0, "unchanged", 0)]])
    assert rows[2].present and rows[2].center_first is None


def truth_mug(instance_id, places):
    return {"instance_id": instance_id, "sessions": [None if x is None else {"pose_world_object": make_pose(
        np.eye(3), np.array([x, 0.0, 0.75])).tolist()} for x in places]}


def row(obj, session, present, x=None, instance=None):
    return HistoryRow(object=obj, session=session, session_name=NAMES[session], present=present,
                      center_first=None if x is None else np.array([x, 0.0, 0.8]), instance_id=instance)


def test_the_history_score_names_split_merged_and_wrong_rows():
    truth = {"objects": [truth_mug(1, [0, 0, 0]), truth_mug(2, [1, None, None]), truth_mug(3, [None, 2, 2])]}
    visible = {name: {1, 2, 3} for name in NAMES}
    right = [row(0, 0, True, 0, 1), row(0, 1, True, 0.01, 1), row(0, 2, True, 0, 1),
             row(1, 0, True, 1, 2), row(1, 1, False), row(1, 2, False),
             row(2, 0, False), row(2, 1, True, 2, 3), row(2, 2, True, 2, 3)]
    score = score_history(right, truth, visible)
    assert score.matches and score.rows == 9 and score.agree == 9 and max(score.position_errors_m) == pytest.approx(0.01)
    # mug 2's object takes mug 3 later (a wrong link) and mug 3 has no object of its own ...
    wrong = right[:3] + [row(1, 0, True, 1, 2), row(1, 1, True, 2, 3), row(1, 2, True, 2, 3)]
    score = score_history(wrong, truth, visible)
    assert not score.matches and score.merged == {1: [2, 3]} and score.matched == 1
    # ... mug 1 at the wrong place in session 2, and said absent where a session shows it
    off = right[:2] + [row(0, 2, True, 0.2, 1)] + right[3:8] + [row(2, 2, False)]
    score = score_history(off, truth, visible)
    assert {(d["mug"], d["session"]) for d in score.disagreements} == {(1, 2), (3, 2)}
    # a mug a session does not show is not scored there
    assert score_history(off, truth, visible | {"session_2": {2}}).disagreements == []


def test_two_sessions_are_the_two_session_world():
    config = make_config("sample", 1)
    models = procedural_models(config)
    world, worlds = build_world(config, models), build_sessions(config, models, 2)
    assert worlds.layouts == [world.source, world.target] and worlds.changes == [world.changes]


def test_more_sessions_change_each_pair_and_keep_ids_for_one_mug():
    config = make_config("sample", 1, changes={"added": 2, "removed": 2, "moved": 1, "switched": 0})
    worlds = build_sessions(config, procedural_models(config), 5)
    assert len(worlds) == 5 and worlds.layouts[:2] == [build_world(config, procedural_models(config)).source,
                                                       build_world(config, procedural_models(config)).target]
    for k, changes in enumerate(worlds.changes):
        assert len(changes) == 5, k
        added = {c.instance_id for c in changes if c.kind == "added"}
        assert added == set(worlds.layouts[k + 1]) - set(worlds.layouts[k])
        assert not added & set().union(*worlds.layouts[:k + 1])  # a new mug never takes an earlier mug's id
    models_of = {}
    for layout in worlds.layouts:
        for i, p in layout.items():
            assert models_of.setdefault(i, p.model_id) == p.model_id


def test_an_added_mug_never_takes_a_removed_mugs_id():
    place = Placement(5, "m", 1, (0.0, 0.0), 0.0)
    layout, changes = _fresh_ids({5: place}, [Change(5, "added")], before={}, used={1, 2, 5})
    assert list(layout) == [6] and layout[6].instance_id == 6 and changes == [Change(6, "added")]


# -- end to end ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def four(tmp_path_factory):
    """Four sessions of a small scene (all mug models distinct, no switches, every session around
    the room), detected through the CLI with every output."""
    out = tmp_path_factory.mktemp("sessions")
    result = CliRunner().invoke(app, ["ingest", "sim", "--preset", "sample", "--seed", "0", "--sessions", "4",
                                      "--models", "20", "--switched", "0", "--target-route", "perimeter",
                                      "--out", str(out / "rec")])
    assert result.exit_code == 0, result.output
    recordings = [str(out / "rec" / f"session_{k}.mcap") for k in range(4)]
    result = CliRunner().invoke(app, ["detect", *recordings, "--threads", "1", "--no-images",
                                      "--log", str(out / "run.rrd"), "--tables", str(out / "tables"),
                                      "--json", str(out / "run.json")])
    assert result.exit_code == 0, result.output
    return out, result.output


@pytest.mark.slow
def test_four_sessions_history_matches_the_ground_truth_object_for_object(four):
    out, output = four
    summary = json.loads((out / "run.json").read_text())
    score = summary["history_score"]
    assert score["matches"], score
    assert score["mugs"] == score["objects"] == score["matched"] == 15 and score["rows"] >= 50
    assert score["position_error_max_m"] < 0.02
    assert "matches the ground truth object for object" in output
    # the per-pair scores are reported: each pair's changes found (measured: TP 1, FP 0, FN 0 each)
    assert [p["pair"] for p in summary["pairs"]] == ["0-1", "1-2", "2-3"]
    for pair in summary["pairs"]:
        assert pair["registration"] is not None and pair["score"]["fn"] == 0 and pair["score"]["fp"] == 0


@pytest.mark.slow
def test_four_sessions_tables_and_rerun_file(four):
    from rerun.chunk import RrdReader

    out, _ = four
    history = pl.read_parquet(out / "tables" / "history.parquet")
    summary = json.loads((out / "run.json").read_text())
    assert history.height == len(summary["history"]) == 15 * 4
    assert history.group_by("object").len()["len"].to_list() == [4] * 15
    assert set(history["decision"].drop_nulls()) <= {"unchanged", "added", "removed", "moved"}
    decisions = pl.read_parquet(out / "tables" / "decisions.parquet")
    assert set(decisions["pair"]) == {"0-1", "1-2", "2-3"}
    assert set(pl.read_parquet(out / "tables" / "observations.parquet")["session"]) == {f"session_{k}" for k in range(4)}
    store = RrdReader(out / "run.rrd").store()
    entities = {str(chunk.entity_path) for chunk in store.stream().to_chunks()}
    assert {"/session_3/camera", "/history/objects", "/registration/log"} <= entities
    assert any(e.startswith("/session_2/objects/") for e in entities)
    timelines = {(str(chunk.entity_path), name) for chunk in store.stream().to_chunks()
                 for name in chunk.timeline_names}
    # one timeline through the visits: every session's frames on `session` (and on `step`)
    assert {("/session_0/camera", "session"), ("/session_3/camera", "session"), ("/session_3/camera", "step"),
            ("/history/objects", "session")} <= timelines


@pytest.mark.slow
def test_eval_history_writes_the_pair_and_history_scores(four, tmp_path):
    out, _ = four
    recordings = [str(out / "rec" / f"session_{k}.mcap") for k in range(3)]
    result = CliRunner().invoke(app, ["eval", "--history", *recordings, "--out", str(tmp_path), "--frame-step", "2"])
    assert result.exit_code == 0, result.output
    pairs = pl.read_parquet(tmp_path / "pairs.parquet")
    assert pairs["pair"].to_list() == ["0-1", "1-2"] and pairs["tp"].null_count() == 0
    scored = pl.read_parquet(tmp_path / "history_eval.parquet")
    assert scored.height > 0 and set(scored.columns) >= {"mug", "object", "session", "truth", "found", "why"}
    assert pl.read_parquet(tmp_path / "history.parquet")["session"].max() == 2


@pytest.mark.slow
def test_a_pair_of_a_many_session_run_is_the_two_session_detector():
    from ndfa.eval.runs import score_detection, score_sessions
    from ndfa.run.detect import run_detection
    from ndfa.run.sessions import run_sessions

    pair = score_detection(run_detection(SAMPLE / "source.mcap", SAMPLE / "target.mcap"))
    many = score_sessions(run_sessions([SAMPLE / "source.mcap", SAMPLE / "target.mcap"]))
    assert sorted((c.kind, c.object_id, c.instance_ids) for c in pair.changes) == \
        sorted((c.kind, c.object_id, c.instance_ids) for c in many.pairs[0].changes)
    assert (pair.score.tp, pair.score.fp, pair.score.fn) == (many.pairs[0].score.tp, many.pairs[0].score.fp,
                                                             many.pairs[0].score.fn)
    assert many.pairs[0].registration["inliers"] == pair.registration["inliers"]


def test_one_recording_is_refused_in_one_line():
    result = CliRunner().invoke(app, ["detect", str(SAMPLE / "source.mcap")])
    assert result.exit_code == 2


@pytest.fixture(scope="module")
def turned(tmp_path_factory):
    """Three sessions of a small scene with two mugs turned in place in the second, detected
    through the CLI (the session pass over three: session 1 is pair 0-1's target and pair 1-2's
    source)."""
    out = tmp_path_factory.mktemp("turned")
    result = CliRunner().invoke(app, ["ingest", "sim", "--preset", "sample", "--seed", "0", "--sessions", "3",
                                      "--rotated", "2", "--models", "20", "--switched", "0",
                                      "--target-route", "perimeter", "--out", str(out / "rec")])
    assert result.exit_code == 0, result.output
    recordings = [out / "rec" / f"session_{k}.mcap" for k in range(3)]
    result = CliRunner().invoke(app, ["detect", *map(str, recordings), "--threads", "1",
                                      "--json", str(out / "run.json")])
    assert result.exit_code == 0, result.output
    return recordings, json.loads((out / "run.json").read_text())


@pytest.mark.slow
def test_every_pair_of_a_many_session_run_reports_its_turned_mugs_rotated(turned):
    # The pair's source objects carry their views' handle headings as the two-session run's do
    # (before one `Measurement` builder, the many-session pass rebuilt the source's measurements
    # without them: no "rotated" in any pair, pair 0-1 TP 1 / FN 2 where `ndfa detect session_0
    # session_1` finds 3 of 3).
    from ndfa.io.recording import RecordingReader

    recordings, summary = turned
    turned_in = [{o["instance_id"] for o in RecordingReader(path).ground_truth["objects"] if o["change"] == "rotated"}
                 for path in recordings[1:]]
    assert turned_in[0], "the scene turns mugs between sessions 0 and 1"
    for pair, truth in zip(summary["pairs"], turned_in, strict=True):
        reported = {i for c in pair["changes"] if c["kind"] == "rotated" for i in c["instance_ids"]}
        assert reported == truth, (pair["pair"], pair["changes"])
        assert pair["score"]["fn"] == 0 and pair["score"]["fp"] == 0, pair
