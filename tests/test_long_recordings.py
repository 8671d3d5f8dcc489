"""What a pass keeps per object and per pair stays bounded in the recording's length (issue 32):
an object's history of measurements is thinned to an even sample, a pair keeps each object's
latest "unchanged" decision and every change. The peak-RSS figures are in docs/speed.md."""

from __future__ import annotations

import numpy as np

from ndfa.change.associate import MAX_HISTORY, Measurement, SessionMap
from ndfa.change.rotation import fused_heading
from ndfa.core.events import DecisionEvent
from ndfa.run.history import PairOutcome
from ndfa.run.pair import PairResult


def _measurements(count: int, seed: int = 0) -> list[Measurement]:
    """One mug seen `count` times: noisy centers drifting along x, noisy headings about 40 deg."""
    rng = np.random.default_rng(seed)
    code = rng.normal(size=32)
    return [Measurement(k, 1, code + rng.normal(scale=0.01, size=32),
                        np.array([0.5 + 0.02 * k / count, 0.2, 0.8]) + rng.normal(scale=0.004, size=3), 0.6,
                        heading_rad=np.radians(40.0) + rng.normal(scale=0.2), heading_strength=0.5)
            for k in range(count)]


def test_an_object_seen_thousands_of_times_keeps_an_even_sample_of_its_history():
    measurements = _measurements(5000)
    session_map = SessionMap()
    for m in measurements:
        session_map.update(m)
    assert len(session_map) == 1
    obj = session_map.objects[0]
    assert obj.n_measurements == 5000
    assert MAX_HISTORY // 2 <= len(obj.centers) == len(obj.headings) <= MAX_HISTORY
    # An even sample: its median center and fused heading are those of all the measurements.
    every_center = np.median([m.center_world for m in measurements], axis=0)
    assert np.linalg.norm(obj.center_world - every_center) < 1e-3
    views = np.array([(m.heading_rad, m.heading_strength) for m in measurements])
    every_heading = np.arctan2(np.sin(views[:, 0]).mean(), np.cos(views[:, 0]).mean())
    # (313 views of a 0.2 rad noise: the mean is known to ~0.7 deg)
    assert abs(fused_heading(obj, 0.1).angle_rad - every_heading) < np.radians(2.5)
    # Spread over the whole pass, not only its end: the drift along x is in the sample's span.
    xs = np.array(obj.centers)[:, 0]
    assert xs.min() < 0.5 + 0.002 and xs.max() > 0.52 - 0.002


def test_an_object_seen_fewer_times_keeps_every_measurement():
    measurements = _measurements(MAX_HISTORY)
    session_map = SessionMap()
    for m in measurements:
        session_map.update(m)
    obj = session_map.objects[0]
    assert len(obj.centers) == MAX_HISTORY and obj.history_stride == 1
    assert np.allclose(obj.center_world, np.median([m.center_world for m in measurements], axis=0))


def _decision(kind: str, object_id: int, frame: int, session: str = "target") -> DecisionEvent:
    return DecisionEvent(frame_index=frame, session=session, object_id=object_id, kind=kind, reason="test",
                         center_world=np.zeros(3), center_source=np.zeros(3), score=0.5)


def test_a_pair_keeps_each_objects_latest_unchanged_decision_and_every_change():
    pair = PairResult(0, "source", "target", detector=None)  # type: ignore[arg-type]
    every = []
    for frame in range(2000):  # three objects re-tested at every view
        every += [_decision("unchanged", object_id, frame) for object_id in (0, 1, 2)]
    every += [_decision("added", 3, 5), _decision("unchanged", 4, 7), _decision("added", 4, 9),
              _decision("moved", 4, 2000), _decision("removed", 7, 2000, session="source")]
    for decision in every:
        pair.relabel(decision)
    assert len(pair.decisions) == 3 + 1 + 4  # the latest "unchanged" of objects 0-2 and 4, and the four changes
    kept, full = PairOutcome.of(pair.decisions), PairOutcome.of(every)
    assert kept.target == full.target and kept.removed == full.removed
    assert [d.kind for d in pair.reported] == ["added", "moved", "removed"]
