"""A synthetic case only the static scene registers, end to end (issue 29, item 2; docs/registration.md):
a room with furniture along its walls, every mug changed between the sessions (no object pair can
confirm a registration), the target's poses in a world of their own (a session offset). ndfa aligns
the scene clouds (`--registration scene`), accepts the alignment on its own evidence, and scores
the changes; the same room without furniture fits itself turned, and ndfa refuses with the reason.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ndfa.eval.runs import score_detection
from ndfa.io.ingest.synthetic import ingest_sim
from ndfa.pipeline import PipelineConfig
from ndfa.run.detect import RunOptions, run_detection
from ndfa.sim.pose_error import PoseError
from ndfa.sim.presets import make_config
from ndfa.sim.trajectory import TrajectoryConfig

pytestmark = pytest.mark.slow


def _scene(out: Path, furniture: int) -> Path:
    """Two tables, six mugs, all of them changed (3 removed, 3 moved, 1 added); the target's poses
    offset by up to 1 m and 180 deg about up."""
    config = make_config("paper", 0, table_rows=1, table_cols=2, mugs_per_table=(3, 3), total_mugs=None,
                         changes={"added": 1, "removed": 3, "moved": 3, "switched": 0}, furniture=furniture,
                         target_route="perimeter", trajectory=TrajectoryConfig(step_m=0.2),
                         target_pose_error=PoseError(offset_translation_m=1.0, offset_yaw_deg=180.0))
    ingest_sim(config, out)
    return out


def _detect(scene: Path):  # noqa: ANN202
    return score_detection(run_detection(scene / "source.mcap", scene / "target.mcap", PipelineConfig(),
                                         options=RunOptions(registration="scene")))


def test_a_furnished_room_where_every_mug_changed_is_registered_by_the_scene_alone(tmp_path):
    result = _detect(_scene(tmp_path, furniture=6))
    registration = result.registration
    assert registration is not None, result.notes
    assert registration["method"] == "scene (own evidence)" and registration["inliers"] < 2
    evidence = result.alignment.evidence
    assert evidence is not None and evidence.ok and evidence.rival_fitness < 0.8 * evidence.upright_fitness
    score = result.score
    assert (score.tp, score.fp, score.fn) == (7, 0, 0)
    assert all(right == reports for reports, right in score.kinds.values()), score.kinds


def test_the_same_room_without_furniture_fits_itself_turned_and_is_refused_with_the_reason(tmp_path):
    result = _detect(_scene(tmp_path, furniture=0))
    assert result.registration is None
    evidence = result.alignment.evidence
    assert evidence is not None and not evidence.ok and "ambiguous" in evidence.reason
    assert any("too weak to stand" in note and "ambiguous" in note for note in result.notes)
    assert result.score.tp == 0 and result.score.fp == 0  # nothing reported rather than a guess
