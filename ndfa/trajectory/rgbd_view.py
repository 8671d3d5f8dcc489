"""One frame prepared for RGB-D registration, and Open3D's dense terms on a pair of them (rgbd.py's
odometry and loop closure use both)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.frame import Frame
from ndfa.trajectory.degeneracy import plane_information, textured_fraction, unseen_information
from ndfa.trajectory.features import Features, detect_features, no_features
from ndfa.trajectory.rgbd_config import HYBRID, INTENSITY, POINT_TO_PLANE, RgbdOdometryConfig

# A relative change no iteration meets (Open3D's default): every level runs all its iterations.
ALL_ITERATIONS = 1e-6


@dataclass
class View:
    """One frame prepared for registration: subsampled images as Open3D tensors."""

    rgbd: object  # open3d.t.geometry.RGBDImage (colour uint8, depth float32 metres, 0 = invalid)
    features: Features | None  # ORB keypoints of the full-resolution image (none without colour); None: not yet made (`keypoints`)
    K: object  # open3d.core.Tensor (3, 3) float64, of the subsampled image
    plane_information: np.ndarray  # (6, 6) of the frame's own point-to-plane term (`plane_information`)
    unseen_information: np.ndarray  # the same from normals over a wider baseline: what depth cannot see
    median_depth_m: float
    valid_fraction: float
    textured: bool
    coloured: bool = True  # False: the frame had no colour (its image is zeros)
    contrast: View | None = field(default=None, repr=False)  # `local_contrast`'s, once made
    # What `keypoints` makes the features from when they were deferred: grey image, depth, K, settings.
    pending: tuple | None = field(default=None, repr=False)


def keypoints(view: View) -> Features:
    """The view's ORB features, made now if `prepare_view` deferred them (and kept)."""
    if view.features is None:
        assert view.pending is not None
        gray, depth, K, feature_config = view.pending
        view.features = detect_features(gray, depth, K, feature_config)
        view.pending = None
    return view.features


def prepare_view(frame: Frame, config: RgbdOdometryConfig, defer_features: bool = False) -> View:
    """Subsample the frame to at most `max_width` pixels wide, drop depth out of range, and
    wrap the images as Open3D tensors. defer_features: the ORB features are made only when
    `keypoints` first asks for them (a frame the odometry registers without them never pays)."""
    import open3d as o3d

    height, width = frame.image_size
    step = max(1, math.ceil(width / config.max_width))
    depth = frame.depth[::step, ::step].copy()
    depth[~(np.isfinite(depth) & (depth >= config.min_depth_m) & (depth <= config.max_depth_m))] = np.nan
    rows, cols = depth.shape
    full_rgb = frame.rgb
    if full_rgb is not None and config.color_camera is not None:
        full_rgb = config.color_camera.register_to_depth(full_rgb, frame.depth, frame.K)
    if full_rgb is not None:
        # Blurred, then every step-th pixel: intensity residuals need an image without aliasing,
        # and centred on the depth samples (a block mean is centred half a pixel off them, and
        # the intensity term then pulls every frame's rotation the same way).
        rgb = full_rgb if step == 1 else _smooth(full_rgb, step)
        rgb = rgb[::step, ::step][:rows, :cols]
    else:
        rgb = np.zeros((rows, cols, 3), np.uint8)
    valid = np.isfinite(depth)
    features: Features | None = no_features(frame.K)
    pending = None
    if full_rgb is not None and config.features is not None:
        full_depth = np.where(frame.depth >= config.min_depth_m, frame.depth, np.nan)
        gray = (full_rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.uint8)
        if defer_features:
            features, pending = None, (gray, full_depth, frame.K, config.features)
        else:
            features = detect_features(gray, full_depth, frame.K, config.features)
    K = frame.K.copy()
    K[:2] /= step  # pixel (step*i) becomes pixel i: centres at integer coordinates stay so
    rgbd = o3d.t.geometry.RGBDImage(_owned_image(rgb), _owned_image(depth[..., None]))
    return View(rgbd=rgbd, features=features, K=o3d.core.Tensor(K), plane_information=plane_information(depth, K),
                unseen_information=unseen_information(depth, K),
                 median_depth_m=float(np.median(depth[valid])) if valid.any() else 1.0,
                 valid_fraction=float(valid.mean()),
                 textured=frame.rgb is not None and textured_fraction(rgb, valid, config.gradient_threshold) >= config.textured_fraction,
                 coloured=frame.rgb is not None, pending=pending)


def _owned_image(array: np.ndarray) -> object:
    """An Open3D image holding its own copy of `array`. `o3d.t.geometry.Image(array)` shares the
    numpy buffer without keeping it alive: once the array is freed the image reads whatever memory
    takes its place, and the same frames gave other poses from run to run (2026-12-07)."""
    import open3d as o3d

    return o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(array)))


def local_contrast(view: View, sigma_px: float, gain: float) -> View:
    """The view with its colour replaced by its local contrast: the intensity less its Gaussian
    blur over `sigma_px` pixels (of the view's image), times `gain`, about mid-grey; depth as it was.
    Made once per view and kept on it.

    Why: the intensity term assumes a surface's brightness does not change with the viewpoint. A
    light on the camera, vignetting or auto-exposure change it smoothly across the image, with the
    camera; where the texture is faint that smooth pattern outweighs it, and the term is pulled
    towards no motion against the pattern (docs/odometry.md, "Local contrast on faint walls")."""
    if view.contrast is None:
        import cv2
        import open3d as o3d

        rgb = view.rgbd.color.as_tensor().numpy()  # type: ignore[attr-defined]
        gray = rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
        detail = gray - cv2.GaussianBlur(gray, (0, 0), sigmaX=sigma_px)
        image = np.clip(128.0 + gain * detail + 0.5, 0.0, 255.0).astype(np.uint8)
        rgbd = o3d.t.geometry.RGBDImage(_owned_image(np.repeat(image[..., None], 3, axis=2)),
                                        view.rgbd.depth)  # type: ignore[attr-defined]
        view.contrast = dataclasses.replace(view, rgbd=rgbd)
    return view.contrast


def register_dense(source: View, target: View, initial: np.ndarray, term: str,
               config: RgbdOdometryConfig, early_stop: bool = True) -> tuple[np.ndarray | None, float]:
    """T_target_source by RGB-D odometry from `initial`, and its fitness (None, 0 when it failed).
    early_stop: each level stops at `config.converged_change`; otherwise it runs all its iterations."""
    import open3d as o3d

    odometry = o3d.t.pipelines.odometry
    method = {HYBRID: odometry.Method.Hybrid, INTENSITY: odometry.Method.Intensity,
              POINT_TO_PLANE: odometry.Method.PointToPlane}[term]
    change = config.converged_change if early_stop else ALL_ITERATIONS
    criteria = [odometry.OdometryConvergenceCriteria(iterations, change, change) for iterations in config.iterations]
    params = odometry.OdometryLossParams(config.depth_outlier_trunc_m, config.depth_huber_delta_m,
                                         config.intensity_huber_delta)
    try:
        result = odometry.rgbd_odometry_multi_scale(
            source.rgbd, target.rgbd, source.K, o3d.core.Tensor(initial), 1.0, config.max_depth_m,
            criteria, method, params)
    except RuntimeError:  # Open3D raises when a pyramid level has no correspondences
        return None, 0.0
    transform = result.transformation.numpy()
    if not np.all(np.isfinite(transform)):
        return None, 0.0
    return transform, float(result.fitness)

def depth_information(source: View, target: View, target_from_source: np.ndarray,
                  config: RgbdOdometryConfig) -> np.ndarray:
    """The depth term's 6x6 information matrix of T_target_source (Open3D's (rotation,
    translation) order); zeros when there are no correspondences."""
    import open3d as o3d

    try:
        information = o3d.t.pipelines.odometry.compute_odometry_information_matrix(
            source.rgbd.depth, target.rgbd.depth, source.K, o3d.core.Tensor(target_from_source),
            config.depth_outlier_trunc_m, 1.0, config.max_depth_m).numpy()
    except RuntimeError:
        return np.zeros((6, 6))
    return information if np.all(np.isfinite(information)) else np.zeros((6, 6))


def _smooth(image: np.ndarray, step: int) -> np.ndarray:
    """A Gaussian blur wide enough to subsample `image` by `step` without aliasing."""
    import cv2

    return cv2.GaussianBlur(image, (0, 0), sigmaX=0.5 * step)

