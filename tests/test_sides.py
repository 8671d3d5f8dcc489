"""From which sides two sessions saw an object (`ndfa.change.sides`), and the detector's rules that
ask it: an "added" object where a "removed" one stood, compared across no common side, is doubtful."""

import numpy as np
import pytest

from ndfa.change.associate import Measurement
from ndfa.change.config import DetectorConfig, EvidenceConfig, RegistrationConfig
from ndfa.change.detector import ChangeDetector, reported_changes
from ndfa.change.sides import common_side, mean_azimuth_deg, view_azimuths
from ndfa.core.geometry import rotation_z
from tests.test_sight import K, look_at


def test_a_views_azimuth_is_the_direction_to_its_camera_about_up_turned_into_the_source_world():
    center = np.array([1.0, 2.0, 0.8])
    cameras = center + np.array([[1.0, 0.0, 0.5], [0.0, -2.0, 0.4], [-1.0, 0.0, 0.0]])
    np.testing.assert_allclose(np.degrees(view_azimuths(cameras, center)), [0.0, -90.0, 180.0], atol=1e-9)
    turned = view_azimuths(cameras, center, rotation_z(np.radians(30.0)))
    np.testing.assert_allclose(np.degrees(turned), [30.0, -60.0, -150.0], atol=1e-9)
    assert mean_azimuth_deg(np.radians([170.0, -170.0])) == pytest.approx(180.0, abs=1e-6) or \
        mean_azimuth_deg(np.radians([170.0, -170.0])) == pytest.approx(-180.0, abs=1e-6)


def test_views_are_from_a_common_side_within_the_angle_across_the_wrap():
    front, back = np.radians([-80.0, -90.0, -135.0]), np.radians([80.0, 90.0, 179.0])
    a, b = common_side(front, back, 90.0)
    assert a.tolist() == [False, False, True] and b.tolist() == [False, False, True]   # -135 and 179: 46 apart
    a, b = common_side(front, back, 30.0)
    assert not a.any() and not b.any()
    a, b = common_side(front, front + 0.1, 90.0)
    assert a.all() and b.all()


def _replaced_in_place(target_eye_x: float, similarity: float = 0.25, evidence: EvidenceConfig = EvidenceConfig()):
    """A table of four mugs and a fifth at its middle in both sessions, whose target code is unlike
    its source code, at cosine `similarity` (one mug's codes from opposite sides can be this unlike).
    The source looks from x = -1.2; the target from `target_eye_x`. The reported changes and the
    withheld ones, by mask id."""
    table = np.array([0.0, 0.0])
    mugs = {k + 1: np.r_[table + offset, 0.8] for k, offset in enumerate([(-0.2, -0.15), (0.2, -0.1), (-0.15, 0.2),
                                                                             (0.25, 0.2)])}
    place = np.r_[table, 0.8]
    rng = np.random.default_rng(0)
    codes = {i: rng.normal(size=16) for i in (1, 2, 3, 4, 20, 30)}
    before = codes[30] / np.linalg.norm(codes[30])
    other = codes[20] - (codes[20] @ before) * before
    codes[20] = 4.0 * (similarity * before + np.sqrt(1 - similarity**2) * other / np.linalg.norm(other))
    detector = ChangeDetector(DetectorConfig(registration=RegistrationConfig(pairs=4), evidence=evidence))
    for session, layout, eye_x, first in (("source", mugs | {30: place}, -1.2, 0), ("target", mugs | {20: place},
                                                                                     target_eye_x, 20)):
        for view in range(10):
            frame = first + view
            detector.add_view(session, frame, np.full((480, 640), 9.0, np.float32), K,  # type: ignore[arg-type]
                              look_at([eye_x, -0.3 + 0.06 * view, 1.3], place))
            measurements = [Measurement(frame, i, codes[i] + rng.normal(scale=0.02, size=16),
                                        c + rng.normal(scale=0.003, size=3), 0.8) for i, c in layout.items()]
            (detector.add_source if session == "source" else detector.add_target)(measurements)
    decisions = [e for e in detector.finish() if hasattr(e, "kind")] + list(detector.changed.values()) \
        + list(detector.unseen.values())
    return ({d.instance_ids[0]: d.kind for d in reported_changes(decisions)},
            {d.instance_ids[0]: d.withheld for d in decisions if d.withheld is not None})


def test_a_replacement_seen_from_opposite_sides_only_is_withheld_as_doubtful():
    """`EvidenceConfig.side_deg`: where the target has an object unlike the one the source had at the
    same place, "added" + "removed" stand when both sessions looked from one side; when they looked
    from opposite sides (the source from the front, the target from behind: `shelves` seed 4's mug
    29, cosine 0.35) the codes are no evidence of another object, and both are withheld with the
    reason, unless they are nearer unrelated objects' (`doubtful_share`: at most half delta_s)."""
    same_side, withheld = _replaced_in_place(-1.2)
    assert same_side == {20: "added", 30: "removed"} and withheld == {}
    opposite, withheld = _replaced_in_place(1.2)
    assert opposite == {} and set(withheld) == {20, 30}
    assert "doubtful" in withheld[20] and "0 / 0 views from a common side" in withheld[20]
    assert withheld[30] == withheld[20]
    unrelated, withheld = _replaced_in_place(1.2, similarity=0.1)
    assert unrelated == {20: "added", 30: "removed"} and withheld == {}
    off, withheld = _replaced_in_place(1.2, evidence=EvidenceConfig(side_deg=None))
    assert off == {20: "added", 30: "removed"} and withheld == {}
