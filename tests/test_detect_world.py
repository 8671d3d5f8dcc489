"""`ndfa detect` on recordings whose world is not z-up: up is estimated and the world levelled, so the
result matches the z-up recording's; a world without a findable up stops with one line."""

from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ndfa.core.errors import RecordingError
from ndfa.core.geometry import axis_angle_to_matrix, make_pose
from ndfa.eval.runs import score_detection
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.run.detect import RunOptions, run_detection
from ndfa.run.world import prepare_session

SAMPLE = Path(__file__).resolve().parents[1] / "recordings" / "sample"
WRITER_KEYS = ("format", "format_version", "depth_scale", "units")


def _rewritten(source: Path, out: Path, pose_world_world: np.ndarray, meta_update: dict, stop: int | None = None) -> Path:
    """A copy of `source` whose world is turned by `pose_world_world` (every pose, given and true,
    and the ground truth's objects, with the turn recorded as the truth's `world_tilt`)."""
    reader = RecordingReader(source)
    meta = {k: v for k, v in reader.meta.items() if k not in WRITER_KEYS} | meta_update
    with RecordingWriter(out, meta) as writer:
        if reader.ground_truth is not None:
            writer.write_ground_truth(_turned_truth(reader.ground_truth, pose_world_world))
        for frame in reader.frames(stop=stop):
            true = frame.pose_world_camera_true
            writer.write_frame(dataclasses.replace(
                frame, pose_world_camera=pose_world_world @ frame.pose_world_camera,
                pose_world_camera_true=None if true is None else pose_world_world @ true))
    return out


def _turned_truth(truth: dict, pose_world_world: np.ndarray) -> dict:
    turned = copy.deepcopy(truth)
    for obj in turned.get("objects", []):
        for session in ("source", "target"):
            if obj.get(session):
                obj[session]["pose_world_object"] = (pose_world_world @ np.asarray(obj[session]["pose_world_object"])).tolist()
    level = np.asarray(truth["world_tilt"]["pose_world_level"]) if truth.get("world_tilt") else np.eye(4)
    turned["world_tilt"] = {"pose_world_level": (pose_world_world @ level).tolist()}
    return turned


def _tilt(degrees: float) -> np.ndarray:
    axis = np.array([0.6, -0.8, 0.0])
    return make_pose(axis_angle_to_matrix(np.radians(degrees) * axis), np.array([0.3, -0.2, 0.1]))


def test_a_synthetic_recording_is_taken_as_z_up_and_a_tilted_one_is_levelled(tmp_path):
    world = prepare_session(RecordingReader(SAMPLE / "source.mcap"), "source")
    assert world.up is None and world.levelling is None and "synthetic" in world.up_source

    tilted = _rewritten(SAMPLE / "source.mcap", tmp_path / "tilted.mcap", _tilt(25.0), {"source": "tum"}, stop=12)
    world = prepare_session(RecordingReader(tilted), "source")
    assert world.up is not None and world.up.ok
    assert world.up.tilt_deg == pytest.approx(25.0, abs=1.5)
    frame = world.apply(next(RecordingReader(tilted).frames(stop=1)))
    original = next(RecordingReader(SAMPLE / "source.mcap").frames(stop=1))
    # Levelled: the camera's view of "up" is the original one again (yaw about up stays free).
    up_in_camera = frame.pose_world_camera[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    up_in_camera_original = original.pose_world_camera[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(np.clip(up_in_camera @ up_in_camera_original, -1, 1))) < 1.5


@pytest.mark.slow
def test_detection_on_a_tilted_world_matches_the_z_up_one(tmp_path):
    reference = score_detection(run_detection(SAMPLE / "source.mcap", SAMPLE / "target.mcap"))
    tilt = _tilt(30.0)
    pair = [_rewritten(SAMPLE / f"{s}.mcap", tmp_path / f"{s}.mcap", tilt, {"source": "tum"}) for s in ("source", "target")]
    tilted = score_detection(run_detection(*pair))
    assert all(w.levelling is not None for w in tilted.worlds.values())
    assert tilted.score is not None and reference.score is not None
    assert abs(tilted.score.tp - reference.score.tp) <= 1
    assert abs(tilted.score.fp - reference.score.fp) <= 1
    # Without levelling (the user insists on z) the tilted world loses objects or changes.
    assert score_detection(run_detection(*pair, options=RunOptions(up="z"))).summary() != tilted.summary()


def test_no_up_stops_with_the_reason(tmp_path):
    # Every pose turned by its own large tilt: the frames cannot agree on one up.
    reader = RecordingReader(SAMPLE / "source.mcap")
    meta = {k: v for k, v in reader.meta.items() if k not in WRITER_KEYS} | {"source": "tum"}
    rng = np.random.default_rng(0)
    with RecordingWriter(tmp_path / "wobbly.mcap", meta) as writer:
        for frame in reader.frames(stop=12):
            turn = axis_angle_to_matrix(rng.normal(size=3) * 0.6)
            writer.write_frame(dataclasses.replace(frame, pose_world_camera=make_pose(turn, np.zeros(3))
                                                   @ frame.pose_world_camera))
    with pytest.raises(RecordingError, match="no world up found.*--up z"):
        prepare_session(RecordingReader(tmp_path / "wobbly.mcap"), "source")
    assert prepare_session(RecordingReader(tmp_path / "wobbly.mcap"), "source", up="z").levelling is None


def test_a_session_without_objects_says_why():
    from ndfa.core.events import FrameEvent, ObservationEvent
    from ndfa.run.detect import SessionCounts

    frame = next(RecordingReader(SAMPLE / "source.mcap").frames(stop=1))
    counts = SessionCounts()
    counts.count(FrameEvent(session="source", frame=dataclasses.replace(frame, instances=None)))
    assert "none of its 1 frames has an object mask or segment" in counts.why_none()

    counts = SessionCounts()
    counts.count(FrameEvent(session="source", frame=frame))
    for n in (120, 80):
        counts.count(ObservationEvent(session="source", frame_index=0, instance_id=n, n_pixels=n,
                                      skipped=f"{n} pixels < min_pixels 300"))
    counts.count(ObservationEvent(session="source", frame_index=0, instance_id=9, n_pixels=900,
                                  skipped="fragmented: largest cluster holds 10 of 90 points"))
    assert counts.why_none() == "every view of an object was skipped (2 pixels < min_pixels, 1 fragmented)"


def test_truth_poses_replace_the_given_ones_and_need_a_ground_truth_channel(tmp_path):
    offset = _tilt(10.0)
    shifted = tmp_path / "shifted.mcap"
    reader = RecordingReader(SAMPLE / "source.mcap")
    meta = {k: v for k, v in reader.meta.items() if k not in WRITER_KEYS}
    with RecordingWriter(shifted, meta) as writer:
        for frame in reader.frames(stop=3):
            writer.write_frame(dataclasses.replace(frame, pose_world_camera=offset @ frame.pose_world_camera,
                                                   pose_world_camera_true=frame.pose_world_camera))
    world = prepare_session(RecordingReader(shifted), "source", poses="truth")
    for frame, original in zip(RecordingReader(shifted).frames(), RecordingReader(SAMPLE / "source.mcap").frames(stop=3)):
        np.testing.assert_allclose(world.apply(frame).pose_world_camera, original.pose_world_camera, atol=1e-9)

    without_truth = _rewritten(SAMPLE / "source.mcap", tmp_path / "plain.mcap", np.eye(4), {}, stop=2)
    assert next(RecordingReader(without_truth).frames()).pose_world_camera_true is None
    with pytest.raises(RecordingError, match="no true pose"):
        prepare_session(RecordingReader(without_truth), "source", poses="truth")


def test_estimated_poses_are_scored_against_the_true_ones_when_a_recording_has_them():
    from ndfa.run.world import SessionWorld, _pose_error

    truth = {i: make_pose(axis_angle_to_matrix(np.array([0.0, 0.0, 0.1 * i])), np.array([0.1 * i, 0.02 * i * i, 0.0]))
             for i in range(10)}
    elsewhere = _tilt(30.0)   # the estimate's own world: ATE aligns it away
    quality = _pose_error({i: elsewhere @ pose for i, pose in truth.items()}, truth)
    assert quality is not None and quality["ate_rmse_m"] < 1e-9 and quality["rpe_translation_m"] < 1e-9
    jumped = {i: elsewhere @ pose @ (make_pose(np.eye(3), np.array([0.05, 0, 0])) if i >= 5 else np.eye(4))
              for i, pose in truth.items()}
    quality = _pose_error(jumped, truth)
    assert quality is not None and 0.01 < quality["ate_rmse_m"] < 0.05
    assert _pose_error(jumped, {i: truth[i] for i in range(5)}) is None   # not every frame has a true pose
    world = SessionWorld("target", pose_source="estimated", up_source="z", pose_error=quality)
    assert "ATE RMSE" in world.describe() and world.as_dict()["pose_error"] == quality


@pytest.mark.slow
def test_a_synthetic_recording_with_estimated_poses_has_its_up_estimated(tmp_path):
    # Odometry's world starts at its first camera: the simulator's "z is up" no longer holds there.
    short = _rewritten(SAMPLE / "source.mcap", tmp_path / "short.mcap", np.eye(4), {}, stop=12)
    world = prepare_session(RecordingReader(short), "source", poses="estimate")
    assert world.poses is not None and world.up is not None and world.up_source == "estimated"
    assert prepare_session(RecordingReader(short), "source").up_source.startswith("z (a synthetic")


@pytest.mark.slow
def test_the_up_from_the_patches_the_odometry_found_is_the_up_of_the_frames_read_again(tmp_path, monkeypatch):
    # The odometry finds the up's frames' planar patches as it reads them; the up is then made
    # from those and the poses, without reading the file again, and must be what reading gives.
    import ndfa.run.world as world_module
    from ndfa.run.world import UP_FRAMES, spread, up_under_poses
    from ndfa.trajectory.up import estimate_up

    short = _rewritten(SAMPLE / "source.mcap", tmp_path / "short.mcap", np.eye(4), {}, stop=14)
    reader = RecordingReader(short)
    positions = [0, 2, 3, 5, 7, 8, 10, 13]  # a run that uses some frames (`--rate`)

    def unused(*args, **kwargs):
        raise AssertionError("the up read the frames again")

    with monkeypatch.context() as patched:
        patched.setattr(world_module, "estimate_up", unused)
        world = prepare_session(reader, "source", poses="estimate", positions=positions)
    read_again = up_under_poses(estimate_up(
        world.apply(f) for f in reader.frames(positions=spread(len(reader), UP_FRAMES, positions))), world.pose_quality)
    assert world.up is not None and world.up.frames_used == len(positions)
    assert {**world.up.to_dict(), "seconds": 0} == {**read_again.to_dict(), "seconds": 0}



@pytest.mark.slow
def test_estimated_poses_are_checked_backwards_only_when_asked(tmp_path, monkeypatch):
    # What the backward estimate measures is tested in test_pose_quality; here: that detect's
    # option reaches the odometry, with the session's frames last first, and only when asked.
    import ndfa.run.world as world_module

    short = _rewritten(SAMPLE / "source.mcap", tmp_path / "short.mcap", np.eye(4), {}, stop=6)
    seen: list[list[int] | None] = []
    estimate = world_module.estimate_session_poses

    def spy(*args, backward_frames=None, **kwargs):
        seen.append(None if backward_frames is None else [frame.index for frame in backward_frames])
        return estimate(*args, **kwargs)

    monkeypatch.setattr(world_module, "estimate_session_poses", spy)
    prepare_session(RecordingReader(short), "source", poses="estimate")
    prepare_session(RecordingReader(short), "source", poses="estimate", check_poses_backward=True)
    assert seen == [None, [5, 4, 3, 2, 1, 0]]
