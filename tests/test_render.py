"""Pinhole camera, raycast renderer and depth noise model (ndfa.sim.camera / render / noise)."""

import math

import numpy as np
import open3d as o3d
import pytest

from ndfa.core.errors import SimError
from ndfa.core.geometry import invert_pose, look_at, transform_points
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.noise import DepthNoise
from ndfa.sim.render import RenderObject, SceneRenderer

# Small images keep the tests fast; the model does not depend on the resolution.
CAMERA = PinholeCamera.from_fov(160, 120, 60.0)
# At the origin, looking along world +x: camera x = world -y, camera y (down) = world -z, z = x.
LOOK_ALONG_X = look_at(np.zeros(3), np.array([1.0, 0.0, 0.0]))


def wall_at(distance: float, instance_id: int = 0) -> RenderObject:
    """A 20 m x 20 m wall facing the camera of LOOK_ALONG_X, its front face at x = distance."""
    return RenderObject(box_mesh((0.1, 20.0, 20.0), (distance + 0.05, 0.0, 0.0)), instance_id, (0.6, 0.6, 0.6))


def render_wall(distance: float):
    return SceneRenderer([wall_at(distance)]).render(CAMERA, LOOK_ALONG_X)


# --- camera -------------------------------------------------------------------------------------


def test_default_camera_is_640x480_with_60_degree_horizontal_fov():
    camera = PinholeCamera()
    assert (camera.width, camera.height) == (640, 480)
    assert math.degrees(2 * math.atan(camera.width / 2 / camera.fx)) == pytest.approx(60.0)
    assert camera.fx == camera.fy
    assert np.allclose(camera.K, [[camera.fx, 0, 319.5], [0, camera.fy, 239.5], [0, 0, 1]])
    assert PinholeCamera.from_fov(640, 480, 60.0) == camera


def test_scaled_camera_keeps_the_field_of_view():
    camera = PinholeCamera()
    half = camera.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    assert (half.cx, half.cy) == (159.5, 119.5)
    # The outer edge of the image (half a pixel beyond the corner pixel's centre) sees the same ray.
    for cam in (camera, half):
        assert (-0.5 - cam.cx) / cam.fx == pytest.approx((-0.5 - camera.cx) / camera.fx)
    with pytest.raises(SimError):
        camera.scaled(0.0)


def test_pixel_rays_have_unit_depth_and_pass_through_pixel_centres():
    rays = CAMERA.pixel_rays()
    assert rays.shape == (CAMERA.height, CAMERA.width, 3)
    assert np.all(rays[..., 2] == 1.0)
    uv, _ = CAMERA.project(rays.reshape(-1, 3))
    cols, rows = np.meshgrid(np.arange(CAMERA.width), np.arange(CAMERA.height))
    assert np.allclose(uv, np.stack([cols.ravel(), rows.ravel()], axis=1), atol=1e-4)
    assert np.allclose(np.linalg.norm(CAMERA.pixel_directions(), axis=-1), 1.0, atol=1e-6)


def test_point_in_front_of_look_at_camera_projects_to_the_image_centre():
    eye, target = np.array([1.0, -2.0, 1.2]), np.array([-0.5, 1.0, 0.8])
    pose = look_at(eye, target)
    camera_from_world = invert_pose(pose)
    uv, z = CAMERA.project(transform_points(camera_from_world, target[None]))
    assert np.allclose(uv[0], [CAMERA.cx, CAMERA.cy], atol=1e-6)
    assert z[0] == pytest.approx(np.linalg.norm(target - eye))
    # OpenCV convention: world up is up in the image (smaller v), the camera's right is larger u.
    right = np.cross(target - eye, [0.0, 0.0, 1.0])
    (u_up, v_up), (u_right, v_right) = CAMERA.project(
        transform_points(camera_from_world, np.array([target + [0.0, 0.0, 0.3], target + 0.3 * right])))[0]
    assert v_up < CAMERA.cy - 10 and abs(u_up - CAMERA.cx) < 1e-6
    assert u_right > CAMERA.cx + 10


def test_backproject_returns_valid_pixels_and_inverts_project():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 5.0, CAMERA.shape).astype(np.float32)
    depth[rng.random(CAMERA.shape) < 0.3] = 0.0
    depth[0, 0] = np.nan
    points, pixels = CAMERA.backproject(depth)
    valid = np.isfinite(depth) & (depth > 0)
    assert points.shape == (valid.sum(), 3) and pixels.shape == (valid.sum(), 2)
    assert np.all(valid[pixels[:, 0], pixels[:, 1]])
    assert np.allclose(points[:, 2], depth[pixels[:, 0], pixels[:, 1]])
    uv, _ = CAMERA.project(points)
    assert np.allclose(uv, pixels[:, ::-1], atol=1e-3)
    with pytest.raises(SimError):
        CAMERA.backproject(depth[:-1])


# --- renderer -----------------------------------------------------------------------------------


def test_wall_renders_exact_z_depth_everywhere():
    view = render_wall(2.0)
    assert view.depth.dtype == np.float32 and view.depth.shape == CAMERA.shape
    # z-depth, not ray length: the same 2.0 at the image corners, where the ray is ~1.16x longer.
    assert np.allclose(view.depth, 2.0, atol=1e-5)
    assert view.instance.dtype == np.uint16 and np.all(view.instance == 0)
    assert np.allclose(view.normals_camera, [0.0, 0.0, -1.0], atol=1e-5)


def test_misses_are_zero_in_every_image():
    box = RenderObject(box_mesh((0.2, 0.2, 0.2), (1.0, 0.0, 0.0)), 3, (0.5, 0.5, 0.5))
    view = SceneRenderer([box]).render(CAMERA, LOOK_ALONG_X)
    miss = view.depth == 0
    assert 0 < miss.mean() < 1
    assert np.all(view.instance[miss] == 0)
    assert np.all(view.rgb[miss] == 0)
    assert np.all(view.normals_camera[miss] == 0)
    assert np.array_equal(view.hit, ~miss)


def test_instance_ids_land_where_the_geometry_projects():
    box_near = box_mesh((0.2, 0.4, 0.2), (1.1, 0.0, 0.0))      # front face at x = 1.0
    box_off = box_mesh((0.2, 0.2, 0.2), (1.6, -0.6, 0.3))      # up and to the camera's right
    renderer = SceneRenderer([wall_at(3.0), RenderObject(box_near, 7, (0.9, 0.2, 0.2)),
                              RenderObject(box_off, 9, (0.2, 0.9, 0.2))])
    view = renderer.render(CAMERA, LOOK_ALONG_X)
    assert set(np.unique(view.instance)) == {0, 7, 9}

    # The front face of box_near, projected, bounds the pixels of instance 7.
    corners = np.array([[1.0, y, z] for y in (-0.2, 0.2) for z in (-0.1, 0.1)])
    uv, _ = CAMERA.project(transform_points(invert_pose(LOOK_ALONG_X), corners))
    (u_min, v_min), (u_max, v_max) = uv.min(axis=0), uv.max(axis=0)
    cols, rows = np.meshgrid(np.arange(CAMERA.width), np.arange(CAMERA.height))
    inside = (cols > u_min + 1) & (cols < u_max - 1) & (rows > v_min + 1) & (rows < v_max - 1)
    outside = (cols < u_min - 1) | (cols > u_max + 1) | (rows < v_min - 1) | (rows > v_max + 1)
    assert np.all(view.instance[inside] == 7)
    assert np.allclose(view.depth[inside], 1.0, atol=1e-5)
    assert not np.any(view.instance[outside] == 7)
    # The other box is to the camera's right (world -y) and above the centre (world +z).
    rows9, cols9 = np.nonzero(view.instance == 9)
    assert cols9.min() > CAMERA.cx and rows9.max() < CAMERA.cy


def test_backprojected_depth_lies_on_the_mesh():
    meshes = [box_mesh((4.0, 4.0, 0.1), (0.0, 0.0, -0.05)), box_mesh((1.2, 0.8, 0.75), (0.0, 0.0, 0.375)),
              box_mesh((0.1, 0.1, 0.15), (0.2, 0.1, 0.825)), box_mesh((0.2, 0.1, 0.3), (-0.3, -0.1, 0.9))]
    pose = look_at(np.array([-1.3, -1.6, 1.4]), np.array([0.0, 0.0, 0.7]))
    view = SceneRenderer([RenderObject(m, i) for i, m in enumerate(meshes)]).render(CAMERA, pose)
    points_camera, _ = CAMERA.backproject(view.depth)
    assert len(points_camera) > 0.5 * CAMERA.width * CAMERA.height
    points_world = transform_points(pose, points_camera)

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(Mesh.concatenate(meshes).to_open3d_tensor())
    distance = scene.compute_distance(o3d.core.Tensor(points_world.astype(np.float32))).numpy()
    assert np.median(distance) < 1e-4
    assert np.percentile(distance, 99.9) < 1e-3


def test_colour_image_is_shaded_and_nonzero_where_geometry_is_hit():
    box = RenderObject(box_mesh((0.5, 0.5, 0.5), (0.0, 0.0, 0.25)), 1, (0.8, 0.3, 0.2))
    floor = RenderObject(box_mesh((4.0, 4.0, 0.1), (0.0, 0.0, -0.05)), 0, (0.7, 0.7, 0.7))
    pose = look_at(np.array([-1.2, -1.6, 1.2]), np.array([0.0, 0.0, 0.2]))
    view = SceneRenderer([floor, box]).render(CAMERA, pose)
    assert view.rgb.dtype == np.uint8 and view.rgb.shape == (*CAMERA.shape, 3)
    hit = view.hit
    assert hit.mean() > 0.5
    assert np.all(view.rgb[hit].max(axis=1) > 0)
    # The three visible faces of the box (top, and two sides) get three different shades.
    box_shades = {tuple(c) for c in view.rgb[view.instance == 1]}
    assert len(box_shades) >= 3
    assert len(np.unique(view.rgb.reshape(-1, 3), axis=0)) > 3


def test_back_faces_are_hit_and_their_normals_face_the_camera():
    # Inside a box, the camera sees the inner (back) faces of its triangles.
    room = RenderObject(box_mesh((4.0, 4.0, 4.0)), 0, (0.5, 0.5, 0.5))
    view = SceneRenderer([room]).render(CAMERA, LOOK_ALONG_X)
    assert np.all(view.depth > 0)
    assert np.all(CAMERA.ray_cosines(view.normals_camera) < 0)
    assert np.allclose(view.depth[CAMERA.height // 2, CAMERA.width // 2], 2.0, atol=1e-5)


def test_render_objects_and_renderer_reject_bad_input():
    with pytest.raises(SimError):
        RenderObject(box_mesh((1, 1, 1)), instance_id=70000)
    with pytest.raises(SimError):
        RenderObject(box_mesh((1, 1, 1)), color=(1.0, 2.0, 0.0))
    with pytest.raises(SimError):
        SceneRenderer([])
    with pytest.raises(SimError):
        SceneRenderer([wall_at(2.0)]).render(CAMERA, np.eye(3))


# --- noise --------------------------------------------------------------------------------------


def test_noise_off_returns_the_depth_unchanged():
    view = render_wall(2.0)
    out = DepthNoise.off().apply(view.depth, view.normals_camera, np.random.default_rng(0), CAMERA)
    assert np.array_equal(out, view.depth) and out is not view.depth


def test_same_seed_gives_the_same_noise():
    view = render_wall(2.0)
    noise = DepthNoise()
    first, second, other = (noise.apply(view.depth, view.normals_camera, np.random.default_rng(seed), CAMERA)
                            for seed in (5, 5, 6))
    assert np.array_equal(first, second)
    assert not np.array_equal(first, other)
    assert first.dtype == np.float32


@pytest.mark.parametrize("distance", [1.0, 3.0])
def test_noise_std_follows_the_model(distance):
    view = render_wall(distance)
    noise = DepthNoise()
    noisy = noise.apply(view.depth, view.normals_camera, np.random.default_rng(1), CAMERA)
    valid = noisy > 0
    assert valid.mean() > 0.95  # a wall facing the camera barely drops out
    std = np.std(noisy[valid] - view.depth[valid])
    # Quantisation adds step^2 / 12 of variance to the Gaussian's.
    step = max(noise.min_step_m, noise.disparity_step_per_m * distance**2)
    expected = math.sqrt(noise.sigma(distance) ** 2 + step**2 / 12)
    assert std == pytest.approx(expected, rel=0.1)


def test_noise_grows_with_distance_and_is_quantised():
    noise = DepthNoise()
    std, values = {}, {}
    for distance in (1.0, 3.0):
        view = render_wall(distance)
        noisy = noise.apply(view.depth, view.normals_camera, np.random.default_rng(2), CAMERA)
        std[distance] = np.std(noisy[noisy > 0] - distance)
        values[distance] = np.unique(noisy[noisy > 0])
    assert std[3.0] > 3 * std[1.0]
    # Whole millimetres, as the recording stores them.
    millimetres = values[1.0] * 1000
    assert np.allclose(millimetres, np.round(millimetres), atol=1e-3)
    # At 3 m the disparity step (c z^2 = 9 mm) is coarser than a millimetre.
    assert np.min(np.diff(values[3.0])) > 0.008


def test_grazing_surfaces_drop_out():
    # A floor 0.5 m below a camera that looks 15 degrees down (the vertical field of view is ~47
    # degrees): incidence angles from ~50 degrees at the bottom of the image to 90 at the horizon.
    floor = RenderObject(box_mesh((40.0, 40.0, 0.1), (0.0, 0.0, -0.55)))
    pose = look_at(np.zeros(3), np.array([1.0, 0.0, -math.tan(math.radians(15.0))]))
    view = SceneRenderer([floor]).render(CAMERA, pose)
    noise = DepthNoise(edge_dropout=0.0, random_dropout=0.0, max_range_m=100.0)
    noisy = noise.apply(view.depth, view.normals_camera, np.random.default_rng(3), CAMERA)
    angle = np.degrees(np.arccos(np.abs(CAMERA.ray_cosines(view.normals_camera))))
    hit = view.depth > 0
    assert np.any(hit & (angle > noise.grazing_full_deg)) and np.any(angle < noise.grazing_start_deg)
    assert np.all(noisy[hit & (angle > noise.grazing_full_deg)] == 0)
    assert np.all(noisy[hit & (angle < noise.grazing_start_deg)] > 0)
    ramp = hit & (angle > noise.grazing_start_deg + 3) & (angle < noise.grazing_full_deg - 3)
    assert 0.1 < np.mean(noisy[ramp] == 0) < 0.9


def test_pixels_at_depth_edges_drop_out():
    box = RenderObject(box_mesh((0.2, 0.4, 0.4), (1.1, 0.0, 0.0)), 1)
    view = SceneRenderer([wall_at(2.0), box]).render(CAMERA, LOOK_ALONG_X)
    # The silhouette: pixels with a 4-neighbour of the other object.
    ids = view.instance
    boundary = np.zeros(ids.shape, dtype=bool)
    boundary[:, 1:] |= ids[:, 1:] != ids[:, :-1]
    boundary[:, :-1] |= ids[:, 1:] != ids[:, :-1]
    boundary[1:, :] |= ids[1:, :] != ids[:-1, :]
    boundary[:-1, :] |= ids[1:, :] != ids[:-1, :]
    assert boundary.sum() > 50
    near_boundary = boundary.copy()
    for axis, shift in ((0, 1), (0, -1), (1, 1), (1, -1)):
        near_boundary |= np.roll(boundary, shift, axis=axis)

    noise = DepthNoise(edge_dropout=1.0, random_dropout=0.0)
    noisy = noise.apply(view.depth, view.normals_camera, np.random.default_rng(4), CAMERA)
    assert np.all(noisy[boundary] == 0)
    assert np.all(noisy[~near_boundary] > 0)

    wider = DepthNoise(edge_dropout=1.0, random_dropout=0.0, edge_width_px=2)
    noisy_wider = wider.apply(view.depth, view.normals_camera, np.random.default_rng(4), CAMERA)
    assert np.all(noisy_wider[near_boundary] == 0)
    no_edges = DepthNoise(edge_dropout=0.0, random_dropout=0.0)
    assert np.all(no_edges.apply(view.depth, view.normals_camera, np.random.default_rng(4), CAMERA) > 0)


def test_random_dropout_and_range_cut():
    view = render_wall(2.0)
    rng = np.random.default_rng(5)
    dropped = DepthNoise(random_dropout=0.1).apply(view.depth, view.normals_camera, rng, CAMERA) == 0
    assert dropped.mean() == pytest.approx(0.1, abs=0.02)
    too_far = DepthNoise(max_range_m=1.5).apply(view.depth, view.normals_camera, rng, CAMERA)
    too_near = DepthNoise(min_range_m=2.5, max_range_m=5.0).apply(view.depth, view.normals_camera, rng, CAMERA)
    assert np.all(too_far == 0) and np.all(too_near == 0)


def test_noise_config_is_checked():
    with pytest.raises(SimError):
        DepthNoise(grazing_start_deg=80.0, grazing_full_deg=70.0)
    with pytest.raises(SimError):
        DepthNoise(min_range_m=5.0, max_range_m=1.0)
    with pytest.raises(SimError):
        DepthNoise(random_dropout=1.5)
    view = render_wall(2.0)
    with pytest.raises(SimError):
        DepthNoise().apply(view.depth[:-1], view.normals_camera, np.random.default_rng(0), CAMERA)
