"""What depth cannot see: the plane term's unseen directions on a noisy wall, the prediction kept
along them (after the choice of term, not before), and the constant-velocity model of a camera
that walks straight while it pans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ndfa.core.geometry import axis_angle_to_matrix, make_pose
from ndfa.trajectory import rgbd
from ndfa.trajectory.constant_velocity import motion_between, predict
from ndfa.trajectory.degeneracy import (
    depth_degeneracy,
    keep_prediction_where_unseen,
    plane_information,
    unseen_information,
)
from ndfa.trajectory.rgbd import HYBRID, POINT_TO_PLANE
from ndfa.trajectory.rgbd_view import View, local_contrast

K = np.array([[290.0, 0.0, 160.0], [0.0, 290.0, 120.0], [0.0, 0.0, 1.0]])


def wall(distance_m: float = 1.2, noise_m: float = 0.0, seed: int = 0) -> np.ndarray:
    """A 320x240 depth image of a wall facing the camera, with Gaussian noise."""
    rng = np.random.default_rng(seed)
    return (distance_m + noise_m * rng.standard_normal((240, 320))).astype(np.float32)


def corner() -> np.ndarray:
    """Depth of three planes meeting (floor, two walls) seen from inside the corner."""
    rows, cols = np.mgrid[0:240, 0:320].astype(float)
    rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones_like(cols)], axis=-1)
    depth = np.full(rows.shape, np.inf)
    for normal, offset in (((0.0, -1.0, 0.0), -0.8), ((-0.7, 0.0, -0.7), -2.0), ((0.7, 0.0, -0.7), -2.0)):
        along = rays @ np.array(normal)
        with np.errstate(divide="ignore"):
            t = offset / along
        depth = np.where((t > 0) & (t < depth), t, depth)
    return depth.astype(np.float32)


def twist_pose(rotation: tuple[float, float, float], translation: tuple[float, float, float]) -> np.ndarray:
    return make_pose(axis_angle_to_matrix(np.array(rotation)), np.array(translation))


def _plane_information_by_definition(depth: np.ndarray, step: int, baseline: int) -> np.ndarray:
    """sum of J^T J, J = (p x n, n), over the pixels whose right and lower neighbours are on the same
    surface: the matrix `plane_information` computes component by component."""
    z = depth[::step, ::step].astype(np.float64)
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]] * step
    points = np.stack([(cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    b = baseline
    right, down = points[:-b, b:] - points[:-b, :-b], points[b:, :-b] - points[:-b, :-b]
    normals = np.cross(right, down)
    length = np.linalg.norm(normals, axis=-1)
    p = points[:-b, :-b]
    jump = 0.05 * b * p[..., 2]
    keep = np.isfinite(length) & (length > 0) & (np.abs(right[..., 2]) < jump) & (np.abs(down[..., 2]) < jump)
    n = normals[keep] / length[keep, None]
    jacobian = np.hstack([np.cross(p[keep], n), n])
    return jacobian.T @ jacobian


def test_the_plane_information_is_the_sum_over_the_surface_pixels_of_its_definition():
    depth = corner()
    depth[100:140, 50:90] = np.nan  # a hole of invalid depth
    depth[:, 200:] += 0.3  # and a depth jump, no plane across it
    for step, baseline in ((2, 1), (4, 4)):
        expected = _plane_information_by_definition(depth, step, baseline)
        assert np.allclose(plane_information(depth, K, step, baseline), expected, rtol=1e-12, atol=0.0)


def test_a_noisy_wall_shows_its_unseen_directions_only_with_normals_over_a_wider_baseline():
    noisy = wall(noise_m=0.004)
    adjacent = depth_degeneracy(plane_information(noisy, K), 1.2)
    wide = depth_degeneracy(plane_information(noisy, K, step=4, baseline=4), 1.2)
    assert adjacent > 0.01  # the noise's scattered normals look like a constraint on the slide
    assert wide < 0.002


def test_on_a_wall_the_prediction_is_kept_along_the_slide_and_the_roll_and_the_rest_is_measured():
    information = plane_information(wall(), K, step=4, baseline=4)
    prediction = twist_pose((0.0, 0.05, 0.0), (0.08, 0.0, 0.02))
    measured = prediction @ twist_pose((0.01, 0.02, 0.03), (0.2, -0.1, 0.05))  # slid 22 cm, rolled
    kept = np.linalg.inv(prediction) @ keep_prediction_where_unseen(measured, prediction, information, 1.2, 0.005)
    np.testing.assert_allclose(kept[:3, 3], [0.0, 0.0, 0.05], atol=1e-3)  # the distance to the wall measured
    rotation = kept[:3, :3]
    np.testing.assert_allclose(rotation, axis_angle_to_matrix(np.array([0.01, 0.02, 0.0])), atol=1e-3)  # tilts, no roll


def test_where_depth_sees_every_direction_the_registration_stands():
    depth = corner()
    information = plane_information(depth, K, step=4, baseline=4)
    assert depth_degeneracy(information, float(np.median(depth[np.isfinite(depth)]))) > 0.005
    prediction = twist_pose((0.0, 0.0, 0.0), (0.08, 0.0, 0.0))
    measured = prediction @ twist_pose((0.01, 0.02, 0.03), (0.02, -0.01, 0.01))
    kept = keep_prediction_where_unseen(measured, prediction, information, 1.5, 0.005)
    assert kept is measured


def test_a_camera_that_walks_straight_while_it_pans_is_predicted_by_its_velocity_in_the_world():
    poses = [twist_pose((0.0, np.radians(3.0) * k, 0.0), (0.08 * k, 0.0, 0.0)) for k in range(3)]
    world = predict(poses[1], motion_between(poses[0], poses[1], in_world=True), in_world=True)
    camera = predict(poses[1], motion_between(poses[0], poses[1], in_world=False), in_world=False)
    np.testing.assert_allclose(world, poses[2], atol=1e-12)
    assert np.linalg.norm(camera[:3, 3] - poses[2][:3, 3]) > 0.003  # the body-frame model turns the walk


def test_a_prediction_stays_a_rotation_however_often_it_is_repeated():
    # A registration's rotation a little off orthonormal (float32 inside Open3D), repeated frame
    # after frame by the world-velocity model, grew by its own error each time without the projection.
    last = twist_pose((0.0, 0.05, 0.0), (0.1, 0.0, 0.0))
    last[:3, :3] *= 1.0 + 1e-4
    motion = motion_between(last, last @ twist_pose((0.0, 0.03, 0.0), (0.05, 0.0, 0.0)), in_world=True)
    for _ in range(200):
        last = predict(last, motion, in_world=True)
    np.testing.assert_allclose(last[:3, :3] @ last[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.linalg.det(last[:3, :3]) == pytest.approx(1.0)


def test_the_term_nearer_the_prediction_is_chosen_before_the_prediction_is_kept_where_unseen(monkeypatch):
    # A textured frame facing a wall: hybrid lands 3 cm from the prediction (beyond the cross-check),
    # point-to-plane 10 cm along the wall. Kept where the wall's depth is blind, point-to-plane's
    # result would be the prediction itself and win the comparison it lost on its merits.
    prediction = twist_pose((0.0, 0.0, 0.0), (0.05, 0.0, 0.0))
    results = {HYBRID: prediction @ twist_pose((0.0, 0.0, 0.0), (0.0, 0.03, 0.0)),
               POINT_TO_PLANE: prediction @ twist_pose((0.0, 0.0, 0.0), (0.1, 0.0, 0.0))}
    monkeypatch.setattr(rgbd, "register_dense", lambda view, keyframe, initial, term, config, early_stop=True: (results[term], 0.8))
    view = View(rgbd=None, features=None, K=None, plane_information=np.eye(6),
                unseen_information=unseen_information(wall(), K), median_depth_m=1.2, valid_fraction=1.0, textured=True)
    odometry = rgbd.RgbdOdometry(rgbd.RgbdOdometryConfig(unseen_from_prediction=(POINT_TO_PLANE,)))
    result, _, term = odometry._from_prediction(view, view, prediction, HYBRID)
    assert term == HYBRID and result is results[HYBRID] and not odometry._unseen
    # Where point-to-plane is the better of the two, its slide along the wall is the prediction's.
    results[HYBRID] = prediction @ twist_pose((0.0, 0.0, 0.0), (0.0, 0.2, 0.0))
    result, _, term = odometry._from_prediction(view, view, prediction, HYBRID)
    assert term == POINT_TO_PLANE and odometry._unseen
    np.testing.assert_allclose(result, prediction, atol=1e-9)


def test_an_untextured_frame_facing_a_wall_meets_hybrid_when_it_has_colour(monkeypatch):
    # Colour below the `textured` test on a bare wall: point-to-plane slides 10 cm along it, hybrid,
    # pinned by the wall's faint texture, lands 3 mm from the prediction and wins; its slide is
    # measured, not guessed. Without colour hybrid is not tried: point-to-plane, prediction kept.
    prediction = twist_pose((0.0, 0.0, 0.0), (0.04, 0.0, 0.0))
    results = {HYBRID: prediction @ twist_pose((0.0, 0.0, 0.0), (0.003, 0.0, 0.0)),
               POINT_TO_PLANE: prediction @ twist_pose((0.0, 0.0, 0.0), (0.1, 0.0, 0.0))}
    tried = []

    def register(view, keyframe, initial, term, config, early_stop=True):
        tried.append(term)
        assert not early_stop  # from the prediction every iteration runs (rgbd_config: converged_change)
        return results[term], 0.9

    monkeypatch.setattr(rgbd, "register_dense", register)
    faint = View(rgbd=None, features=None, K=None, plane_information=np.eye(6),
                 unseen_information=unseen_information(wall(), K), median_depth_m=1.2, valid_fraction=1.0, textured=False)
    odometry = rgbd.RgbdOdometry(rgbd.RgbdOdometryConfig())
    result, _, term = odometry._from_prediction(faint, faint, prediction, POINT_TO_PLANE)
    assert tried == [POINT_TO_PLANE, HYBRID]
    # Off, the frame is point-to-plane's with the prediction kept, as before.
    plain = rgbd.RgbdOdometry(rgbd.RgbdOdometryConfig(hybrid_where_unseen=False))
    assert plain._from_prediction(faint, faint, prediction, POINT_TO_PLANE)[2] == POINT_TO_PLANE and plain._unseen
    assert term == HYBRID and result is results[HYBRID] and not odometry._unseen and odometry._faint_wall
    # Where hybrid slides as far as point-to-plane (no texture at all), point-to-plane keeps the prediction.
    results[HYBRID] = prediction @ twist_pose((0.0, 0.0, 0.0), (0.12, 0.0, 0.0))
    odometry._faint_wall = False
    result, _, term = odometry._from_prediction(faint, faint, prediction, POINT_TO_PLANE)
    assert term == POINT_TO_PLANE and odometry._unseen and not odometry._faint_wall
    np.testing.assert_allclose(result, prediction, atol=1e-9)
    # No colour: nothing for hybrid to pin the slide with.
    tried.clear()
    blind = View(rgbd=None, features=None, K=None, plane_information=np.eye(6),
                 unseen_information=unseen_information(wall(), K), median_depth_m=1.2, valid_fraction=1.0,
                 textured=False, coloured=False)
    result, _, term = odometry._from_prediction(blind, blind, prediction, POINT_TO_PLANE)
    assert tried == [POINT_TO_PLANE] and term == POINT_TO_PLANE and odometry._unseen
    # A frame whose depth sees every direction (a corner) is not a wall: no hybrid either.
    tried.clear()
    seen = View(rgbd=None, features=None, K=None, plane_information=np.eye(6),
                unseen_information=unseen_information(corner(), K), median_depth_m=1.5, valid_fraction=1.0, textured=False)
    odometry._from_prediction(seen, seen, prediction, POINT_TO_PLANE)
    assert tried == [POINT_TO_PLANE]


def test_frames_crossing_a_faint_wall_by_hybrid_become_keyframes(monkeypatch):
    # Hybrid on a faint wall lands a few millimetres off, more the farther its keyframe: each such
    # frame is made a keyframe (frame to frame through the wall); off, they share the first keyframe.
    # The first frame on the wall meets its keyframe (off the wall) in their colour; the frames
    # after it, whose keyframe is on the wall too, in their local contrast (`local_contrast`).
    compared = []

    def register(view, keyframe, initial, term, config, early_stop=True):
        if term == HYBRID:
            compared.append((view.textured, keyframe.textured))  # stands for "local contrast" below
        shift = 0.003 if term == HYBRID else 0.1
        return initial @ twist_pose((0.0, 0.0, 0.0), (shift, 0.0, 0.0)), 0.9

    def contrast(view, sigma_px, gain):
        assert (sigma_px, gain) == (8.0, 4.0)
        return dataclasses.replace(view, textured=True)

    monkeypatch.setattr(rgbd, "register_dense", register)
    monkeypatch.setattr(rgbd, "local_contrast", contrast)
    monkeypatch.setattr(rgbd, "depth_information", lambda *args: np.eye(6))
    faint = View(rgbd=None, features=None, K=None, plane_information=np.eye(6),
                 unseen_information=unseen_information(wall(), K), median_depth_m=1.2, valid_fraction=1.0, textured=False)
    for keyframes, expected in ((True, 4), (False, 1)):
        odometry = rgbd.RgbdOdometry(rgbd.RgbdOdometryConfig(features=None, loop_closure=False,
                                                             faint_wall_keyframes=keyframes))
        compared.clear()
        for _ in range(4):
            odometry._poses.append(odometry._track(faint)[0])
        assert odometry.faint_wall_frames == 3 and len(odometry.keyframes) == expected
        assert not odometry._unseen  # its slide measured by hybrid, not kept from the prediction
        assert compared == [(False, False), (True, True), (True, True)]
    # Off (0 px), the colour as it is throughout.
    odometry = rgbd.RgbdOdometry(rgbd.RgbdOdometryConfig(features=None, loop_closure=False, faint_wall_contrast_px=0.0))
    compared.clear()
    for _ in range(4):
        odometry._poses.append(odometry._track(faint)[0])
    assert compared == [(False, False)] * 3


def test_local_contrast_removes_shading_that_moves_with_the_camera():
    # A wall with faint texture (2 grey levels) under a light on the camera: brightness falls off
    # 60 grey levels from the image's centre to its corners. The local contrast keeps the texture,
    # amplified, and drops the fall-off; depth and the rest of the view are untouched; made once.
    import open3d as o3d

    rows, cols = np.mgrid[0:240, 0:320].astype(np.float32)
    falloff = 60.0 * ((rows - 120.0) ** 2 + (cols - 160.0) ** 2) / (120.0 ** 2 + 160.0 ** 2)
    texture = 2.0 * np.sign(np.sin(cols / 3.0) * np.sin(rows / 3.0))
    gray = np.clip(180.0 - falloff + texture, 0, 255).astype(np.uint8)
    depth = wall()[..., None]
    view = View(rgbd=o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.repeat(gray[..., None], 3, axis=2)),
                                              o3d.t.geometry.Image(depth)),
                features=None, K=None, plane_information=np.eye(6), unseen_information=np.eye(6),
                median_depth_m=1.2, valid_fraction=1.0, textured=False)
    seen = local_contrast(view, 8.0, 4.0)
    image = seen.rgbd.color.as_tensor().numpy()[..., 0].astype(float)
    inner = (slice(30, 210), slice(30, 290))  # away from the blur's border
    centre, corner_block = image[100:140, 140:180], image[30:70, 30:70]
    assert abs(gray[100:140, 140:180].mean() - gray[30:70, 30:70].mean()) > 20.0
    assert abs(centre.mean() - corner_block.mean()) < 2.0  # the fall-off is gone
    assert 6.0 < image[inner].std() < 10.0  # the texture (2 levels either way) kept, times 4
    assert np.corrcoef(image[inner].ravel(), texture[inner].ravel())[0, 1] > 0.8
    np.testing.assert_array_equal(seen.rgbd.depth.as_tensor().numpy(), depth)
    assert seen.median_depth_m == view.median_depth_m and local_contrast(view, 8.0, 4.0) is seen
