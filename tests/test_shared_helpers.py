"""The helpers every stage shares: pinhole projection, pose interpolation, atomic writes, TUM pose
lines, the visibility rule and the conventions' defaults."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from ndfa.core import conventions
from ndfa.core.conventions import is_visible
from ndfa.core.geometry import axis_angle_to_matrix, backproject, interpolate_pose, make_pose, project, rotation_z
from ndfa.eval.baselines.nn import NNConfig
from ndfa.eval.baselines.tsdf import TSDFConfig
from ndfa.io.atomic import Staged, atomic_dir, atomic_path
from ndfa.io.tum_format import pose_from_fields, pose_line
from ndfa.perception.observations import ObservationConfig
from ndfa.sim.camera import PinholeCamera

K = np.array([[525.0, 0.0, 319.5], [0.0, 520.0, 239.5], [0.0, 0.0, 1.0]])


def test_project_inverts_backproject():
    rng = np.random.default_rng(0)
    rows, cols, z = rng.uniform(0, 480, 50), rng.uniform(0, 640, 50), rng.uniform(0.2, 4.0, 50)
    uv = project(K, backproject(K, rows, cols, z))
    np.testing.assert_allclose(uv, np.stack([cols, rows], axis=1), atol=1e-9)


def test_project_is_the_simulated_cameras_projection():
    camera = PinholeCamera()
    points = np.random.default_rng(1).uniform([-1, -1, 0.5], [1, 1, 3], size=(20, 3))
    uv, z = camera.project(points)
    assert np.array_equal(uv, project(camera.K, points)) and np.array_equal(z, points[:, 2])


def test_project_leaves_points_behind_to_the_caller():
    with np.errstate(all="raise"):  # no warning escapes for z = 0
        uv = project(K, np.array([[0.1, 0.1, 0.0], [0.0, 0.0, 1.0]]))
    assert not np.isfinite(uv[0]).all() and np.allclose(uv[1], [319.5, 239.5])


def test_interpolate_pose_ends_and_middle():
    a = make_pose(np.eye(3), np.zeros(3))
    b = make_pose(rotation_z(np.pi / 2), np.array([2.0, 0.0, 0.0]))
    np.testing.assert_allclose(interpolate_pose(a, b, 0.0), a, atol=1e-12)
    np.testing.assert_allclose(interpolate_pose(a, b, 1.0), b, atol=1e-12)
    middle = interpolate_pose(a, b, 0.5)
    np.testing.assert_allclose(middle[:3, 3], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(middle[:3, :3], rotation_z(np.pi / 4), atol=1e-12)
    # the shorter way round: 350 degrees one way is 10 degrees the other
    c = make_pose(axis_angle_to_matrix(np.array([0.0, 0.0, np.radians(350)])), np.zeros(3))
    np.testing.assert_allclose(interpolate_pose(a, c, 0.5)[:3, :3], rotation_z(np.radians(-5)), atol=1e-12)


def test_atomic_path_keeps_the_old_file_on_error(tmp_path: Path):
    path = tmp_path / "sub" / "table.md"
    with atomic_path(path) as temporary:
        assert temporary.name == "table.md" and temporary != path
        temporary.write_text("one")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as temporary:
            temporary.write_text("two, half")
            raise RuntimeError("crash")
    assert path.read_text() == "one"
    assert [p.name for p in path.parent.iterdir()] == ["table.md"]


def test_atomic_dir_fills_a_new_or_empty_folder(tmp_path: Path):
    for folder in (tmp_path / "new", tmp_path / "empty"):
        if folder.name == "empty":
            folder.mkdir()
        with atomic_dir(folder) as temporary:
            (temporary / "a.txt").write_text("a")
            assert not (folder / "a.txt").exists()
        assert (folder / "a.txt").read_text() == "a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "new"]


def test_staged_discard_leaves_nothing(tmp_path: Path):
    staged = Staged(tmp_path / "run.rrd")
    staged.temporary.write_bytes(b"partial")
    staged.discard()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OSError):
        Staged(tmp_path / "missing" / "x.mcap", make_parents=False)


def test_tum_pose_line_round_trip():
    pose = make_pose(axis_angle_to_matrix(np.array([0.3, -0.2, 1.1])), np.array([1.25, -0.5, 0.75]))
    line = pose_line(12.5, pose)
    assert line.startswith("12.500000 1.250000000 -0.500000000 0.750000000 ")
    fields = line.split()
    assert float(fields[0]) == 12.5
    np.testing.assert_allclose(pose_from_fields(fields[1:]), pose, atol=1e-8)


def test_one_visibility_rule_for_numbers_arrays_and_tables():
    at = conventions.VISIBLE_PIXELS
    assert is_visible(at) and not is_visible(at - 1)
    assert is_visible(np.array([at - 1, at])).tolist() == [False, True]
    table = pl.DataFrame({"n_pixels": [at - 1, at, at + 5]})
    assert table.filter(is_visible(pl.col("n_pixels")))["n_pixels"].to_list() == [at, at + 5]


def test_thresholds_default_to_the_conventions():
    observations, tsdf, nn = ObservationConfig(), TSDFConfig(), NNConfig()
    assert observations.min_pixels == tsdf.min_pixels == conventions.VISIBLE_PIXELS
    assert (observations.min_depth_m, observations.max_depth_m) == (conventions.MIN_DEPTH_M, conventions.MAX_DEPTH_M)
    assert tsdf.max_depth_m == nn.max_depth_m == conventions.MAX_DEPTH_M
