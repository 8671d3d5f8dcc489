"""Chairs pushed in at the tables (`ndfa.sim.chairs`): static, part of the room, their backs' top
rails beside the tables' edges, a little above the tops (docs/categories.md, "Objects in real rooms")."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.core.geometry import transform_points
from ndfa.io.ingest.synthetic import render_objects, world_ground_truth
from ndfa.sim.chairs import BACK_ABOVE_M, GAP_M, table_chairs
from ndfa.sim.presets import make_config
from ndfa.sim.scene import Table
from ndfa.sim.world import build_world, procedural_models


def test_chairs_stand_on_the_floor_beside_the_table_clear_of_its_top_legs_and_each_other():
    assert len(table_chairs([Table(1, (0.0, 0.0))], 4, np.random.default_rng(0))) == 2  # 1.2 m: one a side
    table = Table(1, (0.5, -0.3), size_xy=(1.8, 0.9), yaw=0.4)
    chairs = table_chairs([table], 4, np.random.default_rng(0))
    assert len(chairs) == 4 and sorted(c.side for c in chairs) == [-1, -1, 1, 1]
    length, width = table.size_xy
    boxes = []
    for chair in chairs:
        local = transform_points(np.linalg.inv(table.pose_world_top), chair.mesh.vertices)  # the top at z = 0
        low, high = local.min(axis=0), local.max(axis=0)
        assert low[2] == pytest.approx(-table.height) and high[2] == pytest.approx(chair.back_above_m)
        assert BACK_ABOVE_M[0] <= chair.back_above_m <= BACK_ABOVE_M[1] and GAP_M[0] <= chair.gap_m <= GAP_M[1]
        # above the top's underside only the back, outside the table's edge
        upper = local[local[:, 2] > -table.top_thickness]
        assert np.all(np.abs(upper[:, 1]) >= width / 2 + chair.gap_m - 1e-9)
        # clear of the legs (two leg widths in from the ends)
        assert np.all(np.abs(local[:, 0]) <= length / 2 - 2.5 * table.leg_width + 1e-9)
        boxes.append((chair.side, low[0], high[0]))
    for i, (side_a, low_a, high_a) in enumerate(boxes):
        for side_b, low_b, high_b in boxes[i + 1:]:
            assert side_a != side_b or low_a >= high_b or low_b >= high_a


def test_chairs_are_part_of_the_room_and_leave_the_rest_of_the_scene_as_it_was():
    plain = make_config("sample", 2)
    seated = make_config("sample", 2, chairs_per_table=2)
    models = procedural_models(plain)
    a, b = build_world(plain, models), build_world(seated, models)
    assert a.chairs == [] and len(b.chairs) == 2 * len(b.tables)
    assert a.source == b.source and a.target == b.target and a.changes == b.changes and a.clutter == b.clutter
    objects, before = render_objects(b, "source"), render_objects(a, "source")
    assert len(objects) == len(before) + len(b.chairs)
    assert {id(o.mesh) for o in objects if o.instance_id == 0} >= {id(c.mesh) for c in b.chairs}  # never an object
    assert len(world_ground_truth(b, seated)["chairs"]) == len(b.chairs)
    assert "chairs" not in world_ground_truth(a, plain)
    again = build_world(seated, models)  # drawn from the seed
    assert [c.as_dict() for c in again.chairs] == [c.as_dict() for c in b.chairs]


def test_a_count_out_of_range_is_refused():
    with pytest.raises(SimError):
        make_config("sample", 0, chairs_per_table=-1)
    with pytest.raises(SimError):
        make_config("sample", 0, chairs_per_table=5)
