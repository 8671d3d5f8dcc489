"""Furniture along the walls (`ndfa.sim.furniture`): static pieces that break the box room's symmetry."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.io.ingest.synthetic import render_objects, world_ground_truth
from ndfa.sim.furniture import wall_furniture
from ndfa.sim.presets import make_config
from ndfa.sim.scene import Room
from ndfa.sim.world import build_world, procedural_models


def test_pieces_stand_on_the_floor_against_the_walls_apart_from_each_other():
    room = Room((6.0, 5.0))
    pieces = wall_furniture(room, 8, np.random.default_rng(3))
    assert len(pieces) == 8
    half = np.array(room.size_xy) / 2
    footprints = []
    for piece in pieces:
        vertices = piece.mesh.vertices
        low, high = vertices.min(axis=0), vertices.max(axis=0)
        assert low[2] == pytest.approx(0.0, abs=1e-9) and high[2] == pytest.approx(piece.size[2])
        assert np.all(low[:2] >= -half - 1e-9) and np.all(high[:2] <= half + 1e-9)  # inside the room
        # its back on its wall, its depth into the room
        axis, side = {0: (1, -1), 1: (0, 1), 2: (1, 1), 3: (0, -1)}[piece.wall]
        wall_face = side * half[axis]
        assert (high if side > 0 else low)[axis] == pytest.approx(wall_face)
        assert high[axis] - low[axis] == pytest.approx(piece.size[1])
        footprints.append((low[:2], high[:2]))
    for i, (low_a, high_a) in enumerate(footprints):
        for low_b, high_b in footprints[i + 1:]:
            assert np.any(low_a >= high_b) or np.any(low_b >= high_a)  # no two overlap


def test_furniture_is_part_of_the_room_and_leaves_the_rest_of_the_scene_as_it_was():
    plain = make_config("sample", 2)
    furnished = make_config("sample", 2, furniture=5)
    models = procedural_models(plain)
    a, b = build_world(plain, models), build_world(furnished, models)
    assert a.furniture == [] and len(b.furniture) == 5
    assert a.source == b.source and a.target == b.target and a.changes == b.changes  # the same mugs and changes
    objects = render_objects(b, "source")
    assert len(objects) == len(render_objects(a, "source")) + 5
    assert all(o.instance_id == 0 for o in objects[len(b.room.meshes()) + len(b.tables):][:5])  # never an object
    truth = world_ground_truth(b, furnished)
    assert [p["kind"] for p in truth["furniture"]] == [p.kind for p in b.furniture]
    assert "furniture" not in world_ground_truth(a, plain)
    again = build_world(furnished, models)  # drawn from the seed
    assert [p.as_dict() for p in again.furniture] == [p.as_dict() for p in b.furniture]


def test_a_negative_count_is_refused():
    with pytest.raises(SimError):
        make_config("sample", 0, furniture=-1)
    with pytest.raises(SimError):
        wall_furniture(Room((4.0, 4.0)), 1000, np.random.default_rng(0))
