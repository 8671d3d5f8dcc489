"""NDF v3's data and outputs over every object category (issue 33, item 2): per-object samples of
any category, views of any category among occluders of any, the category in the dataset arrays
and the batches, the category head's loss, and `ndfa ndf-eval`'s figures per category."""

import dataclasses

import numpy as np
import open3d as o3d
import pytest

from ndfa.core.errors import DataError, ModelError
from ndfa.core.geometry import invert_pose, transform_points
from ndfa.ndf.config import NDFConfig
from ndfa.sim.categories import CATEGORIES
from ndfa.sim.splits import TEST_SEEDS, make_split_object
from ndfa.training import dataset as dataset_module
from ndfa.training.batches import sample_batch
from ndfa.training.dataset import DATASET_ARRAYS, generate_views, load_dataset, object_ids
from ndfa.training.ndf_eval import per_category, per_track
from ndfa.training.object_samples import object_center, object_samples
from ndfa.training.views import ViewConfig

SMALL = ViewConfig(n_points=64, n_queries=64, distance_range_m=(0.2, 0.8))


def _distance_to_surface(solid, points: np.ndarray) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(solid.mesh.to_open3d_tensor())
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


@pytest.mark.parametrize("category, seed", [("bowl", 0), ("cup", 1), ("bottle", 0), ("can", 0), ("box", 0)])
def test_samples_of_an_object_are_its_solid_centroid_and_surface(category, seed):
    solid = make_split_object(category, "train", seed)
    assert category != "box" or len(solid.parts) == 2  # box 0 has a lid, cup 1 a takeaway lid: overlapping parts
    box_min, box_max = solid.mesh.bounds
    points = np.random.default_rng(0).uniform(box_min, box_max, size=(300_000, 3))
    inside = solid.occupancy(points)
    assert np.array_equal(inside, solid.part_occupancy(points).any(axis=0))  # the union of the parts
    # Brute force: the mean of the points inside among random points filling the bounding box.
    size = float(np.max(box_max - box_min))
    assert np.linalg.norm(object_center(solid) - points[inside].mean(axis=0)) < 0.004 * size
    surface = object_samples(solid).surface
    assert len(surface) > 4000 and np.median(_distance_to_surface(solid, surface)) < 1e-4


def test_views_of_several_categories_carry_the_category_and_take_occluders_of_any(monkeypatch):
    seen = []
    real_render_view = dataset_module.render_view

    def spy(target, others, rng, config, **kwargs):
        seen.append((target.category, [other.category for other in others], [other.seed for other in others]))
        return real_render_view(target, others, rng, config, **kwargs)

    monkeypatch.setattr(dataset_module, "render_view", spy)
    categories = ("bottle", "box")
    views = generate_views("train", [3, 4], 2, seed=1, config=SMALL, workers=1, categories=categories)
    assert list(views["category"]) == [CATEGORIES.index("bottle")] * 4 + [CATEGORIES.index("box")] * 4
    assert list(views["object_index"]) == [3, 3, 4, 4] * 2 and list(views["view_id"]) == [0, 1] * 4
    assert list(object_ids(views)) == [0, 0, 1, 1, 2, 2, 3, 3]  # distinct across categories
    occluders = {category for _, others, _ in seen for category in others}
    assert occluders == set(categories)  # each target among objects of both categories (3 candidates, 4 picked)
    assert all(seed in {3, 4} for _, _, seeds in seen for seed in seeds)  # only the dataset's own objects
    for row in (0, 5):  # labels are the object's occupancy of the stored queries
        solid = make_split_object(CATEGORIES[views["category"][row]], "train", int(views["object_index"][row]))
        queries = transform_points(invert_pose(views["pose_camera_object"][row].astype(np.float64)), views["queries"][row])
        assert np.mean(solid.occupancy(queries) == views["occupancy"][row]) > 0.99
    batch = sample_batch(views, 3, np.random.default_rng(0))
    ids, category = batch["object_id"].numpy(), batch["category"].numpy()
    assert len(set(ids[:3])) == 3 and np.array_equal(ids[:3], ids[3:])
    assert np.array_equal(category, np.where(ids >= 2, CATEGORIES.index("box"), CATEGORIES.index("bottle")))


def test_the_categories_of_a_dataset_are_checked():
    for categories in [(), ("mug", "mug"), ("mug", "plate")]:
        with pytest.raises(DataError, match="categories"):
            generate_views("train", [0], 1, seed=0, config=SMALL, categories=categories)
    assert make_split_object("bowl", "test", 2).seed == TEST_SEEDS[2]


def test_a_dataset_file_from_before_the_categories_loads_as_mugs(tmp_path):
    views = 3
    old = {name: np.zeros((views, *([2, 3] if name in ("points", "queries") else [4, 4] if name == "pose_camera_object"
                                    else [3] if name == "center" else [2] if name == "occupancy" else [])), dtype=dtype)
           for name, dtype in DATASET_ARRAYS.items() if name not in ("object_index", "category")}
    old["mug_index"] = np.array([5, 5, 6], dtype=np.int32)
    np.savez_compressed(tmp_path / "old.npz", **old)
    loaded = load_dataset(tmp_path / "old.npz")
    assert list(loaded["object_index"]) == [5, 5, 6] and list(loaded["category"]) == [CATEGORIES.index("mug")] * 3
    assert list(object_ids(loaded)) == [0, 0, 1]


def test_the_headline_per_category():
    # Four views in the regime (two bowls, a box twice) and one beyond it; codes chosen so that the
    # second bowl's view retrieves the box's.
    per_view = {"category": np.array(["bowl", "bowl", "box", "box", "bowl"]), "object_id": np.array([0, 1, 2, 2, 0]),
                "detector_regime": np.array([True, True, True, True, False]),
                "predicted_category": np.array(["bowl", "box", "box", "box", "box"])}
    codes = np.array([[1.0, 0.0], [0.0, 1.0], [0.1, 1.0], [0.2, 1.0], [1.0, 0.0]])
    true = np.zeros((5, 3))
    predicted = true + np.array([[0.001, 0, 0], [0.003, 0, 0], [0.002, 0, 0], [0.004, 0, 0], [0.5, 0, 0]])
    summary = per_category(per_view, predicted, true, codes)
    assert summary["bowl_views_within_2m"] == 2 and summary["box_views_within_2m"] == 2
    assert summary["bowl_center_median_mm_within_2m"] == pytest.approx(2.0)
    assert summary["box_center_median_mm_within_2m"] == pytest.approx(3.0)
    assert summary["bowl_retrieval_top1_within_2m"] == 0.0  # bowl 0 has no other view in the regime, bowl 1 finds a box
    assert summary["box_retrieval_top1_within_2m"] == 1.0
    assert summary["bowl_category_accuracy_within_2m"] == 0.5 and summary["box_category_accuracy_within_2m"] == 1.0
    assert summary["category_accuracy_within_2m"] == 0.75
    assert "mug_views_within_2m" not in summary



def test_tracks_fuse_views_and_vote_their_category():
    # Object 0 (a mug) is seen as a cup in 3 of its 4 views, but the mug views are sure and the cup
    # views are not: a track of 2 views names it a mug only when it holds a sure view. Object 1's
    # codes agree; object 0's single views scatter, yet their mean stays its own.
    per_view = {"category": np.array(["mug"] * 4 + ["cup"] * 4), "object_id": np.array([0] * 4 + [1] * 4),
                "detector_regime": np.ones(8, dtype=bool),
                "predicted_category": np.array(["mug", "cup", "cup", "cup"] + ["cup"] * 4),
                "category_probability": np.array([0.99, 0.4, 0.4, 0.4] + [0.9] * 4)}
    codes = np.array([[1.0, 0.3], [1.0, -0.3], [1.0, 0.2], [1.0, -0.2]] + [[0.0, 1.0]] * 4)
    summary = per_track(per_view, codes, views_per_track=2, draws=20)
    assert summary["track_objects"] == 2
    assert summary["track_retrieval_top1"] == 1.0
    assert summary["cup_track_category_accuracy"] == 1.0
    # the sure mug view is in exactly one of each draw's two tracks: half the mug tracks are right
    assert summary["mug_track_category_accuracy"] == 0.5
    one_view = per_track(per_view, codes, views_per_track=1, draws=50)
    assert one_view["mug_track_category_accuracy"] == pytest.approx(0.25, abs=0.15)
    assert per_track(per_view, codes, views_per_track=5)["track_objects"] == 0  # 4 views: not two tracks of 5

TINY = NDFConfig(hidden=8, latent=16, knn=8, encoder_blocks=1, decoder_width=32, decoder_blocks=1, code_dim=16, gram_channels=4,
                 decoder="frame", local_points=4, up_cue=True, view_cue=True, center_head="gated", categories=("bowl", "box"))


@pytest.fixture(scope="module")
def category_run(tmp_path_factory):
    from ndfa.training.train import TrainConfig, train

    out = tmp_path_factory.mktemp("train-categories")
    config = TrainConfig(model=TINY, view=dataclasses.replace(SMALL, n_queries=128), categories=("bowl", "box"),
                         train_mugs=4, views_per_mug=3, val_mugs=2, val_views_per_mug=2, batch_mugs=4, steps=40,
                         steps_per_epoch=20, lr=3e-3, proxy_weight=0.1, category_weight=1.0, threads=1)
    return config, out, train(config, out)


@pytest.mark.slow
def test_training_over_categories_learns_the_category_and_resumes(category_run, tmp_path):
    import shutil

    from ndfa.training.train import train

    config, out, metrics = category_run
    assert metrics["step"].to_list() == [20, 40]
    assert metrics["train_category"][1] < metrics["train_category"][0]
    assert 0.0 <= metrics["val_category_accuracy"][1] <= 1.0
    shutil.copytree(out, tmp_path / "run")
    longer = train(dataclasses.replace(config, steps=60), tmp_path / "run", resume=True)
    assert longer["step"].to_list() == [20, 40, 60]
    with pytest.raises(ModelError, match="categories"):  # the head's categories are the views'
        train(dataclasses.replace(config, categories=("bowl", "cup")), tmp_path / "other")
    with pytest.raises(ModelError, match="parameter"):  # the mugs' shape parameters are mugs' only
        train(dataclasses.replace(config, param_weight=1.0), tmp_path / "param")


@pytest.mark.slow
def test_ndf_eval_reports_each_category(category_run):
    from ndfa.training.ndf_eval import evaluate_ndf

    _, out, _ = category_run
    views = generate_views("test", [0, 1], 2, 0, SMALL, workers=1, categories=("bowl", "box"))
    summary, per_view = evaluate_ndf(out / "checkpoint.pt", views=views, iou_grid=0)
    assert set(per_view["category"].to_list()) == {"bowl", "box"}
    assert set(per_view["predicted_category"].to_list()) <= {"bowl", "box"}
    for category in ("bowl", "box"):
        regime = per_view.filter(per_view["detector_regime"] & (per_view["category"] == category))
        assert summary[f"{category}_views_within_2m"] == len(regime)
        if len(regime):
            assert summary[f"{category}_category_accuracy_within_2m"] == pytest.approx(
                float((regime["predicted_category"] == category).mean()))
    assert 0.0 <= summary["retrieval_top1"] <= 1.0
