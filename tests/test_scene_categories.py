"""Scenes of every category (issue 33, items 3 and 5): the models a multi-category scene places,
their categories in the ground truth, switches across categories, and scoring per true category."""

import dataclasses
from collections import Counter

import numpy as np
import pytest

from ndfa.eval.scoring import KindReport, score
from ndfa.io.ingest.synthetic import world_ground_truth
from ndfa.sim.categories import CATEGORIES
from ndfa.sim.presets import make_config
from ndfa.sim.splits import make_split_mug
from ndfa.sim.table_space import footprint_radius
from ndfa.sim.world import MAX_SCENE_RADIUS_M, MAX_SHELF_HEIGHT_M, build_world, model_category, procedural_models


def test_mugs_alone_keep_the_seeds_mugs():
    config = make_config("paper", 0)
    rng = np.random.default_rng([0, 1])
    expected = [make_split_mug("test", int(i)).model_id for i in sorted(rng.choice(1_000_000, size=20, replace=False))]
    assert [m.model_id for m in procedural_models(config)] == expected
    assert {model_category(m) for m in procedural_models(config)} == {"mug"}


@pytest.mark.parametrize("seed", [1, 4])
def test_random_with_every_category_places_each_and_labels_the_truth(seed):
    config = make_config("random", seed, categories=CATEGORIES)
    models = procedural_models(config)
    assert Counter(model_category(m) for m in models).keys() == set(CATEGORIES)  # 6+ models: each category once
    assert all(footprint_radius(m) <= MAX_SCENE_RADIUS_M for m in models)
    world = build_world(config, models)
    truth = world_ground_truth(world, config)
    by_model = {m["model_id"]: m["category"] for m in truth["models"]}
    assert set(by_model.values()) <= set(CATEGORIES)
    for o in truth["objects"]:
        assert o["category"] == by_model[o["model_id"]] == o["model_id"].split("-")[0]


def test_a_switch_may_cross_categories():
    """Seed 4 switches a mug and a bottle: each takes the other's place (a bowl may take a cup's)."""
    config = make_config("random", 4, categories=CATEGORIES)
    world = build_world(config, procedural_models(config))
    category = {i: model_category(world.mugs[p.model_id]) for i, p in world.source.items()}
    pairs = {(c.instance_id, c.partner) for c in world.changes if c.kind == "switched"}
    assert any(category[a] != category[b] for a, b in pairs)
    for a, b in pairs:
        assert world.target[a].xy == world.source[b].xy


def test_shelves_take_objects_that_fit_between_the_boards():
    config = make_config("shelves", 1, categories=CATEGORIES)
    for model in procedural_models(config):
        assert np.ptp(model.mesh.vertices[:, 2]) <= MAX_SHELF_HEIGHT_M


def test_score_per_true_category():
    objects = [{"instance_id": 1, "category": "mug", "change": "added"},
               {"instance_id": 2, "category": "bowl", "change": "removed"},
               {"instance_id": 3, "category": "bowl", "change": "unchanged"},
               {"instance_id": 4, "category": "box", "change": "switched"}]
    s = score([1, 3], {"objects": objects})
    assert (s.tp, s.fp, s.fn) == (1, 1, 2)
    assert s.categories == {"bowl": (0, 1, 1), "box": (0, 0, 1), "mug": (1, 0, 0)}
    assert s.as_dict()["categories"]["bowl"] == {"tp": 0, "fp": 1, "fn": 1, "precision": 0.0, "recall": 0.0}
    # one category (or a ground truth written before them): the overall score alone
    mugs_only = [dict(o, category="mug") for o in objects]
    assert score([1, 3], {"objects": mugs_only}).categories == {}
    assert score([1], {"objects": [{k: v for k, v in o.items() if k != "category"} for o in objects]}).categories == {}


def test_the_reports_named_categories_are_scored_against_the_truth():
    objects = [{"instance_id": 1, "category": "bowl", "change": "added"},
               {"instance_id": 2, "category": "cup", "change": "removed"},
               {"instance_id": 3, "category": "box", "change": "added"}]
    reports = [KindReport("added", 1, category="bowl"), KindReport("removed", 2, category="bowl"),
               KindReport("added", 3), KindReport("added", 9, category="box")]  # 3: unknown; 9: not scored
    s = score([1, 2, 3, 9], {"objects": objects}, {"source": {1, 2, 3}, "target": {1, 2, 3}}, kinds=reports)
    assert s.categories_named == (2, 1)
    assert s.as_dict()["categories_named"] == {"reports": 2, "right": 1, "accuracy": 0.5}
    assert "categories_named" not in score([1], {"objects": objects}, kinds=[KindReport("added", 1)]).as_dict()


def test_scene_categories_are_checked():
    with pytest.raises(Exception, match="distinct names"):
        dataclasses.replace(make_config("random", 1), categories=("mug", "mug"))
