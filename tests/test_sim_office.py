"""The office preset (ndfa.sim.office, ndfa.sim.handheld, ndfa.sim.aligned_depth): screens that
return no or wrong depth and are never objects, a hand-held camera whose turns stay within a hand's
90 deg/s at 30 Hz while it sweeps and looks down at the desks, and depth aligned to colour with the
occlusion bands of a RealSense."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ndfa.core.geometry import look_at
from ndfa.io.ingest.synthetic import office, render_objects
from ndfa.sim.aligned_depth import AlignedDepth
from ndfa.sim.handheld import angular_speeds_deg_s
from ndfa.sim.office import SCREEN_FIRST_ID
from ndfa.sim.presets import make_config
from ndfa.sim.render import SceneRenderer
from ndfa.sim.scene import table_grid
from ndfa.sim.trajectory import TrajectoryConfig, camera_poses
from ndfa.sim.world import build_world, procedural_models

pytestmark = pytest.mark.slow  # builds an office world and renders it


@pytest.fixture(scope="module")
def office_scene():
    config = make_config("office", 1, mug_models=6)
    world = build_world(config, procedural_models(config))
    return config, world, office(config, world)


def test_office_preset_is_an_office_recorded_by_hand(office_scene):
    config, world, fixtures = office_scene
    assert config.ceiling and config.textures and config.aligned_depth and config.clutter_per_table > 0
    assert config.trajectory.motion == "handheld" and config.fps == 30.0
    assert len(fixtures.monitors) == len(world.tables) * config.monitors_per_table
    # changes between the sessions as the random preset draws them
    assert world.changes and dataclasses.asdict(make_config("random", 1))["changes"] == config.changes


@pytest.mark.parametrize("reading", ["none", "wrong"])
def test_screens_return_no_or_wrong_depth_and_are_not_objects(office_scene, reading):
    config, world, fixtures = office_scene
    fixtures = dataclasses.replace(fixtures, monitors=[dataclasses.replace(m, reading=reading) for m in fixtures.monitors])
    monitor = fixtures.monitors[0]
    table = world.tables[monitor.table_id - 1]
    outward = 1.0 if table.center_xy[1] >= 0.0 else -1.0
    screen_centre = np.array([table.center_xy[0] + monitor.x, table.center_xy[1] + outward * table.size_xy[1] / 2,
                              table.height + 0.3])
    eye = screen_centre - outward * np.array([0.0, 1.2, -0.3])
    camera = config.camera.scaled(0.25)
    view = SceneRenderer(render_objects(world, "source", None, fixtures)).render(camera, look_at(eye, screen_centre))
    screen = view.instance == monitor.screen_id
    assert screen.sum() > 200 and (view.depth[screen] > 0).all()
    depth, instance = fixtures.sensor(view.depth, view.instance, np.random.default_rng(0))
    assert not (instance >= SCREEN_FIRST_ID).any()  # no screen is ever an instance
    if reading == "none":
        assert (depth[screen] == 0).all()
    else:  # the reflection, far behind the glass; some pixels without depth
        measured = depth[screen] > 0
        assert 0.5 < measured.mean() < 0.9
        assert (depth[screen][measured] > view.depth[screen][measured] + 0.3).all()
    np.testing.assert_array_equal(depth[~screen], view.depth[~screen])


def test_handheld_motion_turns_like_a_hand():
    rng = np.random.default_rng(3)
    config = TrajectoryConfig(step_m=0.08, height_above_table_m=0.6, motion="handheld")
    tables = table_grid(2, 2)
    poses = camera_poses(tables, config, rng, fps=30.0)
    speeds = angular_speeds_deg_s(poses, 30.0)
    assert speeds.max() <= 100.0  # 90 deg/s of pan, pitch at a third of it, a little tremor
    assert np.quantile(speeds, 0.9) >= 40.0  # it sweeps: fast turns are common
    forward, right = poses[:, :3, 2], poses[:, :3, 0]
    pitch = np.degrees(np.arcsin(forward[:, 2]))
    assert -30.0 < np.median(pitch) < -12.0 and pitch.min() >= -36.0  # looking down at the desks
    roll = np.degrees(np.arcsin(right[:, 2]))
    assert np.abs(roll).max() < 10.0 and 0.5 < np.std(roll) < 4.0  # held roughly level, not rigidly
    steady = dataclasses.replace(config, handheld=dataclasses.replace(config.handheld, shake_m=0.0))
    shake = np.linalg.norm(poses[:, :3, 3] - camera_poses(tables, steady, np.random.default_rng(3), fps=30.0)[:, :3, 3],
                           axis=1)
    assert 0.001 < np.sqrt(np.mean(shake**2)) < 0.01  # the hand shakes the path by millimetres


def test_the_office_is_walked_at_a_hand_held_pace_that_drifts():
    config = make_config("office", 1).trajectory
    poses = camera_poses(table_grid(2, 2), config, np.random.default_rng(1), fps=30.0)
    speeds = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) * 30.0  # m/s, the hand's shake included
    assert 0.7 < speeds.mean() < 1.1  # a walk with a camera, not a run (8 cm per frame was 2.4 m/s)
    assert 0.4 < speeds.min() and speeds.max() < 1.4
    assert np.quantile(speeds, 0.9) - np.quantile(speeds, 0.1) > 0.2  # slowing down and speeding up
    fast = camera_poses(table_grid(2, 2), dataclasses.replace(config, step_m=0.08), np.random.default_rng(1), fps=30.0)
    assert len(poses) > 1.5 * len(fast)  # --step 0.08 stays the run over the same route (the pace drifts apart)


def test_aligned_depth_cuts_the_occlusion_bands():
    # A near box (1 m) in front of a far wall (3 m): with a 50 mm stereo baseline at 615 px the band
    # left of the box is 615 * 0.05 * (1 - 1/3) = 20.5 px; the colour offset's on its right 6.8 px.
    depth = np.full((20, 100), 3.0, np.float32)
    depth[:, 40:60] = 1.0
    aligned = AlignedDepth().apply(depth, 615.0)
    assert (aligned[:, 40:60] == 1.0).all()
    assert (aligned[:, 20:40] == 0).all() and (aligned[:, :19] == 3.0).all()
    assert (aligned[:, 60:66] == 0).all() and (aligned[:, 67:] == 3.0).all()
