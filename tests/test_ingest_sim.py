"""`ndfa ingest sim` end to end: render, write, read back, and check against the scene."""

import dataclasses
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from ndfa.core.errors import IngestError
from ndfa.core.geometry import transform_points
from ndfa.io.ingest.synthetic import ingest_sim, render_objects
from ndfa.io.recording import RecordingReader
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.noise import DepthNoise
from ndfa.sim.presets import make_config
from ndfa.sim.world import build_world, procedural_models


def small_config(**overrides):
    config = make_config("sample", 3, depth_noise=DepthNoise.off(), camera=PinholeCamera().scaled(0.25))
    return dataclasses.replace(config, trajectory=dataclasses.replace(config.trajectory, step_m=0.6), **overrides)


@pytest.fixture(scope="module")
def noiseless(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    config = small_config()
    summaries = ingest_sim(config, out)
    return config, out, summaries


def scene_distance(world, session):
    scene = o3d.t.geometry.RaycastingScene()
    for obj in render_objects(world, session):
        scene.add_triangles(obj.mesh.to_open3d_tensor())
    return lambda points: scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def test_recordings_carry_frames_and_ground_truth(noiseless):
    config, out, summaries = noiseless
    assert [s.session for s in summaries] == ["source", "target"]
    for summary in summaries:
        reader = RecordingReader(summary.path)
        assert len(reader) == summary.frames > 5
        assert reader.meta["session"] == summary.session and reader.has_instances
        truth = reader.ground_truth
        assert truth["session"] == summary.session
        assert truth["changes"]["total"] == sum(config.changes.values())
        assert len(truth["tables"]) == config.table_rows * config.table_cols
    assert not list(out.glob(".*tmp*"))


@pytest.mark.parametrize("session", ["source", "target"])
def test_depth_reprojects_onto_the_scene_meshes(noiseless, session):
    config, out, _ = noiseless
    world = build_world(config, procedural_models(config))
    distance = scene_distance(world, session)
    reader = RecordingReader(out / f"{session}.mcap")
    camera = config.camera
    mug_points = 0
    for frame in reader.frames():
        true_pose = frame.pose_world_camera if session == "source" else frame.pose_world_camera_true
        assert true_pose is not None
        points, pixels = camera.backproject(frame.depth)
        world_points = transform_points(true_pose, points)
        assert np.median(distance(world_points)) < 0.002
        # Pixels labelled with an instance land on that instance's mug.
        ids = frame.instances[pixels[:, 0], pixels[:, 1]]
        for instance_id in np.unique(ids[ids > 0]):
            placement = world.layout(session)[int(instance_id)]
            mug = world.mugs[placement.model_id]
            local = transform_points(np.linalg.inv(world.object_pose(placement)), world_points[ids == instance_id])
            mug_scene = o3d.t.geometry.RaycastingScene()
            mug_scene.add_triangles(mug.mesh.to_open3d_tensor())
            assert np.median(mug_scene.compute_distance(o3d.core.Tensor(local.astype(np.float32))).numpy()) < 0.002
            mug_points += len(local)
    assert mug_points > 100


def test_target_poses_are_offset_from_the_truth(noiseless):
    _, out, _ = noiseless
    reader = RecordingReader(out / "target.mcap")
    offset = np.array(reader.ground_truth["pose_offset"])
    assert not np.allclose(offset, np.eye(4))
    for frame in reader.frames():
        assert np.allclose(frame.pose_world_camera, offset @ frame.pose_world_camera_true, atol=1e-9)
    source = RecordingReader(out / "source.mcap")
    assert source.ground_truth["pose_offset"] is None
    assert all(f.pose_world_camera_true is None for f in source.frames())


def test_a_failure_mid_render_leaves_no_recording(tmp_path):
    def fail_after_three(session, done, total):
        if session == "target" and done == 3:
            raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        ingest_sim(small_config(), tmp_path, on_progress=fail_after_three)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["source.mcap"]


def test_unwritable_output_is_refused_before_rendering(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(IngestError, match="cannot write to output directory"):
        ingest_sim(small_config(), blocker / "out")


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "ndfa.cli", *args], capture_output=True, text=True, timeout=300)


def one_line_error(result, *fragments):
    assert result.returncode != 0
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


@pytest.mark.slow
def test_cli_bad_input_gives_one_line_errors(tmp_path):
    one_line_error(run_cli("ingest", "sim", "--preset", "kitchen", "--out", str(tmp_path / "a")), "unknown preset", "kitchen")

    blocker = tmp_path / "file"
    blocker.write_text("x")
    one_line_error(run_cli("ingest", "sim", "--preset", "sample", "--out", str(blocker / "out")), str(blocker / "out"))

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    (meshes / "empty.ply").write_text("")
    out = tmp_path / "m"
    one_line_error(run_cli("ingest", "sim", "--preset", "sample", "--mesh-dir", str(meshes), "--out", str(out)), "empty.ply")
    assert not list(out.glob("*.mcap"))

    one_line_error(run_cli("ingest", "sim", "--preset", "sample", "--mesh-dir", str(tmp_path / "nowhere"), "--out", str(out)), "nowhere")

    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("hello")
    one_line_error(run_cli("info", str(not_mcap)), "notes.mcap")
    one_line_error(run_cli("info", str(tmp_path / "missing.mcap")), "missing.mcap")


@pytest.mark.slow
def test_cli_info_on_a_truncated_recording(noiseless, tmp_path):
    _, out, _ = noiseless
    data = (out / "source.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    one_line_error(run_cli("info", str(cut)), "cut.mcap")
    ok = run_cli("info", str(out / "source.mcap"))
    assert ok.returncode == 0 and "source" in ok.stdout


def test_user_meshes_are_placed_and_open_ones_only_warn(tmp_path):
    from ndfa.sim.mesh_io import load_mug_dir
    from ndfa.sim.mug import make_mug

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    for seed, suffix in zip((11, 12, 13), (".ply", ".obj", ".stl")):
        mesh = make_mug(seed).mesh.to_open3d()
        mesh.scale(1000.0, center=(0, 0, 0))  # millimetres, as CAD files often are
        mesh.compute_triangle_normals()
        assert o3d.io.write_triangle_mesh(str(meshes / f"mug{seed}{suffix}"), mesh)
    open_mesh = make_mug(14).parts[0].to_open3d()
    open_mesh.triangles = o3d.utility.Vector3iVector(np.asarray(open_mesh.triangles)[:-40])
    o3d.io.write_triangle_mesh(str(meshes / "open.ply"), open_mesh)

    with pytest.warns(UserWarning, match="open.ply"):
        models = load_mug_dir(meshes)
    assert [m.watertight for m in models] == [True, True, True, False]
    for model in models:
        lo, hi = model.mesh.bounds
        assert lo[2] == pytest.approx(0.0, abs=1e-9) and 0.06 <= hi[2] <= 0.13

    summaries = ingest_sim(small_config(), tmp_path / "out", models=models)
    truth = RecordingReader(summaries[0].path).ground_truth
    used = {o["model_id"] for o in truth["objects"]}
    assert used <= {m.model_id for m in models} and "file:open" in {m["model_id"] for m in truth["models"]}


def test_bench_reports_every_stage():
    from ndfa.eval.bench import bench_sim

    result = bench_sim(frames=3)
    assert result["frames"] == 3 and result["triangles"] > 100_000
    for stage in ("world", "render", "noise", "write", "read"):
        assert result[f"{stage}_ms"] > 0


@pytest.mark.slow
def test_a_bad_option_value_is_one_line_not_a_traceback(tmp_path):
    done = subprocess.run([sys.executable, "-c", "from ndfa.cli import main; main()", "ingest", "sim",
                           "--tables", "foo", "--out", str(tmp_path / "x")], capture_output=True, text=True)
    assert done.returncode == 2
    assert "--tables must be ROWSxCOLS" in done.stderr and "Traceback" not in done.stderr
