"""The score of a run (`ndfa.run`) against its recordings' ground truth: each pair's reported
changes, and over many sessions every object's history.

A replay of an observations table (`ndfa.run.replay`) is scored by the labels the table holds.

A pair is scored by its target recording's ground truth: by the masks' instance ids when both
sessions have masks (`ndfa.eval.scoring.score`), by position when a session was segmented (a
segment's label is no instance id: `ndfa.eval.position_score`). The notes a score makes go to the
pair's notes, after the run's own.
"""

from __future__ import annotations

from ndfa.core.events import CHANGE_SCORE
from ndfa.eval.history import score_history
from ndfa.eval.position_score import score_segmented_run
from ndfa.eval.scoring import Score, kind_reports, rotated_reports, score
from ndfa.eval.shown import places_shown
from ndfa.run.detect import DetectionResult
from ndfa.run.replay import ReplayResult, reported_at
from ndfa.run.sessions import SessionsResult


def score_pair(run: SessionsResult, index: int) -> object | None:
    """The score of pair `index` (sessions index -> index + 1), or None when its target recording has
    no ground truth of the objects (or, segmented, no true poses: a note says so); sets
    `pair.score`."""
    pair = run.pairs[index]
    source, target = run.readers[index], run.readers[index + 1]
    truth = target.ground_truth
    if truth is None or "objects" not in truth:
        return None
    reported = pair.reported
    if source.has_instances and target.has_instances:
        visible = {"source": run.visible[pair.source], "target": run.visible[pair.target]}
        detector = pair.detector
        shown = places_shown({"source": source, "target": target}, truth, detector.config.evidence,
                             detector.views["source"].rule)
        pair.score = score([i for c in reported for i in c.reported_instances], truth, visible,
                           rotated_reports(reported), kind_reports(reported), shown)
    else:
        pair.score = score_segmented_run(reported, pair.detector, {"source": source, "target": target},
                                         {"source": run.worlds[pair.source], "target": run.worlds[pair.target]},
                                         pair.notes)
    return pair.score


def score_detection(result: DetectionResult) -> DetectionResult:
    """A two-session run scored (`result.score`), when the target recording has ground truth."""
    result.score = score_pair(result.run, 0)
    return result


def score_sessions(result: SessionsResult) -> SessionsResult:
    """Each pair scored, and the history against the ground truth of the sessions (made by `ndfa
    ingest sim --sessions N`) when every session has masks (`result.history_score`)."""
    for index in range(len(result.pairs)):
        score_pair(result, index)
    truth = result.readers[-1].ground_truth
    if truth is not None and isinstance(truth.get("sessions"), dict) and all(r.has_instances for r in result.readers):
        result.history_score = score_history(result.history, truth["sessions"],
                                             {name: result.visible[name] for name in result.names})
    return result


def score_replay(result: ReplayResult, threshold: float = CHANGE_SCORE) -> Score | None:
    """The replay's score over the instances its table labels (None: the table has no labels). At
    `CHANGE_SCORE` the detector's own reports (the "rotated" among them counted as such); at another
    threshold, every decision scoring at least that reported (`ndfa.run.replay.reported_at`)."""
    if result.truth is None:
        return None
    if threshold == CHANGE_SCORE:
        reported = [i for c in result.changes for i in c.reported_instances]
        return score(reported, result.truth, result.visible, rotated_reports(result.changes),
                     kind_reports(result.changes))
    return score(reported_at(result.decisions, threshold), result.truth, result.visible)
