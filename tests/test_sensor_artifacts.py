"""The real-sensor artifacts of NDF v2's training views (`ndfa.sim.sensor_artifacts`)."""

from __future__ import annotations

import numpy as np
import pytest

from ndfa.core.errors import SimError
from ndfa.sim.sensor_artifacts import SensorArtifacts
from ndfa.sim.splits import make_split_mug
from ndfa.training.views import ViewConfig, render_view

NONE = dict(dark_probability=0.0, shiny_probability=0.0, thin_probability=0.0, flying_probability=0.0,
            mask_shift_probability=0.0)


def scene(mug_depth: float = 1.0, background_depth: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """A 40x40 image: a 20x20 mug at `mug_depth` with a 2-pixel-wide handle bar, background behind."""
    depth = np.full((40, 40), background_depth, dtype=np.float32)
    mask = np.zeros((40, 40), dtype=bool)
    mask[10:30, 10:30] = True
    mask[18:20, 30:38] = True  # the thin handle
    depth[mask] = mug_depth
    return depth, mask


def run(artifacts: SensorArtifacts, depth: np.ndarray, mask: np.ndarray, seed: int = 0):
    cos = np.full(depth.shape, 0.5, dtype=np.float32)
    return artifacts.apply(depth, depth, mask, cos, np.random.default_rng(seed))


def test_nothing_drawn_changes_nothing():
    depth, mask = scene()
    new_depth, new_mask = run(SensorArtifacts(**NONE), depth, mask)
    np.testing.assert_array_equal(new_depth, depth)
    np.testing.assert_array_equal(new_mask, mask)


def test_thin_handle_vanishes_body_stays():
    depth, mask = scene()
    new_depth, _ = run(SensorArtifacts(**(NONE | dict(thin_probability=1.0, thin_radius_px_range=(1, 1)))), depth, mask)
    assert np.all(new_depth[18:20, 31:38] == 0)          # the 2-pixel bar is gone
    assert np.all(new_depth[12:28, 12:28] == 1.0)        # the body's inside is untouched


def test_dark_glaze_holes_take_the_drawn_share():
    depth, mask = scene()
    artifacts = SensorArtifacts(**(NONE | dict(dark_probability=1.0, dark_hole_fraction_range=(0.3, 0.3))))
    new_depth, _ = run(artifacts, depth, mask)
    lost = np.mean(new_depth[mask] == 0)
    assert 0.25 <= lost <= 0.35
    assert np.all(new_depth[~mask] == 2.0)


def test_flying_pixels_lie_between_mug_and_background_and_far_ones_leave_the_mask():
    depth, mask = scene()
    artifacts = SensorArtifacts(**(NONE | dict(flying_probability=1.0)))
    new_depth, new_mask = run(artifacts, depth, mask)
    moved = mask & (new_depth != depth)
    assert moved.sum() > 20                                    # silhouette pixels flew
    assert np.all((new_depth[moved] > 1.0) & (new_depth[moved] < 2.0))
    kept = new_mask & (new_depth > 0)
    assert np.all(np.abs(new_depth[kept] - 1.0) <= artifacts.mask_depth_window_m)
    assert (moved & new_mask).sum() < moved.sum()              # those far behind are cut off


def test_shifted_mask_takes_in_what_lies_beside_at_the_mugs_depth():
    depth, mask = scene(background_depth=1.03)  # a surface right behind the mug: kept when the mask leaks onto it
    artifacts = SensorArtifacts(**(NONE | dict(mask_shift_probability=1.0, mask_shift_px=2)))
    shifted = [run(artifacts, depth, mask, seed)[1] for seed in range(8)]
    assert any((m & ~mask).any() for m in shifted)


def test_same_generator_same_view_and_bad_settings_refused():
    depth, mask = scene()
    a = run(SensorArtifacts(), depth, mask, seed=3)
    b = run(SensorArtifacts(), depth, mask, seed=3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    with pytest.raises(SimError):
        SensorArtifacts(flying_probability=1.5)
    with pytest.raises(SimError):
        SensorArtifacts(disparity_step_range_per_m=(0.003, 0.001))


def test_training_view_with_artifacts_keeps_points_on_the_mug():
    mug = make_split_mug("train", 3)
    config = ViewConfig(distance_range_m=(0.3, 1.5), artifacts=SensorArtifacts(), n_points=128, min_points=100)
    for k in range(4):
        view = render_view(mug, [], np.random.default_rng([0, 3, k]), config)
        distance = np.linalg.norm(view.points - view.center_camera, axis=1)
        assert view.points.shape == (128, 3)
        assert np.percentile(distance, 99) < 0.12  # no flying or leaked point far from the mug
