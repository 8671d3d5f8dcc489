"""`ndfa plant` on a small synthetic pair: a table, a mug on it, seen from a few cameras. The
"real" recordings are renders; planting is checked against renders of the edited scene."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ndfa.core.errors import OptionError
from ndfa.core.frame import Frame
from ndfa.core.geometry import look_at, make_pose
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.run.plant import run_plant
from ndfa.run.plant_plan import PlantedObject, load_mesh, read_plan
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.mesh import box_mesh
from ndfa.sim.noise import DepthNoise
from ndfa.sim.plant import ColorGrid, Cylinder, MeshInserter, SupportPlane, remove_object
from ndfa.sim.render import RenderObject, SceneRenderer

CAMERA = PinholeCamera.from_fov(320, 240, 60.0)  # a mug shows the pixels that make it visible
TABLE_Z = 0.75
TABLE = RenderObject(box_mesh((1.6, 1.2, 0.04), (0.0, 0.0, TABLE_Z - 0.02)), 0, (0.6, 0.45, 0.3))
FLOOR = RenderObject(box_mesh((8.0, 8.0, 0.02), (0.0, 0.0, -0.01)), 0, (0.5, 0.5, 0.5))
MUG_AT = np.array([0.0, 0.1])
EYES = [np.array([1.1, -0.9, 1.35]), np.array([-1.0, -1.0, 1.3]), np.array([0.2, -1.3, 1.4]), np.array([1.2, 0.6, 1.3])]
POSES = [look_at(eye, np.array([0.0, 0.0, TABLE_Z])) for eye in EYES]
PLANE = SupportPlane(np.array([0.0, 0.0, 1.0]), TABLE_Z)
OFF = DepthNoise.off()


def _real_mug() -> RenderObject:
    mug = load_mesh("mug:7")
    return RenderObject(mug.mesh.transformed(make_pose(np.eye(3), np.array([*MUG_AT, TABLE_Z]))), 0, (0.9, 0.9, 0.9))


def _write(path: Path, objects: list[RenderObject], session: str) -> Path:
    renderer = SceneRenderer(objects)
    with RecordingWriter(path, {"source": "sim", "session": session}) as writer:
        for index, pose in enumerate(POSES):
            view = renderer.render(CAMERA, pose)
            writer.write_frame(Frame(index=index, timestamp=float(index), rgb=view.rgb, depth=view.depth,
                                     K=CAMERA.K, pose_world_camera=pose))
    return path


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("plant")
    scene = [FLOOR, TABLE, _real_mug()]
    return _write(folder / "source.mcap", scene, "source"), _write(folder / "target.mcap", scene, "target")


def _plan(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "plan.toml"
    path.write_text(text)
    return path


PLAN = """
[[object]]
name = "real mug"
real = true
at = [0.0, 0.1]
change = "removed"

[[object]]
mesh = "mug:3"
at = [0.45, -0.25]
change = "added"
color = [0.2, 0.6, 0.2]
"""


def test_removed_mug_shows_the_table_behind_and_added_mug_shows_as_rendered(pair, tmp_path):
    source, target = pair
    result = run_plant(source, target, tmp_path / "out", read_plan(_plan(tmp_path, PLAN)), noise=OFF,
                       log=tmp_path / "preview.rrd", preview_every=2)
    assert (tmp_path / "preview.rrd").is_file()
    assert result.edited["target"] == len(POSES) and result.edited["source"] == 0
    added = RenderObject(load_mesh("mug:3").mesh.transformed(
        make_pose(np.eye(3), np.array([0.45, -0.25, TABLE_Z - 0.001]))), 0, (0.2, 0.6, 0.2))
    expected = SceneRenderer([FLOOR, TABLE, added])  # the target as it should look: mug gone, new mug in
    planted = list(RecordingReader(result.paths["target"]).frames())
    for frame, pose in zip(planted, POSES):
        truth = expected.render(CAMERA, pose).depth
        assert np.array_equal(frame.depth > 0, truth > 0)  # the sky stays empty, the table whole
        both = truth > 0
        # Millimetres in the file, and the mesh sunk 1 mm: within a few mm nearly everywhere (the
        # hole's edge keeps some mixed pixels of the real mug).
        assert np.mean(np.abs(frame.depth[both] - truth[both]) < 0.004) > 0.99
    # The untouched source is a copy of the input, frame for frame.
    for a, b in zip(RecordingReader(source).frames(), RecordingReader(result.paths["source"]).frames()):
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.rgb, b.rgb)
        assert np.allclose(a.pose_world_camera, b.pose_world_camera, atol=1e-12)


def test_ground_truth_lists_what_was_planted_where_and_which_session_shows_it(pair, tmp_path):
    source, target = pair
    result = run_plant(source, target, tmp_path / "out", read_plan(_plan(tmp_path, PLAN)), noise=OFF)
    truth = RecordingReader(result.paths["target"]).ground_truth
    assert truth["session"] == "target"
    real, mug = truth["objects"]
    assert (real["change"], mug["change"]) == ("removed", "added")
    assert real["target"] is None and mug["source"] is None
    assert np.allclose(np.array(real["source"]["pose_world_object"])[:3, 3], [*MUG_AT, TABLE_Z], atol=0.005)
    assert np.allclose(np.array(mug["target"]["pose_world_object"])[:3, 3], [0.45, -0.25, TABLE_Z], atol=0.005)
    assert truth["visible"] == {"source": [1], "target": [2]}
    assert RecordingReader(result.paths["source"]).ground_truth["objects"] == truth["objects"]


def test_an_empty_plan_copies_the_recordings(pair, tmp_path):
    source, target = pair
    result = run_plant(source, target, tmp_path / "out", [], noise=OFF)
    assert result.edited == {"source": 0, "target": 0}
    for original, path in ((source, result.paths["source"]), (target, result.paths["target"])):
        for a, b in zip(RecordingReader(original).frames(), RecordingReader(path).frames(), strict=True):
            assert np.array_equal(a.depth, b.depth) and np.array_equal(a.rgb, b.rgb)


def test_a_mesh_behind_a_real_surface_stays_hidden():
    pose = look_at(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 1.0]))
    wall = SceneRenderer([RenderObject(box_mesh((0.1, 20.0, 20.0), (1.55, 0.0, 0.0)))]).render(CAMERA, pose)
    box = RenderObject(box_mesh((0.2, 0.2, 0.2), (1.0, 0.0, 1.0)), 5, (1.0, 0.0, 0.0))
    _, depth, shown = MeshInserter([box], OFF).insert(wall.rgb, wall.depth, CAMERA, pose, np.random.default_rng(0))
    assert (shown == 5).sum() > 100 and np.allclose(depth[shown == 5], 0.9, atol=1e-3)
    hidden = RenderObject(box_mesh((0.2, 0.2, 0.2), (2.5, 0.0, 1.0)), 6, (1.0, 0.0, 0.0))
    rgb, depth, shown = MeshInserter([hidden], OFF).insert(wall.rgb, wall.depth, CAMERA, pose, np.random.default_rng(0))
    assert not shown.any() and np.array_equal(depth, wall.depth) and np.array_equal(rgb, wall.rgb)


def test_removing_where_nothing_stands_changes_nothing(pair):
    frame = next(RecordingReader(pair[0]).frames())
    empty = Cylinder(PLANE.foot(np.array([-0.6, -0.4])), 0.08, 0.2, PLANE)
    rgb, depth, hole = remove_object(frame.rgb, frame.depth, CAMERA, frame.pose_world_camera, empty, OFF,
                                     np.random.default_rng(0))
    assert not hole.any() and np.array_equal(depth, frame.depth)


@pytest.mark.parametrize("text, problem", [
    ("[[object]]\nreal = true\nat = [0, 0]\nchange = 'moved'\n", "change must be one of removed, unchanged"),
    ("[[object]]\nmesh = 'mug:1'\nat = [0, 0]\nchange = 'moved'\n", "needs 'to'"),
    ("[[object]]\nmesh = 'mug:1'\nat = [0]\n", "at must be [x, y]"),
    ("[[object]]\nmesh = 'mug:1'\nat = [0, 0]\nsize = 3\n", "unknown key(s) size"),
    ("[[object]\n", "not valid TOML"),
])
def test_a_bad_plan_fails_naming_the_entry(tmp_path, text, problem):
    with pytest.raises(OptionError, match="--plan .*" + problem.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        read_plan(_plan(tmp_path, text))


def test_cli_refuses_a_bad_plan_in_one_line_and_writes_nothing(pair, tmp_path):
    plan = _plan(tmp_path, "[[object]]\nmesh = 'mug:1'\nat = [0, 0]\nchange = 'sideways'\n")
    run = subprocess.run([sys.executable, "-m", "ndfa.cli", "plant", str(pair[0]), str(pair[1]), "--out",
                          str(tmp_path / "out"), "--plan", str(plan)], capture_output=True, text=True)
    assert run.returncode == 2
    assert run.stderr.strip().count("\n") == 0 and "change must be one of" in run.stderr
    assert not (tmp_path / "out").exists()


def test_a_plan_off_every_support_fails_naming_the_object(pair, tmp_path):
    plan = _plan(tmp_path, "[[object]]\nname = 'far'\nmesh = 'mug:1'\nat = [30.0, 30.0]\nchange = 'added'\n")
    with pytest.raises(OptionError, match="far: no support surface found at"):
        run_plant(pair[0], pair[1], tmp_path / "out", read_plan(plan), noise=OFF)
    assert not (tmp_path / "out").exists()


def test_auto_places_a_moved_and_an_added_mug_on_free_table_apart_from_the_real_one(pair, tmp_path):
    real = [PlantedObject("real mug", "unchanged", True, MUG_AT, MUG_AT)]
    first = run_plant(*pair, tmp_path / "a", real, auto_seed=3, noise=OFF).objects
    assert [o.change for o in first] == ["removed", "moved", "added"]
    moved, added = first[1], first[2]
    assert np.linalg.norm(moved.source_xy - moved.target_xy) >= 0.5
    for xy in (moved.source_xy, moved.target_xy, added.target_xy):
        assert abs(xy[0]) <= 0.8 - 0.12 and abs(xy[1]) <= 0.6 - 0.12  # on the table, its footprint too
        assert np.linalg.norm(xy - MUG_AT) >= 0.25
    again = run_plant(*pair, tmp_path / "b", real, auto_seed=3, noise=OFF).objects
    assert all(a.describe() == b.describe() for a, b in zip(first, again))


def test_colour_camera_sees_a_depth_pixel_where_its_intrinsics_and_offset_put_its_point():
    depth_K = np.array([[585.0, 0, 320], [0, 585, 240], [0, 0, 1]])
    color_K = np.array([[525.0, 0, 321], [0, 525, 240], [0, 0, 1]])
    mask, depth = np.zeros((480, 640), dtype=bool), np.zeros((480, 640), dtype=np.float32)
    mask[240, 320 + 117], depth[240, 320 + 117] = True, 2.0  # 0.2 rad right of the depth camera's axis, 2 m
    values = np.zeros((480, 640, 3), dtype=np.uint8)
    values[240, 320 + 117] = 7
    seen, carried = ColorGrid(depth_K, color_K, -0.025).splat(mask, depth, values)
    rows, cols = np.nonzero(seen)
    assert list(rows) == [240] and list(cols) == [round(321 + 525 * (0.2 - 0.025 / 2.0))]
    assert (carried[seen] == 7).all()
    same, _ = ColorGrid(depth_K, depth_K).splat(mask, depth)
    assert np.array_equal(same, mask)


def test_auto_without_a_plan_finds_the_real_mug_and_removes_it(pair, tmp_path):
    result = run_plant(*pair, tmp_path / "out", [], auto_seed=1, noise=OFF)
    real = [o for o in result.objects if o.real]
    assert len(real) == 1 and real[0].change == "removed"
    assert np.linalg.norm(real[0].source_xy - MUG_AT) < 0.03


def test_the_kitchen_plans_of_the_docs_read():
    docs = Path(__file__).resolve().parents[1] / "docs"
    assert [(o.name, o.change) for o in read_plan(docs / "plant_kitchen.toml")] == [
        ("white mug", "removed"), ("patterned mug", "unchanged"), ("moved mug", "moved"), ("added mug", "added")]
    assert {o.change for o in read_plan(docs / "plant_kitchen_same.toml")} == {"unchanged"}
