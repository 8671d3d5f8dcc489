"""NDF training data (`ndfa.training.views`, `object_samples`, `dataset`, `batches`, `shape_parameters`):
partial views of procedural mugs with occupancy labels."""

import dataclasses

import numpy as np
import open3d as o3d
import pytest

from ndfa.core.errors import DataError
from ndfa.core.geometry import invert_pose, transform_points
from ndfa.sim.mug import MugParams, build_mug
from ndfa.sim.noise import DepthNoise
from ndfa.sim.splits import TRAIN_SEEDS, make_split_mug
from ndfa.training import dataset as dataset_module
from ndfa.training import views
from ndfa.training.batches import sample_batch
from ndfa.training.dataset import (
    DATASET_ARRAYS,
    generate_views,
    load_dataset,
    write_dataset,
)
from ndfa.training.object_samples import object_center
from ndfa.training.shape_parameters import NUMERIC_PARAMS, shape_parameters
from ndfa.training.views import View, ViewConfig, render_view

# Near views (the mug 0.2-0.8 m beyond the table's edge): many points, little noise.
NEAR = ViewConfig(distance_range_m=(0.2, 0.8))
SMALL = dataclasses.replace(ViewConfig(), n_points=64, n_queries=64)


@pytest.fixture(scope="module")
def mugs():
    return [make_split_mug("train", i) for i in range(4)]


@pytest.fixture(scope="module")
def near_views(mugs):
    return [render_view(mugs[0], mugs[1:], np.random.default_rng([7, k]), NEAR) for k in range(8)]


def distance_to_surface(mug, points_object):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mug.mesh.to_open3d_tensor())
    return scene.compute_distance(o3d.core.Tensor(points_object.astype(np.float32))).numpy()


def to_object(view: View, points_camera: np.ndarray) -> np.ndarray:
    return transform_points(invert_pose(view.pose_camera_object.astype(np.float64)), points_camera.astype(np.float64))


def test_view_has_exact_sizes_and_types(near_views):
    for view in near_views:
        assert view.points.shape == (NEAR.n_points, 3) and view.points.dtype == np.float32
        assert view.queries.shape == (NEAR.n_queries, 3) and view.queries.dtype == np.float32
        assert view.occupancy.shape == (NEAR.n_queries,) and view.occupancy.dtype == bool
        assert view.pose_camera_object.shape == (4, 4) and view.center_camera.shape == (3,)
        assert view.n_visible >= NEAR.min_points


def test_points_lie_on_the_mug_surface_in_front_of_the_camera(mugs, near_views):
    for view in near_views:
        assert np.all(view.points[:, 2] > 0)  # camera frame: z forward
        distances = distance_to_surface(mugs[0], to_object(view, view.points))
        assert np.median(distances) < 0.005


def test_noiseless_points_lie_exactly_on_the_surface(mugs):
    config = dataclasses.replace(NEAR, noise=DepthNoise.off())
    view = render_view(mugs[0], mugs[1:], np.random.default_rng(3), config)
    assert np.median(distance_to_surface(mugs[0], to_object(view, view.points))) < 0.0005


def test_few_visible_points_are_resampled_with_replacement(mugs):
    far = ViewConfig(distance_range_m=(4.0, 5.0), n_points=3000)  # a mug 4-5 m away shows a few hundred
    view = render_view(mugs[0], [], np.random.default_rng(4), far)
    assert view.points.shape == (3000, 3)
    assert len(np.unique(view.points, axis=0)) <= view.n_visible < 3000


def test_labels_are_the_mug_occupancy_of_the_queries(mugs, near_views):
    for view in near_views:
        assert np.mean(mugs[0].occupancy(to_object(view, view.queries)) == view.occupancy) > 0.999


def test_center_is_the_cached_solid_centroid_in_the_camera_frame(mugs, near_views):
    center = object_center(mugs[0])
    assert np.allclose(object_center(mugs[0]), center)  # cached, and a copy
    assert abs(center[0]) < 0.03 and abs(center[1]) < 0.001  # handle on +x, symmetric about xz
    assert 0.0 < center[2] < mugs[0].mesh.bounds[1][2]
    for view in near_views:
        expected = transform_points(view.pose_camera_object.astype(np.float64), center[None])[0]
        assert np.allclose(view.center_camera, expected, atol=1e-5)


def test_center_is_the_centroid_of_the_solid_volume(mugs):
    # Brute force: the mean of the points inside among random points filling the bounding box.
    mug = mugs[2]
    box_min, box_max = mug.mesh.bounds
    points = np.random.default_rng(0).uniform(box_min, box_max, size=(400_000, 3))
    brute_force = points[mug.occupancy(points)].mean(axis=0)
    assert np.linalg.norm(object_center(mug) - brute_force) < 0.0005
    # Without a handle the mug is a solid of revolution: its center lies on the axis.
    plain = build_mug(MugParams(handle_shape="none"))
    assert np.allclose(object_center(plain)[:2], 0.0, atol=1e-9) and 0.0 < object_center(plain)[2] < 0.095


def test_queries_cover_the_surface_band_and_the_padded_box(mugs, near_views):
    box_min, box_max = mugs[0].mesh.bounds
    half = len(near_views[0].queries) // 2
    for view in near_views:
        queries = to_object(view, view.queries)
        near_distance = distance_to_surface(mugs[0], queries[:half])
        assert np.median(near_distance) < 0.01
        padding = (box_max - box_min) * NEAR.box_padding / 2 + 1e-6
        assert np.all(queries[half:] >= box_min - padding) and np.all(queries[half:] <= box_max + padding)
    occupied = np.mean([view.occupancy.mean() for view in near_views])
    assert 0.15 < occupied < 0.6


def test_cameras_stand_around_the_table_and_look_at_the_mug():
    config = ViewConfig()
    table = config.table
    target = np.array([0.3, -0.2, table.height + 0.05])
    distances = []
    for k in range(200):
        pose_world_camera = views._camera_pose(table, target, np.random.default_rng([6, k]), config)
        eye, axis = pose_world_camera[:3, 3], pose_world_camera[:3, 2]
        distances.append(table.distance_xy(eye[None, :2])[0])
        assert config.height_range_m[0] - 1e-9 <= eye[2] - table.height <= config.height_range_m[1] + 1e-9
        to_target = (target - eye) / np.linalg.norm(target - eye)
        assert np.degrees(np.arccos(axis @ to_target)) < 25  # aimed at the mug, a little off
    distances = np.array(distances)
    assert np.all((distances >= 0.2 - 1e-9) & (distances <= 5.0 + 1e-9))  # never inside the table
    assert 0.35 < np.mean(distances < 1.0) < 0.65  # log-uniform: half the views nearer than 1 m


@pytest.mark.slow
def test_generation_is_deterministic_and_independent_of_workers_and_order():
    one = generate_views("train", [0, 1, 2], 2, seed=11, config=SMALL, workers=1)
    two = generate_views("train", [2, 0, 1], 2, seed=11, config=SMALL, workers=2)
    order = np.lexsort((two["view_id"], two["object_index"]))
    for name in DATASET_ARRAYS:
        assert np.array_equal(one[name], two[name][order]), name
    assert list(one["object_index"]) == [0, 0, 1, 1, 2, 2] and list(one["view_id"]) == [0, 1] * 3
    other_seed = generate_views("train", [0], 2, seed=12, config=SMALL, workers=1)
    assert not np.array_equal(other_seed["points"], one["points"][:2])


def test_only_mugs_of_the_asked_split_are_used(monkeypatch):
    seeds = []
    real_render_view = dataset_module.render_view

    def spy(mug, others, rng, config, **kwargs):
        seeds.extend(m.seed for m in [mug, *others])
        return real_render_view(mug, others, rng, config, **kwargs)

    monkeypatch.setattr(dataset_module, "render_view", spy)
    dataset = generate_views("train", [5, 6, 7], 2, seed=0, config=SMALL, workers=1)
    assert str(dataset["split"]) == "train"
    assert len(seeds) > 6 and all(seed in TRAIN_SEEDS for seed in seeds)
    assert set(seeds) <= {5, 6, 7}  # occluder mugs come from the given indices only


def test_dataset_round_trip(tmp_path):
    dataset = generate_views("train", [0, 1], 2, seed=3, config=SMALL, workers=1)
    path = write_dataset(tmp_path / "views.npz", dataset)
    assert path.exists() and not list(tmp_path.glob(".*.tmp"))
    loaded = load_dataset(path)
    for name, array in dataset.items():
        assert np.array_equal(loaded[name], array) and loaded[name].dtype == array.dtype, name


def test_missing_or_corrupt_dataset_raises_data_error_naming_the_file(tmp_path):
    missing = tmp_path / "missing.npz"
    with pytest.raises(DataError, match="missing.npz"):
        load_dataset(missing)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file at all")
    with pytest.raises(DataError, match="garbage.npz"):
        load_dataset(garbage)
    dataset = generate_views("train", [0], 1, seed=3, config=SMALL, workers=1)
    truncated = write_dataset(tmp_path / "truncated.npz", dataset)
    truncated.write_bytes(truncated.read_bytes()[: truncated.stat().st_size // 2])
    with pytest.raises(DataError, match="truncated.npz"):
        load_dataset(truncated)
    incomplete = tmp_path / "incomplete.npz"
    np.savez_compressed(incomplete, points=dataset["points"])
    with pytest.raises(DataError, match="incomplete.npz.*lacks"):
        load_dataset(incomplete)


def test_batches_hold_two_different_views_of_distinct_mugs():
    dataset = generate_views("train", [0, 1, 2, 3], 3, seed=1, config=SMALL, workers=1)
    rng = np.random.default_rng(0)
    for _ in range(10):
        batch = sample_batch(dataset, 3, rng)
        assert batch["points"].shape == (6, SMALL.n_points, 3)
        assert batch["queries"].shape == (6, SMALL.n_queries, 3)
        assert batch["occupancy"].shape == (6, SMALL.n_queries) and batch["center"].shape == (6, 3)
        mugs = batch["object_id"].numpy()
        assert len(set(mugs[:3])) == 3 and np.array_equal(mugs[:3], mugs[3:])
        assert not any(np.array_equal(batch["points"][b], batch["points"][b + 3]) for b in range(3))
    with pytest.raises(DataError):
        sample_batch(dataset, 5, rng)


def test_bad_config_and_arguments_raise_data_error():
    with pytest.raises(DataError):
        ViewConfig(distance_range_m=(0.0, 5.0))
    with pytest.raises(DataError):
        ViewConfig(height_range_m=(0.3, 0.1))
    with pytest.raises(DataError):
        generate_views("train", [], 2, seed=0, config=SMALL)
    with pytest.raises(DataError):
        generate_views("train", [1, 1], 2, seed=0, config=SMALL)


def test_shape_parameters_describe_each_mug():
    table = shape_parameters("train", list(range(60)))
    numeric = len(NUMERIC_PARAMS)
    assert table.shape == (60, numeric + 4 + 3 + 5) and np.isfinite(table).all()
    tags = table[:, numeric:]
    for start, stop in ((0, 4), (4, 7), (7, 12)):  # profile, base style, handle shape: one of each
        assert (tags[:, start:stop].sum(axis=1) == 1).all()
    height = NUMERIC_PARAMS.index("height")
    assert np.allclose(table[:, height], [make_split_mug("train", i).params.height for i in range(60)])
    handle_fields = [i for i, name in enumerate(NUMERIC_PARAMS) if name.startswith("handle_")]
    without_handle = tags[:, 11] == 1
    assert (table[without_handle][:, handle_fields] == 0).all() and (table[~without_handle][:, handle_fields] > 0).any(axis=1).all()
