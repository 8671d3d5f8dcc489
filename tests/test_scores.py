"""Decision scores (docs/scores.md) on hand-made detector inputs, and the precision/recall sweep
built on them (`ndfa.eval.pr_curve`)."""

import numpy as np
import polars as pl
import pytest

from ndfa.change.associate import Measurement, SessionObject, cosine_similarity
from ndfa.change.config import DetectorConfig, EvidenceConfig, RegistrationConfig
from ndfa.change.detector import ChangeDetector, reported_changes
from ndfa.change.graph import local_graph
from ndfa.change.verdict import Verdict, decision_score, graph_verdict, removal_score, shape_verdict
from ndfa.core.events import CHANGE_SCORE, DecisionEvent
from ndfa.eval.pr_curve import average_precision, pr_curves, score_sweep
from ndfa.run.replay import reported_at


def _code(seed: int, dim: int = 16) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=dim)


def _objects(centers: dict[int, list[float]], codes: dict[int, np.ndarray]) -> dict[int, SessionObject]:
    return {i: SessionObject(i, codes[i], np.array(c, dtype=float), 0.5, 0, 0) for i, c in centers.items()}


def _verdict(target_centers: dict[int, list[float]], target_codes=None) -> Verdict:
    """Target object 0 against a source neighbourhood of three mugs (0 at the origin, 1 and 2
    beside it), target world = source world, the default decision config."""
    codes = {0: _code(10), 1: _code(11), 2: _code(12)}
    source = _objects({0: [0, 0, 0.8], 1: [0.3, 0, 0.8], 2: [0, 0.4, 0.8]}, codes)
    target = _objects(target_centers, target_codes or codes)
    similarity = {s: float(cosine_similarity(target[0].shape_code, source[s].shape_code)) for s in source}
    graph = local_graph(0, sorted(target_centers), target)
    verdict = shape_verdict([0, 1, 2], similarity, 0.7)
    if verdict is None:
        verdict = graph_verdict(graph, target[0].center_world, [0, 1, 2], similarity, source, np.eye(3), 0.7,
                                DetectorConfig(evidence=EvidenceConfig(in_place_m=0.0)))
    return verdict


def test_unchanged_scores_below_the_bar_and_rise_as_the_best_edge_error_nears_delta_e():
    scores = []
    for offset in (0.0, 0.01, 0.025):  # neighbour 1 stayed, this far from where it was (delta_e = 3 cm)
        verdict = _verdict({0: [0, 0, 0.8], 1: [0.3, offset, 0.8], 2: [0.7, 0.7, 0.8]})
        assert verdict.kind == "unchanged"
        assert verdict.shortfall == pytest.approx(max(offset / 0.03, 0.0), abs=1e-9)  # codes identical: shape part 0
        scores.append(decision_score(verdict))
    assert scores[0] == pytest.approx(0.0, abs=1e-9) and scores[0] < scores[1] < scores[2] < CHANGE_SCORE


def test_changed_scores_above_the_bar_and_rise_with_the_edge_error_and_the_shape_gap():
    near = _verdict({0: [0.01, 0, 0.8], 1: [0.31, 0.04, 0.8], 2: [0.7, 0.7, 0.8]})  # 4 cm off: just changed
    far = _verdict({0: [0.3, 0, 0.8], 1: [0, 0, 0.8], 2: [0.7, 0.7, 0.8]})      # 0 and 1 switched
    assert near.kind == far.kind == "changed"
    assert near.shortfall == pytest.approx(0.04 / 0.03)
    assert CHANGE_SCORE < decision_score(near) < decision_score(far) <= 1.0
    # no shape match around it: the best similarity's gap to delta_s decides, 1 with nothing around
    unlike = shape_verdict([0, 1], {0: 0.4, 1: 0.1}, 0.7)
    very_unlike = shape_verdict([0, 1], {0: -0.5, 1: 0.1}, 0.7)
    assert unlike.shortfall == pytest.approx(0.6 / 0.3)
    assert CHANGE_SCORE < decision_score(unlike) < decision_score(very_unlike) < 1.0
    assert decision_score(shape_verdict([], {}, 0.7)) == 1.0
    # at the bar exactly the decision's own side wins: a change never scores below 0.5
    assert decision_score(shape_verdict([0], {0: 0.7}, 0.7)) == CHANGE_SCORE
    assert decision_score(Verdict("unchanged", "x", 0, shortfall=1.0)) < CHANGE_SCORE


def test_removals_score_by_how_many_target_objects_looked_at_them():
    assert removal_score(1) == CHANGE_SCORE
    assert CHANGE_SCORE < removal_score(2) < removal_score(5) < 1.0


def _scene() -> dict[int, np.ndarray]:
    """Three tables of four mugs (instance id -> center)."""
    mugs = {}
    for t, center in enumerate([np.array([0.0, 0.0]), np.array([3.0, 0.0]), np.array([0.0, 3.0])]):
        for k, offset in enumerate([(-0.2, -0.15), (0.2, -0.1), (-0.15, 0.2), (0.25, 0.2)]):
            mugs[4 * t + k + 1] = np.r_[center + offset, 0.8]
    return mugs


@pytest.fixture(scope="module")
def detection() -> list[DecisionEvent]:
    """Every decision of a detector run: mug 2 removed, 20 added, 5 and 6 switched."""
    rng = np.random.default_rng(4)
    source = _scene()
    target = dict(source)
    target.pop(2)
    target[20] = np.r_[3.0, -0.3, 0.8]
    target[5], target[6] = source[6], source[5]
    codes = {i: _code(100 + i) for i in range(1, 30)}
    detector = ChangeDetector(DetectorConfig(registration=RegistrationConfig(pairs=4)))

    def frames(layout, frame0):
        for table in range(3):
            for view in range(3):
                yield [Measurement(frame0 + 3 * table + view, i, codes[i] + rng.normal(scale=0.02, size=16),
                                   center + rng.normal(scale=0.004, size=3), 0.8)
                       for i, center in layout.items() if (1 if center[0] > 1.5 else 2 if center[1] > 1.5 else 0) == table]

    for frame in frames(source, 0):
        detector.add_source(frame)
    events = [e for frame in frames(target, 10) for e in detector.add_target(frame)] + detector.finish()
    return [e for e in events if isinstance(e, DecisionEvent)]


def test_every_decision_of_a_run_is_scored_on_its_side_of_the_bar(detection):
    assert detection and all(np.isfinite(d.score) and 0 <= d.score <= 1 for d in detection)
    assert all((d.score >= CHANGE_SCORE) == (d.kind != "unchanged") for d in detection)
    kinds = {d.kind for d in reported_changes(detection)}
    assert {"moved", "removed"} <= kinds
    moved = [d for d in detection if d.kind == "moved"]
    added = {d.object_id: d for d in detection if d.kind == "added"}
    assert all(m.score == added[m.object_id].score for m in moved)  # a move scores as its target object's change


def test_thresholding_the_scores_at_the_bar_reproduces_the_reports(detection):
    reported = sorted({i for d in reported_changes(detection) for i in d.reported_instances})
    assert reported_at(detection, CHANGE_SCORE) == reported == [2, 5, 6, 20]
    everything = reported_at(detection, 0.0)
    assert set(reported) < set(everything)                       # low enough, unchanged objects flip
    assert reported_at(detection, 1.01) == []
    thresholds = sorted({d.score for d in detection})
    sets = [set(reported_at(detection, t)) for t in thresholds]
    assert all(a >= b for a, b in zip(sets, sets[1:]))          # a higher threshold reports a subset


def _truth(changed: set[int], everything: range) -> dict:
    return {"objects": [{"instance_id": i, "change": "added" if i in changed else "unchanged"} for i in everything]}


def test_a_score_sweep_is_monotone_and_its_average_precision_is_the_step_sum():
    truth = _truth({1, 2, 3}, range(1, 7))
    scores = {1: 0.9, 2: 0.8, 4: 0.7, 3: 0.6, 5: 0.2, 6: 0.1}
    curve = score_sweep("x", scores, 0.65, truth, None).sort("threshold", descending=True)
    assert curve["threshold"].to_list() == [0.9, 0.8, 0.7, 0.65, 0.6, 0.2, 0.1]
    assert curve.filter(pl.col("default"))["threshold"].to_list() == [0.65]
    assert (curve["tp"] + curve["fn"]).unique().to_list() == [3]
    for column in ("tp", "fp"):
        assert curve[column].diff().drop_nulls().min() >= 0  # reports only grow as the threshold falls
    assert curve["recall"].to_list() == pytest.approx([1 / 3, 2 / 3, 2 / 3, 2 / 3, 1, 1, 1])
    # AP: 1/3 at precision 1, 1/3 at 1, 1/3 at 3/4
    assert average_precision(curve) == pytest.approx(1 / 3 + 1 / 3 + 0.75 / 3)
    perfect = score_sweep("x", {1: 0.9, 2: 0.8, 3: 0.7, 4: 0.1}, 0.5, truth, None)
    assert average_precision(perfect) == pytest.approx(1.0)


def test_pr_curves_hold_every_method_with_its_default_point(detection):
    truth = _truth({2, 5, 6, 20}, range(1, 21))
    curves = pr_curves(detection, {"NN": ({2: 1.0, 5: 0.5, 7: 0.4, 6: 0.1}, 0.3)}, truth, None)
    assert set(curves.table["method"]) == {"ndfa", "NN"} and set(curves.average_precision) == {"ndfa", "NN"}
    ndfa = curves.table.filter((pl.col("method") == "ndfa") & pl.col("default")).row(0, named=True)
    assert (ndfa["tp"], ndfa["fp"], ndfa["fn"]) == (4, 0, 0)
    nn = curves.table.filter((pl.col("method") == "NN") & pl.col("default")).row(0, named=True)
    assert (nn["tp"], nn["fp"], nn["fn"], nn["threshold"]) == (2, 1, 2, 0.3)
    assert 0 < curves.average_precision["NN"] < curves.average_precision["ndfa"] == pytest.approx(1.0)
