"""The objects' gate's outline rule (`ndfa.perception.segmentation._outline`, `_hanging`, `Outline`):
a standing object is seen free, a piece of something larger goes on past its segment. On frames
ray-cast here from a few boxes and upright cylinders (a table, the floor, a back wall), and on
constructed segments of a depth image."""

import dataclasses

import numpy as np
import pytest

from ndfa.core.frame import Frame
from ndfa.core.geometry import make_pose
from ndfa.perception.planes import Plane
from ndfa.perception.segmentation import Outline, _fragments, _outline, explain_frame
from ndfa.perception.segmentation_config import SegmentationConfig

K = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
TABLE_TOP = 0.75
TABLE = ((-0.6, 0.5, TABLE_TOP - 0.03), (0.6, 1.3, TABLE_TOP))  # a 1.2 x 0.8 m top, 3 cm thick
FLOOR = ((-3.0, -3.0, -0.1), (3.0, 3.0, 0.0))
WALL = ((-3.0, 2.4, 0.0), (3.0, 2.5, 2.5))


def _camera(pitch_deg: float, position: tuple[float, float, float]) -> np.ndarray:
    """Camera-to-world pose looking along world +y, tilted down by `pitch_deg` (world z up)."""
    pitch = np.radians(pitch_deg)
    forward = np.array([0.0, np.cos(pitch), -np.sin(pitch)])
    right = np.array([1.0, 0.0, 0.0])
    down = np.cross(forward, right)
    return make_pose(np.column_stack([right, down, forward]), np.array(position))


def _render(boxes: list, cylinders: list, pose: np.ndarray) -> Frame:
    """A 640 x 480 frame of axis-aligned boxes ((min xyz), (max xyz)) and upright cylinders
    (x, y, radius, bottom z, top z), depth along the optical axis."""
    rows, cols = np.mgrid[0:480, 0:640]
    rays_camera = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(rows.shape)], -1).reshape(-1, 3)
    directions = rays_camera @ pose[:3, :3].T
    origin = pose[:3, 3]
    t = np.full(len(directions), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for low, high in boxes:
            t_low, t_high = (np.asarray(low) - origin) / directions, (np.asarray(high) - origin) / directions
            near = np.minimum(t_low, t_high).max(axis=1)
            far = np.maximum(t_low, t_high).min(axis=1)
            hit = (near <= far) & (near > 0)
            t = np.where(hit, np.minimum(t, near), t)
        for x, y, radius, bottom, top in cylinders:
            o = origin[:2] - (x, y)
            d = directions[:, :2]
            a, b, c = (d * d).sum(1), 2 * (d * o).sum(1), o @ o - radius**2
            side = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
            z = origin[2] + side * directions[:, 2]
            t = np.where((side > 0) & (z >= bottom) & (z <= top), np.minimum(t, side), t)
            cap = (top - origin[2]) / directions[:, 2]
            on_cap = np.linalg.norm(origin[:2] + cap[:, None] * d - (x, y), axis=1) <= radius
            t = np.where((cap > 0) & on_cap, np.minimum(t, cap), t)
    depth = np.where(np.isfinite(t), t * rays_camera[:, 2], 0.0).reshape(480, 640).astype(np.float32)
    return Frame(index=0, timestamp=0.0, rgb=None, depth=depth, K=K, pose_world_camera=pose)


def _kept_near(frame: Frame, config: SegmentationConfig, xy: tuple[float, float]):
    """The verdicts of the clusters whose pixels' mean lies within 5 cm of `xy` (world)."""
    from ndfa.perception.segmentation import _world_points

    labels, verdicts = explain_frame(frame, config)
    near = []
    for verdict in verdicts:
        if verdict.label:
            rows, cols = np.nonzero(labels == verdict.label)
            if np.linalg.norm(_world_points(frame, rows, cols).mean(axis=0)[:2] - xy) < 0.05:
                near.append(verdict)
    return near, verdicts


POSE = _camera(35.0, (0.0, -0.2, 1.35))
OBJECTS = SegmentationConfig().for_objects()


@pytest.mark.parametrize("name, cylinder", [
    ("bowl", (-0.25, 0.9, 0.08, TABLE_TOP, TABLE_TOP + 0.06)),
    ("bottle", (0.0, 1.0, 0.035, TABLE_TOP, TABLE_TOP + 0.26)),
    ("mug", (0.25, 0.8, 0.045, TABLE_TOP, TABLE_TOP + 0.10)),
])
def test_an_object_standing_free_on_a_table_is_kept(name, cylinder):
    frame = _render([TABLE, FLOOR, WALL], [cylinder], POSE)
    near, _ = _kept_near(frame, OBJECTS, cylinder[:2])
    assert len(near) == 1, name
    assert near[0].outline is not None and near[0].outline.goes_on() <= OBJECTS.max_outline_goes_on
    assert near[0].outline.hanging == 0.0  # the table hides what is under its base


def test_a_chairs_back_at_the_tables_edge_goes_on_below_the_support_and_is_turned_away():
    """The kitchen's chair: the top rail of its back, 10 cm above the table top just in front of the
    table's edge, looks like a small box standing on the table; the back goes on down below it."""
    back = ((-0.05, 0.45, 0.35), (0.05, 0.48, TABLE_TOP + 0.10))
    frame = _render([TABLE, FLOOR, WALL, back], [], POSE)
    without = dataclasses.replace(OBJECTS, max_outline_goes_on=None)
    assert len(_kept_near(frame, without, (0.0, 0.465))[0]) == 1  # the gate's shape tests keep it
    near, verdicts = _kept_near(frame, OBJECTS, (0.0, 0.465))
    assert near == []
    turned_away = [v for v in verdicts if v.rejected == "attached"]
    assert len(turned_away) == 1 and turned_away[0].outline.hanging == 1.0


def _wall_patch(wall_cols: tuple[int, int], wall_depth: float, behind_depth: float
                ) -> tuple[Frame, np.ndarray, np.ndarray, Plane]:
    """A horizontal camera 0.5 m above a support plane, facing a wall (`wall_depth`) that covers the
    columns `wall_cols` of rows 100-300, the room behind it at `behind_depth`; a segment of rows
    200-260, columns 300-340 at the wall's depth (every 2nd pixel), standing on the plane."""
    pose = _camera(0.0, (0.0, 0.0, 0.5))
    depth = np.full((480, 640), behind_depth, dtype=np.float32)
    depth[100:300, wall_cols[0]:wall_cols[1]] = wall_depth
    depth[200:260, 300:340] = wall_depth
    frame = Frame(index=0, timestamp=0.0, rgb=None, depth=depth, K=K, pose_world_camera=pose)
    rows, cols = np.mgrid[200:260:2, 300:340:2]
    return frame, rows.ravel(), cols.ravel(), Plane(np.array([0.0, 0.0, 1.0]), 0.0, np.zeros(0, dtype=bool))


def _measure(frame, rows, cols, plane, hanging=0.0) -> Outline:
    none = _fragments(frame.depth.shape, rows, cols, np.full(len(rows), 0), 2, OBJECTS)
    return _outline(frame, rows, cols, plane, 2, none, OBJECTS, hanging)


def test_a_strip_of_a_wall_goes_on_at_both_sides_and_is_turned_away():
    outline = _measure(*_wall_patch((0, 640), 2.0, 4.0))
    assert outline.left == outline.right == outline.top == 1.0
    assert outline.goes_on() > OBJECTS.max_outline_goes_on


def test_an_object_against_a_wall_seen_at_its_edge_goes_on_at_one_side_only_and_is_kept():
    """A surface at the segment's depth goes on at its left only (an object against the end of a
    wall, or a box's face meeting a wall at the corner): the room lies behind it above and on the
    right; one side going on is no strip of a wall."""
    outline = _measure(*_wall_patch((0, 300), 2.0, 4.0))
    assert outline.left == 1.0 and outline.right == 0.0 and outline.top == 0.0
    assert outline.goes_on() <= OBJECTS.max_outline_goes_on


def test_a_segment_seen_free_against_the_room_is_kept():
    outline = _measure(*_wall_patch((0, 0), 2.0, 4.0))
    assert outline.left == outline.right == outline.top == 0.0
    assert outline.goes_on() == 0.0


def test_a_nearer_occluder_beside_a_segment_says_nothing():
    frame, rows, cols, plane = _wall_patch((0, 0), 2.0, 4.0)
    frame.depth[150:300, 280:300] = 1.0  # a nearer post hides the left side
    outline = _measure(frame, rows, cols, plane)
    assert outline.left is None and outline.right == 0.0


def test_the_goes_on_share_takes_the_top_the_smaller_side_and_the_hanging_share():
    assert Outline(top=1.0, left=0.0, right=0.0, hanging=0.0).goes_on() == 1.0   # a chair's slanted leg
    assert Outline(top=0.0, left=1.0, right=0.2, hanging=0.0).goes_on() == 0.2   # against a wall
    assert Outline(top=None, left=1.0, right=None, hanging=None).goes_on() == 0.0  # nothing measured
    assert Outline(top=0.0, left=0.0, right=0.0, hanging=0.9).goes_on() == 0.9   # a chair's back


def test_the_mugs_gate_measures_no_outline():
    frame = _render([TABLE, FLOOR, WALL], [(0.25, 0.8, 0.045, TABLE_TOP, TABLE_TOP + 0.10)], POSE)
    assert SegmentationConfig().max_outline_goes_on is None
    near, _ = _kept_near(frame, SegmentationConfig(), (0.25, 0.8))
    assert len(near) == 1 and near[0].outline is None


def test_a_slanted_leg_goes_on_above_its_segment_and_is_turned_away():
    """A chair's slanted leg on the floor: the column test misses it (what is above lies farther
    than `column_radius_m` sideways), but its segment's top edge goes on into the leg."""
    frame, rows, cols, plane = _wall_patch((0, 0), 2.0, 4.0)
    frame.depth[150:200, 300:340] = 2.0
    outline = _measure(frame, rows, cols, plane)
    assert outline.top == 1.0 and outline.left == outline.right == 0.0
    assert outline.goes_on() > OBJECTS.max_outline_goes_on


def test_an_objects_own_fringe_left_out_of_its_cluster_is_no_surface_going_on():
    """The rim of a far mug, left by DBSCAN as noise just above its cluster (as deep as the look),
    is no surface going on: it says nothing."""
    frame, rows, cols, plane = _wall_patch((0, 0), 2.0, 4.0)
    frame.depth[194:200, 300:340] = 2.0  # three sample rows of rim at the object's depth
    rim_rows, rim_cols = (a.ravel() for a in np.mgrid[194:200:2, 300:340:2])
    all_rows, all_cols = np.concatenate([rows, rim_rows]), np.concatenate([cols, rim_cols])
    clusters = np.concatenate([np.zeros(len(rows), dtype=np.int64), np.full(len(rim_rows), -1)])
    fragments = _fragments(frame.depth.shape, all_rows, all_cols, clusters, 2, OBJECTS)
    assert _outline(frame, rows, cols, plane, 2, fragments, OBJECTS, 0.0).top is None
    assert _measure(frame, rows, cols, plane).top == 1.0  # taken for a surface, it would go on
