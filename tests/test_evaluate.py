"""Object-level scoring (paper Sec. V-B), with mugs that a session never saw left unscored."""

from ndfa.eval.scoring import score

TRUTH = {"objects": [
    {"instance_id": 1, "change": "unchanged"},
    {"instance_id": 2, "change": "added"},
    {"instance_id": 3, "change": "removed"},
    {"instance_id": 4, "change": "switched"},
    {"instance_id": 5, "change": "unchanged"},   # seen only in the target
    {"instance_id": 6, "change": "removed"},     # never seen in the source
]}


def test_every_mug_is_scored_without_visibility():
    s = score([2, 2, 5], TRUTH)
    assert (s.tp, s.fp, s.fn) == (1, 1, 3)  # two reports of mug 2 count once
    assert s.false_positive_ids == (5,) and s.false_negative_ids == (3, 4, 6) and s.unscored_ids == ()


def test_mugs_a_session_could_not_show_are_unscored():
    visible = {"source": {1, 3, 4}, "target": {1, 2, 4, 5}}
    s = score([2, 5, 4], TRUTH, visible)
    assert (s.tp, s.fp, s.fn) == (2, 0, 1)
    assert s.false_negative_ids == (3,) and s.unscored_ids == (5, 6)
    assert s.precision == 1.0 and s.recall == 2 / 3
