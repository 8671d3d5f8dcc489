"""Degenerate input for pose estimation (ndfa.trajectory.checks): time gaps, frames without depth and
flat views are named frame by frame where poses are estimated (`ndfa detect`, `ndfa poses`, the
importers' --poses), and a session none of whose frames can be tracked stops with one line."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.errors import NdfaError, TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import interpolate_pose, make_pose, rotation_z
from ndfa.io.export.tum import export_tum
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.run.world import prepare_session
from ndfa.trajectory.checks import (
    InputMonitor,
    InputWarning,
    _block_mean,
    check_frames,
    describe_frames,
    fill_untracked,
    inspect_frame,
)
from ndfa.trajectory.rewrite import rewrite_poses

SAMPLE = Path(__file__).resolve().parents[1] / "recordings" / "sample"
FRAMES = 8


def raw_copy(out: Path, edit=lambda frame: frame, frames: list[Frame] | None = None) -> Path:
    """A recording as a sensor writes it (no poses; the given ones kept as the truth) of the sample
    source's first FRAMES frames, or of `frames`, each passed through `edit`."""
    if frames is None:
        frames = list(RecordingReader(SAMPLE / "source.mcap").frames(stop=FRAMES))
    with RecordingWriter(out, {"source": "tum", "session": out.stem, "poses": "none"}) as writer:
        for frame in frames:
            frame = dataclasses.replace(frame, pose_world_camera_true=frame.pose_world_camera, instances=None)
            writer.write_frame(edit(frame))
    return out


def without_depth(indices):
    def edit(frame):
        return dataclasses.replace(frame, depth=np.zeros_like(frame.depth)) if frame.index in indices else frame
    return edit


def shifted_after(index: int, seconds: float):
    def edit(frame):
        return dataclasses.replace(frame, timestamp=frame.timestamp + seconds) if frame.index >= index else frame
    return edit


# -- flat views: a wall and the floor, as an upright camera sliding along the wall sees them ---------

K_SMALL = np.array([[160.0, 0.0, 79.5], [0.0, 160.0, 59.5], [0.0, 0.0, 1.0]])


def wall_frames(count: int, textured: bool) -> list[Frame]:
    """A wall 2 m ahead and the floor 1.2 m below: every frame's depth is the same whatever the
    camera's slide along the wall (0.05 m per frame); the colour is a checkerboard on the wall
    (`textured`) or one grey."""
    rows, cols = np.mgrid[0:120, 0:160]
    ray_y = (rows - K_SMALL[1, 2]) / K_SMALL[1, 1]
    with np.errstate(divide="ignore"):
        depth = np.minimum(2.0, np.where(ray_y > 0, 1.2 / ray_y, np.inf)).astype(np.float32)
    frames = []
    for index in range(count):
        pose = make_pose(np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), np.array([0.05 * index, 0.0, 1.2]))
        x_on_wall = (cols - K_SMALL[0, 2]) / K_SMALL[0, 0] * 2.0 + 0.05 * index
        checker = (np.floor(x_on_wall / 0.1) + np.floor(ray_y * 2.0 / 0.1)) % 2
        grey = np.where(checker > 0, 200, 60) if textured else np.full(depth.shape, 128)
        rgb = np.repeat(grey[..., None], 3, axis=2).astype(np.uint8)
        frames.append(Frame(index=index, timestamp=index / 10.0, rgb=rgb, depth=depth.copy(), K=K_SMALL,
                            pose_world_camera=pose))
    return frames


# -- the pure checks -----------------------------------------------------------------------------------


def test_describe_frames_gives_runs():
    assert describe_frames([3, 40, 41, 42, 59, 58, 57, 70]) == "3, 40-42, 57-59, 70"
    assert describe_frames(range(0, 40, 2)) == "0, 2, 4, 6, 8, 10, 12, 14 and 12 more"


def test_sample_frames_pass_every_check():
    monitor = InputMonitor()
    for frame in RecordingReader(SAMPLE / "source.mcap").frames(stop=FRAMES):
        monitor.observe(frame)
    report = monitor.report()
    assert report.warnings() == [] and report.untrackable is None
    assert all(check.textured for check in monitor.checks)


def test_a_gap_and_frames_without_depth_are_named():
    frames = list(RecordingReader(SAMPLE / "source.mcap").frames(stop=FRAMES))
    frames = [shifted_after(5, 2.0)(without_depth({2, 3})(frame)) for frame in frames]
    report = check_frames([inspect_frame(frame) for frame in frames])
    assert report.without_depth == [2, 3] and report.flat == []
    assert [(gap.before, gap.after) for gap in report.gaps] == [(4, 5)]
    assert report.gaps[0].seconds == pytest.approx(2.2, abs=1e-3)
    gap, depth = report.warnings("held")
    assert gap.startswith("time gap of 2.20 s between frames 4 (at 0.80 s) and 5 (at 3.00 s; median step 200 ms)")
    assert depth.startswith("frames 2-3 (2 of 8) have no usable depth") and depth.endswith("their poses are held")


def test_flat_views_are_named_and_untextured_ones_cannot_be_tracked():
    textured = check_frames([inspect_frame(frame) for frame in wall_frames(4, textured=True)])
    assert textured.flat == [0, 1, 2, 3] and textured.flat_untextured == [] and textured.untrackable is None
    assert "frames 0-3 (4 of 4) see only flat surfaces" in textured.warnings()[0]
    assert "4 rest on their colour" in textured.warnings()[0]
    # The same views without texture (or with depth-only odometry): nothing fixes the slide.
    for report in (check_frames([inspect_frame(frame) for frame in wall_frames(4, textured=False)]),
                   check_frames([inspect_frame(frame) for frame in wall_frames(4, textured=True)], uses_colour=False)):
        assert report.flat_untextured == [0, 1, 2, 3]
        assert report.untrackable.startswith("no frame can be tracked: each of its 4 frames with depth sees only flat")
        with pytest.raises(TrajectoryError, match=r"^walls\.mcap: no frame can be tracked"):
            report.raise_if_untrackable("walls.mcap")


def test_fill_untracked_interpolates_in_time_and_holds_at_the_ends():
    a, b = make_pose(np.eye(3), np.zeros(3)), make_pose(rotation_z(np.pi / 2), np.array([1.0, 0.0, 0.0]))
    filled = fill_untracked([0.0, 1.0, 2.0, 4.0, 5.0], [None, a, None, b, None])
    assert np.allclose(filled[0], a) and np.allclose(filled[4], b)
    np.testing.assert_allclose(filled[2][:3, 3], [1 / 3, 0.0, 0.0], atol=1e-12)  # a third of the way in time
    np.testing.assert_allclose(filled[2][:3, :3], rotation_z(np.pi / 6), atol=1e-12)
    with pytest.raises(TrajectoryError):
        fill_untracked([0.0], [None])


# -- where poses are estimated -------------------------------------------------------------------------


def test_detect_names_frames_without_depth_and_interpolates_their_poses(tmp_path):
    path = raw_copy(tmp_path / "holes.mcap", without_depth({3, 4}))
    world = prepare_session(RecordingReader(path), "source", up="z")
    assert world.pose_source.startswith("estimated")
    assert len(world.notes) == 1 and world.notes[0].startswith("frames 3-4 (2 of 8) have no usable depth")
    assert "interpolated between the tracked frames" in world.notes[0]
    assert "\n  warning: source: frames 3-4" in world.describe() and world.as_dict()["notes"] == world.notes
    # Frames 3 and 4 lie on the way from frame 2 to frame 5 (the frames are 0.2 s apart).
    for index, weight in ((3, 1 / 3), (4, 2 / 3)):
        np.testing.assert_allclose(world.poses[index], interpolate_pose(world.poses[2], world.poses[5], weight), atol=1e-6)


def test_detect_names_a_time_gap(tmp_path):
    path = raw_copy(tmp_path / "gap.mcap", shifted_after(5, 2.0))
    world = prepare_session(RecordingReader(path), "source", up="z")
    assert len(world.notes) == 1 and "between frames 4 (at 0.80 s) and 5 (at 3.00 s" in world.notes[0]


def test_detect_stops_in_one_line_when_nothing_can_be_tracked(tmp_path):
    walls = raw_copy(tmp_path / "walls.mcap", frames=wall_frames(5, textured=False))
    with pytest.raises(TrajectoryError, match=r"walls\.mcap: no frame can be tracked: each of its 5 frames"):
        prepare_session(RecordingReader(walls), "source", up="z")
    dark = raw_copy(tmp_path / "dark.mcap", without_depth(set(range(FRAMES))))
    with pytest.raises(TrajectoryError, match=r"dark\.mcap: no frame can be tracked: none of its 8 frames has usable"):
        prepare_session(RecordingReader(dark), "source", up="z")
    textured = prepare_session(RecordingReader(raw_copy(tmp_path / "tex.mcap", frames=wall_frames(5, textured=True))),
                               "source", up="z")
    assert "frames 0-4 (5 of 5) see only flat surfaces" in textured.notes[0]


@pytest.mark.slow
def test_ndfa_poses_warns_and_stops(tmp_path):
    path = raw_copy(tmp_path / "holes.mcap", without_depth({6}))
    with pytest.warns(InputWarning, match=r"holes\.mcap: frames 6 \(1 of 8\) have no usable depth"):
        rewrite_poses(path, tmp_path / "out.mcap", method="rgbd")
    walls = raw_copy(tmp_path / "walls.mcap", frames=wall_frames(4, textured=True))
    with pytest.raises(TrajectoryError, match=r"walls\.mcap: no frame can be tracked.*colour not used"):
        rewrite_poses(walls, tmp_path / "walls-out.mcap", method="kiss-icp")
    assert not (tmp_path / "walls-out.mcap").exists()


@pytest.mark.slow
def test_import_with_estimated_poses_warns_and_stops(tmp_path):
    holes = raw_copy(tmp_path / "holes.mcap", lambda frame: shifted_after(4, 2.0)(without_depth({1, 2})(frame)))
    folder = tmp_path / "tum"
    export_tum(holes, folder)
    (folder / "groundtruth.txt").unlink(missing_ok=True)
    runner = CliRunner(env={"COLUMNS": "300"})
    result = runner.invoke(app, ["ingest", "tum", str(folder), "--out", str(tmp_path / "in.mcap"),
                                 "--poses", "kiss-icp"])
    assert result.exit_code == 0, result.output
    assert "warning: time gap of 2.20 s between frames 3 (at 0.60 s) and 4 (at 2.80 s" in result.output
    assert "warning: frames 1-2 (2 of 8) have no usable depth" in result.output
    assert "their poses are interpolated between the tracked frames around them" in result.output
    poses = [frame.pose_world_camera for frame in RecordingReader(tmp_path / "in.mcap").frames()]
    # frames 1 and 2 (no depth) lie a third and two thirds of the way from frame 0 to frame 3
    for k in (1, 2):
        np.testing.assert_allclose(poses[k][:3, 3], poses[0][:3, 3] + k / 3 * (poses[3][:3, 3] - poses[0][:3, 3]),
                                   atol=1e-6)  # /tf holds float32

    dark = raw_copy(tmp_path / "dark.mcap", without_depth(set(range(FRAMES))))
    export_tum(dark, tmp_path / "dark")
    result = runner.invoke(app, ["ingest", "tum", str(tmp_path / "dark"), "--out", str(tmp_path / "dark-in.mcap"),
                                 "--poses", "estimate"])
    assert isinstance(result.exception, NdfaError)
    assert "no frame can be tracked: none of its 8 frames has usable depth" in str(result.exception)
    assert not (tmp_path / "dark-in.mcap").exists()


def test_the_gap_clock_flags_the_frame_after_a_gap_as_check_frames_does():
    from ndfa.trajectory.checks import GapClock

    clock = GapClock()
    times = [i / 30 for i in range(5)] + [2.0 + i / 30 for i in range(5, 8)]  # 30 Hz, then 2 s missing
    assert [clock.after_gap(t) for t in times] == [False] * 5 + [True, False, False]


@pytest.mark.parametrize("step", [1, 2, 3, 4])
def test_the_block_mean_of_whole_blocks_is_that_of_the_strided_sums(step):
    # A frame of whole blocks takes OpenCV's area resize at a power-of-two step; one a pixel larger
    # each way the strided sums (its last partial blocks cropped off): the same values to the bit.
    rng = np.random.default_rng(step)
    rows, cols = 24, 32
    rgb = rng.integers(0, 256, (rows * step + 1, cols * step + 1, 3), dtype=np.uint8)
    whole = _block_mean(rgb[:rows * step, :cols * step], step, (rows, cols))
    padded = _block_mean(rgb, step, (rows + 1, cols + 1))[:rows, :cols]
    assert whole.dtype == np.float32 and whole.shape == (rows, cols, 3)
    assert np.array_equal(whole, padded)
