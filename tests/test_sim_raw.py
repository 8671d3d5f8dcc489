"""The synthetic world closer to raw sensor data: textures, clutter, raw recordings, tilted worlds."""

import dataclasses

import numpy as np
import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.errors import RecordingError, SimError
from ndfa.core.frame import Frame
from ndfa.core.geometry import invert_pose
from ndfa.io.ingest.synthetic import ingest_sim, render_objects, world_ground_truth
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.clutter import CLUTTER_FIRST_ID, CLUTTER_KINDS, NON_OBJECTS, footprint_radius, make_clutter_mesh
from ndfa.sim.noise import DepthNoise
from ndfa.sim.presets import make_config
from ndfa.sim.render import SceneRenderer
from ndfa.sim.texture import SurfaceTexture, room_textures
from ndfa.sim.trajectory import camera_poses
from ndfa.sim.world import build_world, procedural_models


def small_config(**overrides):
    config = make_config("sample", 3, depth_noise=DepthNoise.off(), camera=PinholeCamera().scaled(0.25))
    return dataclasses.replace(config, trajectory=dataclasses.replace(config.trajectory, step_m=0.6), **overrides)


def frames_of(path):
    return list(RecordingReader(path).frames())


def true_pose(frame):
    """The frame's true camera pose: its own where it is not perturbed."""
    return frame.pose_world_camera if frame.pose_world_camera_true is None else frame.pose_world_camera_true


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """The same small scene three ways: as it was, with a tilted world, and raw with everything on."""
    out = {}
    for name, overrides in {"plain": {}, "tilted": {"world_tilt_deg": 12.0},
                            "raw": {"raw": True, "textures": True, "clutter_per_table": 2, "world_tilt_deg": 12.0}}.items():
        out[name] = tmp_path_factory.mktemp(name)
        ingest_sim(small_config(**overrides), out[name])
    return out


# --- textures ----------------------------------------------------------------------------------


def test_texture_lookup_projects_along_the_face_normal_and_repeats():
    colours = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], dtype=np.float32)  # rows v, columns u
    texture = SurfaceTexture(colours, texel_m=0.5)
    up, along_y = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    points = np.array([[0.25, 0.25, 0.0], [0.75, 0.25, 3.0], [2.25, 0.25, 0.0], [0.25, 5.0, 0.75], [0.5, 0.25, 0.0]])
    normals = np.array([up, up, up, along_y, up])
    albedo = texture.albedo(points, normals)
    assert albedo[0] == pytest.approx([1, 0, 0])       # texel centre (row 0, column 0), on a face along z
    assert albedo[1] == pytest.approx([0, 1, 0])       # column 1; the height does not matter
    assert albedo[2] == pytest.approx([1, 0, 0])       # 2 m further: the image repeats
    assert albedo[3] == pytest.approx([0, 0, 1])       # a face along y shows (x, z): row 1, column 0
    assert albedo[4] == pytest.approx([0.5, 0.5, 0])   # between two texel centres: the mean
    with pytest.raises(SimError):
        SurfaceTexture(colours, pose_world_texture=np.diag([1.0, -1.0, -1.0, 1.0]))  # upside down


def test_textures_change_the_colour_image_but_not_depth_or_instances():
    config = small_config(camera=PinholeCamera().scaled(0.5))
    world = build_world(config, procedural_models(config))
    textures = room_textures(world.room, world.tables, np.random.default_rng(0))
    plain = SceneRenderer(render_objects(world, "source"))
    textured = SceneRenderer(render_objects(world, "source", textures))
    poses = camera_poses(world.tables, dataclasses.replace(config.trajectory, route="perimeter"), np.random.default_rng(0))
    for pose in poses[::8][:3]:
        a, b = plain.render(config.camera, pose), textured.render(config.camera, pose)
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.instance, b.instance)
        mugs = a.instance > 0
        assert np.array_equal(a.rgb[mugs], b.rgb[mugs])  # mugs keep their flat colour
        room = a.hit & ~mugs
        assert np.mean(np.any(a.rgb[room] != b.rgb[room], axis=-1)) > 0.9
        # Texture is detail a photometric term can use: much more change between neighbours.
        assert detail(b.rgb, room) > 3 * detail(a.rgb, room) and detail(b.rgb, room) > 0.3


def detail(rgb, mask):
    """Fraction of horizontal neighbours inside `mask` whose grey levels differ by more than 2."""
    gray = rgb.astype(float).mean(axis=-1)
    step = np.abs(np.diff(gray, axis=1))[mask[:, 1:] & mask[:, :-1]]
    return np.mean(step > 2)


# --- clutter -----------------------------------------------------------------------------------


def test_clutter_never_collides_with_mugs_and_moves_none_of_them():
    config = small_config(clutter_per_table=3)
    world = build_world(config, procedural_models(config))
    without = build_world(small_config(), procedural_models(config))
    assert world.source == without.source and world.target == without.target and world.changes == without.changes
    assert len(world.clutter) >= 2 * len(world.tables)
    assert {item.kind for item in world.clutter} <= set(CLUTTER_KINDS)
    ids = [item.instance_id for item in world.clutter]
    assert len(set(ids)) == len(ids) and min(ids) >= CLUTTER_FIRST_ID
    for item in world.clutter:
        table = world.table(item.table_id)
        half = np.array(table.size_xy) / 2
        assert np.all(np.abs(item.xy) + item.footprint_radius <= half)  # on the table
        for layout in (world.source, world.target):
            for mug in layout.values():
                if mug.table_id == item.table_id:
                    gap = np.linalg.norm(np.subtract(item.xy, mug.xy))
                    assert gap >= item.footprint_radius + np.linalg.norm(
                        world.mugs[mug.model_id].mesh.vertices[:, :2], axis=1).max()
        for other in world.clutter:
            if other is not item and other.table_id == item.table_id:
                assert np.linalg.norm(np.subtract(item.xy, other.xy)) >= item.footprint_radius + other.footprint_radius


@pytest.mark.parametrize("kind", CLUTTER_KINDS)
def test_clutter_stands_on_the_table_and_non_objects_are_closed(kind):
    """Objects are the categories' (closed parts: tests/test_categories.py); papers and cables are
    closed meshes of their own, lying flat."""
    for seed in range(3):
        mesh = make_clutter_mesh(kind, np.random.default_rng(seed))
        assert mesh.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-9)  # stands on z = 0
        assert footprint_radius(mesh) <= 0.19
        if kind in NON_OBJECTS:
            assert mesh.is_watertight() and mesh.vertices[:, 2].max() <= 0.013


def test_clutter_is_listed_as_clutter_not_as_objects(recordings):
    config = small_config(clutter_per_table=2)
    world = build_world(config, procedural_models(config))
    truth = world_ground_truth(world, config)
    plain = world_ground_truth(build_world(small_config(), procedural_models(config)), small_config())
    assert truth["objects"] == plain["objects"] and truth["changes"] == plain["changes"]
    assert "clutter" not in plain
    assert [c["instance_id"] for c in truth["clutter"]] == [item.instance_id for item in world.clutter]
    assert [c["category"] for c in truth["clutter"]] == [None if i.kind in NON_OBJECTS else i.kind for i in world.clutter]
    assert {c["instance_id"] for c in truth["clutter"]}.isdisjoint(o["instance_id"] for o in truth["objects"])
    # The raw recording carries the same list; rendered with masks the clutter is an instance.
    assert len(RecordingReader(recordings["raw"] / "source.mcap").ground_truth["clutter"]) == len(world.clutter)
    renderer = SceneRenderer(render_objects(world, "target"))
    poses = camera_poses(world.tables, dataclasses.replace(config.trajectory, route=config.target_route),
                         np.random.default_rng(0))
    seen = set().union(*(np.unique(renderer.render(config.camera, pose).instance) for pose in poses[::3]))
    assert seen & {item.instance_id for item in world.clutter}


# --- raw recordings ----------------------------------------------------------------------------


def test_raw_recording_has_no_masks_and_no_poses_but_keeps_the_truth(recordings):
    for session in ("source", "target"):
        reader = RecordingReader(recordings["raw"] / f"{session}.mcap")
        assert reader.meta["poses"] == "none" and reader.meta["instances"] == "none"
        assert not reader.has_instances and not reader.has_poses
        assert reader.ground_truth["pose_offset"] is None
        tilted = frames_of(recordings["tilted"] / f"{session}.mcap")
        raw = frames_of(recordings["raw"] / f"{session}.mcap")
        assert len(raw) == len(tilted) > 3
        for frame, reference in zip(raw, tilted):
            assert frame.instances is None
            assert np.array_equal(frame.pose_world_camera, np.eye(4))
            assert np.allclose(frame.pose_world_camera_true, true_pose(reference), atol=1e-6)


def test_cli_info_says_a_raw_recording_has_no_poses(recordings):
    result = CliRunner().invoke(app, ["info", str(recordings["raw"] / "target.mcap")])
    assert result.exit_code == 0, result.output
    rows = {cells[0]: cells[1] for line in result.output.splitlines()
            if len(cells := [c.strip() for c in line.strip("│ ").split("│")]) == 2}
    assert rows["poses"] == "none" and rows["instance masks"] == "no"


def test_a_recording_without_tf_must_say_it_has_no_poses(tmp_path):
    path = tmp_path / "lost.mcap"
    frame = Frame(0, 1.0, None, np.ones((4, 4), np.float32), np.eye(3), np.eye(4))
    with RecordingWriter(path, {"source": "test", "session": "s", "poses": "given"}) as writer:
        writer._writes_poses = False  # a recording whose /tf went missing
        writer.write_frame(frame)
    with pytest.raises(RecordingError, match="lost.mcap.*/tf has no message"):
        RecordingReader(path)


# --- tilted worlds -----------------------------------------------------------------------------


@pytest.mark.parametrize("session", ["source", "target"])
def test_world_tilt_keeps_the_trajectory_and_tilts_up_by_the_angle(recordings, session):
    plain = frames_of(recordings["plain"] / f"{session}.mcap")
    tilted = frames_of(recordings["tilted"] / f"{session}.mcap")
    truth = RecordingReader(recordings["tilted"] / f"{session}.mcap").ground_truth
    tilt = np.array(truth["world_tilt"]["pose_world_level"])
    up = np.array(truth["world_tilt"]["up_world"])
    assert np.degrees(np.arccos(up[2])) == pytest.approx(12.0)
    assert np.allclose(tilt[:3, 2], up) and np.allclose(tilt[:3, 3], 0.0)
    for a, b in zip(plain, tilted):
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.rgb, b.rgb)  # the same images
        # Each camera's optical axis makes the same angle with up, in either world.
        assert np.dot(a.pose_world_camera[:3, 2], [0, 0, 1]) == pytest.approx(np.dot(b.pose_world_camera[:3, 2], up), abs=1e-6)
        assert np.allclose(b.pose_world_camera, tilt @ a.pose_world_camera, atol=1e-6)
    for i, j in [(0, 1), (0, len(plain) - 1)]:  # relative poses: the trajectory's shape
        assert np.allclose(invert_pose(plain[i].pose_world_camera) @ plain[j].pose_world_camera,
                           invert_pose(tilted[i].pose_world_camera) @ tilted[j].pose_world_camera, atol=1e-6)
    # Objects are tilted with the cameras: each one stays where the (true) camera sees it.
    plain_truth = RecordingReader(recordings["plain"] / f"{session}.mcap").ground_truth
    camera_plain, camera_tilted = true_pose(plain[0]), true_pose(tilted[0])
    for o_plain, o_tilted in zip(plain_truth["objects"], truth["objects"]):
        if o_plain[session] is not None:
            assert np.allclose(invert_pose(camera_plain) @ np.array(o_plain[session]["pose_world_object"]),
                               invert_pose(camera_tilted) @ np.array(o_tilted[session]["pose_world_object"]), atol=1e-6)
    if truth["pose_offset"] is not None:  # the target's perturbation still maps true onto given poses
        offset = np.array(truth["pose_offset"])
        assert np.allclose(offset @ tilted[0].pose_world_camera_true, tilted[0].pose_world_camera, atol=1e-5)


def test_ground_truth_lists_the_visible_instances_a_raw_recording_has_no_masks_for(recordings, tmp_path):
    from ndfa.core.conventions import depth_in_range, is_visible

    # The same scene with masks: what `is_visible` makes of them, frame by frame.
    ingest_sim(small_config(textures=True, clutter_per_table=2, world_tilt_deg=12.0), tmp_path)
    expected = {}
    for session in ("source", "target"):
        most: dict[int, int] = {}
        for frame in frames_of(tmp_path / f"{session}.mcap"):
            ids, counts = np.unique(frame.instances[depth_in_range(frame.depth) & (frame.instances > 0)], return_counts=True)
            for i, n in zip(ids.tolist(), counts.tolist()):
                most[i] = max(n, most.get(i, 0))
        expected[session] = sorted(i for i, n in most.items() if is_visible(n))
    assert expected["source"] and expected["target"]
    raw_source = RecordingReader(recordings["raw"] / "source.mcap").ground_truth["visible"]
    raw_target = RecordingReader(recordings["raw"] / "target.mcap").ground_truth["visible"]
    masked_target = RecordingReader(tmp_path / "target.mcap").ground_truth["visible"]
    # The source is written before the target is rendered: it lists its own session only.
    assert raw_source == {"source": expected["source"]}
    assert raw_target == masked_target == expected


def test_detect_scores_a_raw_recording_by_position(recordings):
    from ndfa.eval.runs import score_detection
    from ndfa.eval.scoring import scorable_instances
    from ndfa.run.detect import RunOptions, run_detection

    raw = recordings["raw"]
    # On the true poses; up as recorded (the tiny images give too few planes to estimate it from).
    result = score_detection(run_detection(raw / "source.mcap", raw / "target.mcap",
                                           options=RunOptions(poses="truth", up="z")))
    assert result.score is not None and result.score.as_dict()["scored_by"] == "position"
    # Which mugs are scored follows the ground truth's visible lists (few at this image size).
    truth = RecordingReader(raw / "target.mcap").ground_truth
    visible = {session: set(ids) for session, ids in truth["visible"].items()}
    mugs = {o["instance_id"] for o in truth["objects"]}
    assert result.score.visibility_known
    assert set(result.score.unscored_ids) == mugs - scorable_instances(truth, visible) != set()
    assert max(result.score.alignment_rmse_m.values()) < 1e-6
    assert any(note.startswith("scored by position") for note in result.notes)


def test_a_raw_route_turns_at_most_the_limit_and_keeps_slow_turns():
    from ndfa.sim.trajectory import limit_turns

    # A gaze that pans slowly, then whips round by 180 deg through "straight down".
    headings = np.radians(np.r_[np.arange(0, 20, 2.0), np.full(12, 200.0)])
    gazes = np.c_[np.cos(headings), np.sin(headings), np.full(len(headings), -0.2)]
    gazes[10] = [0.0, 0.0, -1.0]
    limited = limit_turns(gazes, max_turn_deg=20.0)
    heading = np.degrees(np.unwrap(np.arctan2(limited[:, 1], limited[:, 0])))
    pitch = np.degrees(np.arcsin(limited[:, 2]))
    assert np.abs(np.diff(heading)).max() <= 20.0 + 1e-6 and np.abs(np.diff(pitch)).max() <= 20.0 + 1e-6
    assert (heading[-1] - 200.0) % 360.0 == pytest.approx(0.0, abs=1e-6)   # the whip is made up over a few frames
    np.testing.assert_allclose(limited[:10], gazes[:10] / np.linalg.norm(gazes[:10], axis=1, keepdims=True), atol=1e-12)
    assert np.degrees(np.arcsin(-limited[:, 2])).max() <= 30.0 + 1e-6   # never more than 30 deg down
