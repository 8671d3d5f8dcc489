"""Stacked surfaces (issue 33, item 4): the height tree T_z, the detector on mugs stacked on
shelves, and the `shelves` preset's units, changes and camera routes."""

import dataclasses

import numpy as np
import pytest

from ndfa.change.associate import Measurement, SessionMap
from ndfa.change.config import DetectorConfig, LevelsConfig, RegistrationConfig
from ndfa.change.describe import tree_event
from ndfa.change.detector import ChangeDetector
from ndfa.change.register import apply
from ndfa.change.tree import ObjectTree
from ndfa.core.conventions import is_visible
from ndfa.core.errors import SimError
from ndfa.core.geometry import make_pose, rotation_z
from ndfa.io.ingest.synthetic import render_objects
from ndfa.log.table_sink import TableSink
from ndfa.perception.segmentation_config import SegmentationConfig
from ndfa.sim.presets import make_config
from ndfa.sim.render import SceneRenderer
from ndfa.sim.shelves import shelf_camera_poses
from ndfa.sim.world import build_world, procedural_models

# -- the tree ------------------------------------------------------------------------------------


def test_objects_on_shelves_above_one_another_are_neighbours_only_in_the_paper_tree():
    below, above, beside = np.array([0.1, 0.2, 0.35]), np.array([0.12, 0.18, 0.65]), np.array([0.4, 0.1, 0.36])
    paper, levels = ObjectTree(1.2), ObjectTree(1.2, height=0.2)
    for tree in (paper, levels):
        for i, c in enumerate((below, above, beside)):
            tree.insert(i, c)
    assert paper.neighbourhood(below) == {0, 1, 2}
    assert levels.neighbourhood(below) == {0, 2} and levels.neighbourhood(above) == {1}
    assert len(levels.cell(0)) == 3 and len(paper.cell(0)) == 2
    assert levels.region(above).contains(np.array([below, above, beside])).tolist() == [False, True, False]
    # A margin reaches the slab below as far as it goes and no farther.
    assert levels.neighbourhood(np.array([0.1, 0.2, 0.56]), margin=0.02) == {1}
    assert levels.neighbourhood(np.array([0.1, 0.2, 0.56]), margin=0.12) == {0, 1, 2}


def test_height_tree_queries_with_a_margin_match_brute_force():
    rng = np.random.default_rng(3)
    centers = rng.uniform(-3, 3, size=(2_000, 3))
    tree = ObjectTree(1.2, height=0.2)
    for i, c in enumerate(centers):
        tree.insert(i, c)
    axes = (tree.x, tree.y, tree.z)
    for q in rng.uniform(-3, 3, size=(100, 3)):
        near = [{id(n) for n in axis.nodes if n.low <= q[k] + 0.05 and n.high >= q[k] - 0.05} for k, axis in enumerate(axes)]
        expected = {i for i in range(len(centers)) if all(id(node) in near[k] for k, node in enumerate(tree.cell(i)))}
        assert tree.neighbourhood(q, margin=0.05) == expected


def test_a_levels_config_needs_a_positive_height_and_paper_has_none():
    with pytest.raises(ValueError, match="positive"):
        LevelsConfig(tree_height_m=0.0)
    assert DetectorConfig.paper().levels.tree_height_m is None
    assert DetectorConfig().without("levels") == dataclasses.replace(DetectorConfig(), levels=LevelsConfig(None))


def test_the_tree_event_and_the_tables_carry_the_height_tree(tmp_path):
    session = SessionMap(DetectorConfig())
    for frame, center in enumerate(([0.1, 0.2, 0.35], [0.12, 0.18, 0.65], [0.4, 0.1, 0.36])):
        session.update(Measurement(frame, frame + 1, np.random.default_rng(frame).normal(size=16), np.array(center), 0.9))
    event = tree_event("source", 2, session)
    assert [tuple(objects) for objects in event.z_objects] == [(0, 2), (1,)]
    assert np.all(event.z_intervals[:, 1] - event.z_intervals[:, 0] <= 0.2 + 1e-12)
    assert tree_event("source", 2, SessionMap(DetectorConfig().without("levels"))).z_intervals.shape == (0, 2)
    sink = TableSink(tmp_path)
    sink.log(event)
    nodes = sink.tables()["tree_nodes"]
    assert sorted(nodes.filter(nodes["axis"] == "z")["objects"].to_list()) == [[0, 2], [1]]


# -- the detector on stacked mugs -----------------------------------------------------------------

LEVELS_Z = (0.35, 0.65, 0.95)  # mug centers on three shelves 30 cm apart


def _shelf(stacked_xy):
    """Four mugs on each level; the first two of each level stand straight above those below (within 1 cm)."""
    mugs, rng = {}, np.random.default_rng(9)
    for level, z in enumerate(LEVELS_Z):
        spots = [*stacked_xy, (0.12 + 0.1 * level, 0.08), (0.3 - 0.05 * level, -0.1)]
        for k, (x, y) in enumerate(spots):
            mugs[4 * level + k + 1] = np.r_[x + rng.uniform(-0.01, 0.01), y + rng.uniform(-0.01, 0.01), z]
    return mugs


def _run(config: DetectorConfig, source: dict, target: dict, seed: int = 5):
    rng = np.random.default_rng(seed)
    codes = {i: np.random.default_rng(200 + i).normal(size=16) for i in range(1, 40)}
    offset = make_pose(rotation_z(0.7), np.array([0.4, -0.3, 0.02]))
    detector = ChangeDetector(dataclasses.replace(config, registration=RegistrationConfig(pairs=4)))

    def frames(layout, pose, frame0):
        for view in range(10):  # every mug in every frame, as a pass along a shelf sees them
            yield [Measurement(frame0 + view, i, codes[i] + rng.normal(scale=0.02, size=16),
                               apply(pose, (c + rng.normal(scale=0.004, size=3))[None])[0], float(rng.uniform(0.5, 1)))
                   for i, c in layout.items()]

    for frame in frames(source, np.eye(4), 0):
        detector.add_source(frame)
    events = []
    for frame in frames(target, offset, 20):
        events += detector.add_target(frame)
    events += detector.finish()
    reported: dict[str, set[int]] = {}
    for e in events:
        if getattr(e, "kind", "unchanged") != "unchanged":
            reported.setdefault(e.kind, set()).update(e.instance_ids[:1])
    return detector, reported


def test_a_change_on_one_shelf_is_found_and_mugs_stacked_above_one_another_stay_apart():
    source = _shelf([(-0.3, 0.0), (-0.1, 0.05)])
    target = dict(source)
    target.pop(6)                                  # removed from the middle shelf, stacked between 2 and 10
    target[30] = np.r_[0.45, 0.1, LEVELS_Z[2]]     # added on the top shelf
    detector, reported = _run(DetectorConfig(), source, target)
    assert len(detector.source) == 12 and len(detector.target) == 12
    assert reported == {"removed": {6}, "added": {30}}
    # The paper's column-shaped cells make the stacked mugs one place: each stack of three becomes one
    # object (`ViewsConfig.same_place_m` is horizontal), and the removal under the mugs above is lost.
    flat, reported_flat = _run(DetectorConfig().without("levels"), source, target)
    assert len(flat.source) == 8
    assert 6 not in reported_flat.get("removed", set())


# -- the preset --------------------------------------------------------------------------------------


def test_shelves_have_three_or_four_levels_25_to_35_cm_apart_with_a_change_on_every_level():
    for seed in (1, 2, 3):
        config = make_config("shelves", seed)
        world = build_world(config, procedural_models(config))
        assert 2 <= len(world.shelf_units) <= 3
        for unit in world.shelf_units:
            assert 3 <= len(unit.level_heights) <= 4
            gaps = np.diff([*unit.level_heights, unit.height])
            assert np.all((gaps >= 0.25) & (gaps <= 0.35))
        levels = {t.table_id: t.level for t in world.tables}
        ends = [layout[c.instance_id] for c in world.changes for layout in (world.source, world.target)
                if c.instance_id in layout]  # a change leaves a level, reaches one, or both
        assert {levels[p.table_id] for p in ends} == set(levels.values())
        for placement in world.source.values():  # each mug stands on its board, under the next one
            table = world.table(placement.table_id)
            mesh = world.mugs[placement.model_id].mesh.transformed(world.object_pose(placement))
            assert mesh.vertices[:, 2].min() == pytest.approx(table.height)
            assert mesh.vertices[:, 2].max() < table.height + 0.23


def test_shelf_routes_only_with_shelves():
    with pytest.raises(SimError, match="shelves"):
        make_config("shelves", 1, target_route="corridor")
    with pytest.raises(SimError, match="tables"):
        make_config("random", 1, target_route="back")
    with pytest.raises(SimError, match="distinct names"):
        make_config("shelves", 1, categories=("plate",))


def test_each_route_sees_every_mug_on_every_level_past_the_boards():
    """Rendered at an eighth of the resolution and a step of 25 cm: the boards above and below a
    level hide none of its mugs from both sessions' routes."""
    config = make_config("shelves", 2)
    world = build_world(config, procedural_models(config))
    camera = config.camera.scaled(0.25)
    trajectory = dataclasses.replace(config.trajectory, step_m=0.25)
    for session, route in (("source", config.source_route), ("target", config.target_route)):
        renderer = SceneRenderer(render_objects(world, session))
        seen: dict[int, int] = {}
        for pose in shelf_camera_poses(world.shelf_units, route, trajectory, np.random.default_rng(0)):
            ids, counts = np.unique(renderer.render(camera, pose).instance, return_counts=True)
            for i, n in zip(ids.tolist(), counts.tolist()):
                seen[i] = max(seen.get(i, 0), n * 16)  # pixels at full resolution, roughly
        assert {i for i, n in seen.items() if i and is_visible(n)} == set(world.layout(session))


# -- segmentation without masks on a shelf (`ndfa.perception.planes`, `segmentation`) -------------

LOWER_BOARD = ((-0.45, 0.8, 0.18), (0.45, 1.15, 0.20))   # 20 cm above the floor, 2 cm thick
UPPER_BOARD = ((-0.45, 0.8, 0.48), (0.45, 1.15, 0.50))   # the next one, 30 cm higher
SIDE_PANELS = [((-0.47, 0.8, 0.0), (-0.45, 1.15, 0.8)), ((0.45, 0.8, 0.0), (0.47, 1.15, 0.8))]
SHELF_MUGS = [(-0.2, 0.95, 0.04, 0.20, 0.30), (0.0, 1.0, 0.04, 0.20, 0.31), (0.22, 0.93, 0.04, 0.20, 0.29)]


@pytest.mark.parametrize("pitch_deg, height_m", [(10.0, 0.42), (25.0, 0.55), (35.0, 0.9)])
@pytest.mark.parametrize("objects", [False, True])
def test_mugs_on_a_shelfs_lowest_board_are_segmented_under_the_next_board(pitch_deg, height_m, objects):
    """A shelf unit's lowest board 20 cm above the floor, the next 30 cm higher, three mugs on the
    lower one, seen from just above it (as `--preset shelves` walks), from higher, and from above.
    The board lies within `band_height_m` of the floor, whose band held every level there, so its
    mugs stood 20 cm above their plane ("floating"); and the next board overhangs them, so they
    stood in a tall column. The board is a support of its own (`ndfa.perception.planes._surfaces`)
    and the board above hangs over space the camera sees through (`_overhanging`): one segment per mug."""
    from test_outline import FLOOR, WALL, _camera, _kept_near, _render

    frame = _render([FLOOR, WALL, LOWER_BOARD, UPPER_BOARD, *SIDE_PANELS], SHELF_MUGS, _camera(pitch_deg, (0.0, 0.1, height_m)))
    config = SegmentationConfig().for_objects() if objects else SegmentationConfig()
    assert [len(_kept_near(frame, config, mug[:2])[0]) for mug in SHELF_MUGS] == [1, 1, 1]
