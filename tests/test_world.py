"""The synthetic world's layouts and change scripts, checked without rendering."""

import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.sim.presets import make_config
from ndfa.sim.table_space import footprint_radius
from ndfa.sim.world import CHANGE_KINDS, build_world, procedural_models


@pytest.fixture(scope="module")
def paper_models():
    return procedural_models(make_config("paper", 0))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_paper_preset_matches_the_paper(seed, paper_models):
    config = make_config("paper", seed)
    models = paper_models if seed == 0 else procedural_models(config)
    world = build_world(config, models)
    assert len(world.tables) == 8
    assert len({m.model_id for m in models}) == 20
    assert 35 <= len(world.source) <= 40
    per_table = np.bincount([p.table_id for p in world.source.values()], minlength=9)[1:]
    assert per_table.min() >= 3 and per_table.max() <= 5
    counts = world.change_counts()
    assert sum(counts.values()) == 12
    assert counts == {"added": 4, "removed": 4, "moved": 0, "switched": 4}


def test_layouts_are_collision_free_and_on_the_tables(paper_models):
    world = build_world(make_config("paper", 0), paper_models)
    for layout in (world.source, world.target):
        for table in world.tables:
            here = [p for p in layout.values() if p.table_id == table.table_id]
            for i, a in enumerate(here):
                ra = footprint_radius(world.mugs[a.model_id])
                assert np.all(np.abs(a.xy) + ra <= np.array(table.size_xy) / 2)
                for b in here[i + 1:]:
                    rb = footprint_radius(world.mugs[b.model_id])
                    assert np.linalg.norm(np.subtract(a.xy, b.xy)) >= ra + rb


def test_change_labels_agree_with_the_layouts(paper_models):
    config = make_config("paper", 0, changes={"added": 2, "removed": 2, "switched": 4, "moved": 2})
    world = build_world(config, paper_models)
    kinds = {c.instance_id: c for c in world.changes}
    for instance_id in world.source.keys() | world.target.keys():
        change = kinds.get(instance_id)
        src, tgt = world.source.get(instance_id), world.target.get(instance_id)
        if change is None:
            assert src == tgt
        elif change.kind == "added":
            assert src is None and tgt is not None
        elif change.kind == "removed":
            assert src is not None and tgt is None
        elif change.kind == "moved":
            moved = np.linalg.norm(np.subtract(src.xy, tgt.xy)) >= 0.1 or src.table_id != tgt.table_id
            assert moved
        else:  # switched: each mug stands where its partner stood, and the two differ in shape
            partner = world.source[change.partner]
            assert (tgt.table_id, tgt.xy) == (partner.table_id, partner.xy)
            assert src.model_id != partner.model_id
            assert kinds[change.partner].partner == instance_id
    assert set(world.change_counts()) == set(CHANGE_KINDS)


def test_world_is_deterministic_in_the_seed(paper_models):
    a = build_world(make_config("paper", 0), paper_models)
    b = build_world(make_config("paper", 0), paper_models)
    c = build_world(make_config("paper", 1), paper_models)
    assert a.source == b.source and a.target == b.target and a.changes == b.changes
    assert a.source != c.source


@pytest.mark.parametrize("seed", range(6))
def test_random_preset_builds(seed):
    config = make_config("random", seed)
    world = build_world(config, procedural_models(config))
    assert sum(world.change_counts().values()) == sum(config.changes.values())
    assert config.source_route != config.target_route


def test_bad_settings_are_refused(paper_models):
    with pytest.raises(SimError, match="unknown preset"):
        make_config("kitchen", 0)
    with pytest.raises(SimError, match="pairs"):
        build_world(make_config("paper", 0, changes={"switched": 3}), paper_models)
    with pytest.raises(SimError, match="unknown change kinds"):
        build_world(make_config("paper", 0, changes={"stolen": 1}), paper_models)
    with pytest.raises(SimError, match="cannot"):
        build_world(make_config("paper", 0, mugs_per_table=(40, 40), total_mugs=None), paper_models)
