"""Sightings: views too small to encode count toward the waiting minimum (`ndfa.change.sightings`)."""

import dataclasses

import numpy as np
import pytest

from ndfa.change.associate import Measurement
from ndfa.change.config import DetectorConfig, WaitingConfig
from ndfa.change.detector import ChangeDetector, reported_changes
from ndfa.change.register import RegistrationPrior
from ndfa.change.sightings import SessionSightings, Sighting
from ndfa.perception.observations import ObservationConfig, extract_observations
from ndfa.sim.camera import PinholeCamera
from tests.test_perception import _frame


def _code(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=16)


def _removed(sightings_before: int, sightings_after: int, counted: bool = True) -> list[int]:
    """Source: mugs A and B in ten frames, mug R 30 cm from A measured once (frame 9), sighted
    below the bar in `sightings_before` frames before it and `sightings_after` after (their
    centroids 3 cm off its center, toward the camera). Target: A and B, R's place empty. The
    mask ids of the source objects reported removed."""
    config = DetectorConfig(waiting=WaitingConfig(sightings=counted))
    detector = ChangeDetector(config)
    detector.add_registration_prior(RegistrationPrior("shared world", np.eye(4)))
    codes = {1: _code(1), 2: _code(2), 3: _code(3)}
    place = {1: np.array([0.0, 0.0, 0.8]), 2: np.array([0.0, 0.3, 0.8]), 3: np.array([0.3, 0.0, 0.8])}
    seen_at = {9}
    sighted_at = set(range(9 - sightings_before, 9)) | set(range(10, 10 + sightings_after))
    for k in range(20):
        frame = [Measurement(k, i, codes[i], place[i], 0.7) for i in (1, 2) if k < 10] + \
                ([Measurement(k, 3, codes[3], place[3], 0.7)] if k in seen_at else [])
        sightings = [Sighting(k, 3, place[3] + [-0.03, 0.0, 0.0], 200)] if k in sighted_at else []
        detector.add_source(frame, sightings)
    for k in range(20, 30):
        detector.add_target([Measurement(k, i, codes[i], place[i], 0.7) for i in (1, 2)])
    decisions = [e for e in detector.finish() if hasattr(e, "kind")]
    return sorted(d.instance_ids[0] for d in reported_changes(decisions) if d.kind == "removed")


@pytest.mark.parametrize("before, after", [(5, 0), (0, 5), (1, 1)])
def test_an_object_measured_once_and_sighted_in_other_frames_is_reported_removed(before, after):
    """Its sightings, also those before its one measurement (kept until it appears), make up the
    waiting minimum of 3 views."""
    assert _removed(before, after) == [3]


@pytest.mark.parametrize("before, after, counted", [(0, 0, True), (1, 0, True), (5, 5, False)])
def test_an_object_measured_once_without_enough_sightings_waits_for_ever(before, after, counted):
    """One measurement and no sightings, one and one sighting (2 views of 3), or sightings not
    counted (`WaitingConfig.sightings` False): never tested, never reported."""
    assert _removed(before, after, counted) == []


def test_a_sighting_counts_for_the_nearest_object_in_reach_not_measured_in_its_frame():
    config = DetectorConfig(waiting=WaitingConfig(sightings=True))
    detector = ChangeDetector(config)
    a, b = np.array([0.0, 0.0, 0.8]), np.array([0.12, 0.0, 0.8])
    detector.add_source([Measurement(0, 1, _code(1), a, 0.7)])
    near_b = Sighting(1, 5, b + [-0.04, 0.0, 0.0], 200)            # in b's frame: b is measured in it
    detector.add_source([Measurement(1, 2, _code(2), b, 0.7)], [near_b])
    counts = detector.sightings["source"]
    assert counts.count(0) == 1 and counts.count(1) == 0          # not b (its frame): a, 8 cm away
    detector.add_source([], [dataclasses.replace(near_b, frame_index=2)])
    assert counts.count(0) == 1 and counts.count(1) == 1          # now b, the nearest
    detector.add_source([], [Sighting(3, 6, a + [0.0, 0.0, 0.3], 200), Sighting(3, 7, a + [0.2, 0.2, 0.0], 200)])
    assert counts.count(0) == 1 and counts.count(1) == 1 and len(counts.loose) == 2  # above it, beside: kept
    detector.add_source([Measurement(4, 8, _code(8), a + [0.2, 0.2, 0.0], 0.7)])
    assert counts.count(2) == 1 and len(counts.loose) == 1        # claimed by the object measured there


def test_a_mask_skipped_only_for_its_size_gives_its_centroid():
    depth = np.full((480, 640), 2.0, dtype=np.float32)
    instances = np.zeros((480, 640), dtype=np.uint16)
    instances[200:215, 300:315] = 1          # 225 px: a sighting
    instances[300:308, 300:308] = 2          # 64 px: below `sighting_pixels`
    instances[0:15, 300:315] = 3             # 225 px on the border
    observations, skipped = extract_observations(_frame(depth, instances))
    assert observations == []
    centers = {s.instance_id: s.center_camera for s in skipped}
    assert centers[2] is None and centers[3] is None and all("min_pixels" in s.reason for s in skipped)
    camera = PinholeCamera()
    expected = np.array([(307 - camera.K[0, 2]) / camera.K[0, 0], (207 - camera.K[1, 2]) / camera.K[1, 1], 1.0]) * 2.0
    np.testing.assert_allclose(centers[1], expected, atol=1e-9)
    _, skipped = extract_observations(_frame(depth, instances), ObservationConfig(sighting_pixels=0))
    assert all(s.center_camera is None for s in skipped)


@pytest.mark.parametrize("sighted, withheld", [(5, True), (2, False), (0, False)])
def test_an_added_object_where_the_source_sighted_something_is_withheld(sighted, withheld):
    """The source measured mugs A and B and sighted something at P (below the bar) in `sighted`
    frames; the target measures A, B and a mug at P in ten frames. With as many sightings as the
    waiting minimum asks views of an object, the source did not see P empty: the "added" is withheld."""
    detector = ChangeDetector(DetectorConfig(waiting=WaitingConfig(sightings=True)))
    detector.add_registration_prior(RegistrationPrior("shared world", np.eye(4)))
    codes = {1: _code(1), 2: _code(2), 3: _code(3)}
    place = {1: np.array([0.0, 0.0, 0.8]), 2: np.array([0.0, 0.3, 0.8]), 3: np.array([0.3, 0.0, 0.8])}
    for k in range(10):
        detector.add_source([Measurement(k, i, codes[i], place[i], 0.7) for i in (1, 2)],
                            [Sighting(k, 3, place[3] + [-0.03, 0.0, 0.0], 200)] if k < sighted else [])
    for k in range(20, 30):
        detector.add_target([Measurement(k, i, codes[i], place[i], 0.7) for i in (1, 2, 3)])
    added = [e for e in [*detector.changed.values(), *detector.unseen.values(), *detector.finish()]
             if getattr(e, "kind", None) == "added"]
    assert [e.instance_ids for e in added] == [(3,)]
    assert (added[0].withheld is not None and "sighted something there in 5 views" in added[0].withheld) == withheld
    assert (added[0].withheld is None) == (not withheld)


@pytest.mark.parametrize("beside_m, reported", [(0.02, False), (0.15, True)])
def test_sightings_do_not_make_a_fragment_testable(beside_m, reported):
    """Target object F, measured once (6 cm from target object A, in A's frame: another object then)
    and sighted in five frames, ends `beside_m` (horizontally, 9 cm higher) from A, measured in ten
    frames (where its median drifted; neither was in the source). Two objects cannot stand 2 cm
    apart: F is a view of A's upper part, its sightings repeat it, and it is never reported;
    15 cm away it is an object of its own, "added"."""
    detector = ChangeDetector(DetectorConfig(waiting=WaitingConfig(sightings=True)))
    detector.add_registration_prior(RegistrationPrior("shared world", np.eye(4)))
    codes = {i: _code(i) for i in (1, 2, 3, 4)}
    place = {1: np.array([0.0, 0.0, 0.8]), 2: np.array([0.0, 0.3, 0.8]), 3: np.array([0.5, 0.0, 0.8])}
    first = place[3] + [max(beside_m, 0.06), 0.0, 0.09]
    for k in range(10):
        detector.add_source([Measurement(k, i, codes[i], place[i], 0.7) for i in (1, 2)])
    for k in range(20, 30):
        frame = [Measurement(k, i, codes[i], place[i], 0.7) for i in (1, 2, 3)]
        frame += [Measurement(k, 4, codes[4], first, 0.7)] if k == 24 else []
        detector.add_target(frame, [Sighting(k, 4, first + [-0.02, 0, 0], 200)] if k > 24 else [])
    fragment = next(o for o in detector.target.objects.values() if o.instance_ids == (4,))
    assert fragment.n_measurements == 1 and detector.sightings["target"].count(fragment.object_id) == 5
    fragment.center_world = place[3] + [beside_m, 0.0, 0.09]
    added = [e for e in [*detector.changed.values(), *detector.finish()] if getattr(e, "kind", None) == "added"]
    assert sorted(e.instance_ids for e in added) == ([(3,), (4,)] if reported else [(3,)])


@pytest.mark.parametrize("origin", [[0.0, 0.0, 0.0], [0.013, -0.007, 0.004], [1.237, 2.519, -0.011]])
def test_the_sightings_at_a_place_do_not_depend_on_the_worlds_origin(origin):
    """Sightings 5 mm inside and 5 mm outside the reach of a place: 3 counted wherever the world's
    origin lies (a count over cells of the points would move them across the reach with it)."""
    sightings = SessionSightings(DetectorConfig(waiting=WaitingConfig(sightings=True)))
    session_map = ChangeDetector(DetectorConfig()).source  # no objects: every sighting unclaimed
    place = np.array([0.4, 0.2, 0.8]) + origin
    inside, outside = sightings.reach_m - 0.005, sightings.reach_m + 0.005
    for k, (radius, angle) in enumerate([(inside, 0.3), (inside, 2.0), (inside, 4.1), (outside, 1.0), (outside, 5.0)]):
        offset = [radius * np.cos(angle), radius * np.sin(angle), 0.0]
        sightings.add([Sighting(k, 9, place + offset, 200)], session_map)
    assert sightings.unexplained(place, session_map) == 3
