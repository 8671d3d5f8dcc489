"""A wide-basin first guess of the camera motion from sparse visual features.

Why: dense RGB-D odometry (rgbd.py) converges only from a guess within a few centimetres and
degrees of the answer (its pyramid and its linearised residuals see no farther). A hand-held or
simulated camera can move more than that between frames, and once the constant-velocity guess is
off by more than the basin, the error feeds the next prediction and snowballs. Features matched by
appearance do not need a guess at all: ORB keypoints (corners with a binary descriptor that
survives rotation and moderate viewpoint change) are matched between a frame and its keyframe,
lifted to 3D with the depth, and the rigid motion that most matches agree on is found by RANSAC
over three-point Kabsch fits. The dense refinement then starts inside its basin.

Agreement is what makes the estimate trustworthy: a motion is returned only when enough matches
(`min_inliers`), and enough of the matches (`min_inlier_ratio`), agree with it, spread over the
image rather than on one line. Dark or untextured images give few keypoints and no estimate; the
caller then falls back to its prediction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import TrajectoryError
from ndfa.core.geometry import kabsch


@dataclass(frozen=True)
class FeatureConfig:
    """Sparse feature matching settings (defaults for 640x480 colour at walking pace).

    max_features: ORB keypoints detected per image (the strongest by corner response).
    max_depth_m: keypoints farther than this are dropped. Beyond the dense odometry's range on
        purpose: far walls often carry the most distinct corners (pictures, doors), and the
        reprojection fit (`_refine_reprojection`) uses their precise pixels whatever their depth noise.
    fast_threshold: intensity step (0-255) of OpenCV's FAST corner test; lower than OpenCV's 20
        so that the soft, low-contrast texture of floors and walls still yields corners.
    edge_radius_px, edge_fraction: keypoints are detected only where the depth within this radius
        is valid and varies by less than this fraction of itself (no silhouettes, see
        `_smooth_depth_mask`).
    ratio: a match is kept when its descriptor distance is below this fraction of the second-best
        candidate's (Lowe's ratio test: repeated patterns have no clear best match).
    ransac_hypotheses: three-point samples tried.
    inlier_base_m, inlier_per_m2: a match is an inlier of a motion when its 3D points end up
        within inlier_base_m + inlier_per_m2 * z^2 of each other (depth noise grows with z^2).
    min_inliers, min_inlier_ratio: a motion is accepted with at least this many inliers and this
        fraction of the matches.
    min_spread_m: and the inliers' 3D points spread at least this far along their second principal
        axis (matches along one edge leave the rotation about it free).
    seed: of the RANSAC sampling (the same frames give the same estimate).
    ransac_confidence: RANSAC stops once the hypotheses tried would, with this probability, have
        drawn one all-inlier sample at the best hypothesis's inlier ratio (tried in batches of
        `RANSAC_BATCH`, in the order drawn, so it keeps the first best as all of them would). 0:
        all `ransac_hypotheses`.
    """

    max_features: int = 1000
    max_depth_m: float = 8.0
    fast_threshold: int = 5
    edge_radius_px: int = 3
    edge_fraction: float = 0.05
    ratio: float = 0.8
    ransac_hypotheses: int = 256
    inlier_base_m: float = 0.01
    inlier_per_m2: float = 0.005
    min_inliers: int = 20
    min_inlier_ratio: float = 0.25
    min_spread_m: float = 0.1
    seed: int = 0
    ransac_confidence: float = 0.0

    def __post_init__(self) -> None:
        if self.max_features < 8 or self.ransac_hypotheses < 1 or self.min_inliers < 3:
            raise TrajectoryError(f"feature matching needs max_features >= 8, ransac_hypotheses >= 1, min_inliers >= 3; "
                                  f"got {self.max_features}, {self.ransac_hypotheses}, {self.min_inliers}")
        if not 0.0 < self.ratio <= 1.0 or not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise TrajectoryError(f"feature ratio must be in (0, 1] and min_inlier_ratio in [0, 1], got {self.ratio}, {self.min_inlier_ratio}")
        if not 0.0 <= self.ransac_confidence < 1.0:
            raise TrajectoryError(f"ransac_confidence must be in [0, 1), got {self.ransac_confidence}")


# Hypotheses scored at a time when RANSAC may stop early (`FeatureConfig.ransac_confidence`).
RANSAC_BATCH = 32


@dataclass(frozen=True)
class Features:
    """ORB keypoints of one image that have valid depth: their pixels (N, 2), 3D points in the
    camera frame (N, 3), binary descriptors (N, 32) uint8, and the camera's intrinsics (3, 3)."""

    pixels: np.ndarray
    points: np.ndarray
    descriptors: np.ndarray
    K: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


@dataclass(frozen=True)
class FeatureMotion:
    """A motion T_target_source (4, 4) found by `estimate_motion`, with its support: the inlier
    count, and the inlier fraction of the matches."""

    target_from_source: np.ndarray
    inliers: int
    inlier_ratio: float


def detect_features(gray: np.ndarray, depth: np.ndarray, K: np.ndarray, config: FeatureConfig = FeatureConfig()) -> Features:
    """ORB keypoints of the 8-bit grey image `gray` where the aligned `depth` (metres, NaN or 0 =
    invalid) is valid, lifted to 3D with the intrinsics `K`."""
    import cv2

    orb = cv2.ORB_create(nfeatures=config.max_features, fastThreshold=config.fast_threshold)
    keypoints, descriptors = orb.detectAndCompute(np.ascontiguousarray(gray), _smooth_depth_mask(depth, config))
    if descriptors is None or not keypoints:
        return no_features(K)
    pixels = cv2.KeyPoint_convert(keypoints).astype(np.float64)  # (N, 2): the float32 pixels, as `keypoint.pt` gives them
    cols = np.clip(np.round(pixels[:, 0]).astype(int), 0, depth.shape[1] - 1)
    rows = np.clip(np.round(pixels[:, 1]).astype(int), 0, depth.shape[0] - 1)
    z = depth[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0) & (z <= config.max_depth_m)
    u, v, z = pixels[valid, 0], pixels[valid, 1], z[valid]
    points = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    return Features(pixels[valid], points, descriptors[valid], np.asarray(K, dtype=np.float64))


def no_features(K: np.ndarray) -> Features:
    """The features of an image without any (no colour, or no corner with depth)."""
    return Features(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 32), np.uint8), np.asarray(K, dtype=np.float64))


def _smooth_depth_mask(depth: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """Where a keypoint's depth can be trusted (uint8 mask, 255 = yes): valid depth all around it
    and no depth edge nearby. The strongest corners are often silhouettes, whose pixels mix the
    object and what is behind it, and far surfaces out of the depth range: without the mask they
    would take most of the keypoint budget and give no usable 3D point."""
    import cv2

    # NaN fails both comparisons. One image serves both filters: where the lowest depth around is
    # positive every pixel around is valid, so the highest there is the highest of valid depths.
    kept = np.where((depth > 0) & (depth <= config.max_depth_m), depth, 0).astype(np.float32, copy=False)
    window = np.ones((2 * config.edge_radius_px + 1,) * 2, np.uint8)
    highest = cv2.dilate(kept, window)
    lowest = cv2.erode(kept, window)  # 0 near invalid depth
    smooth = (highest - lowest) < config.edge_fraction * lowest
    return (smooth & (lowest > 0)).view(np.uint8) * np.uint8(255)


def match(source: Features, target: Features, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices (source, target) of the descriptor matches that pass the ratio test."""
    import cv2

    if len(source) < 2 or len(target) < 2:
        return np.zeros(0, int), np.zeros(0, int)
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(source.descriptors, target.descriptors, k=2)
    good = np.array([(pair[0].queryIdx, pair[0].trainIdx) for pair in pairs
                     if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance], dtype=int).reshape(-1, 2)
    return good[:, 0], good[:, 1]


def estimate_motion(source: Features, target: Features, config: FeatureConfig = FeatureConfig()) -> FeatureMotion | None:
    """T_target_source from the features of two images: the pose of the source camera in the target
    camera's frame (what registering source onto target returns). None when the matches do not
    agree on a motion clearly enough (see the module docstring)."""
    source_index, target_index = match(source, target, config.ratio)
    matches = len(source_index)
    if matches < config.min_inliers:
        return None
    moving, fixed = source.points[source_index], target.points[target_index]
    tolerance = config.inlier_base_m + config.inlier_per_m2 * fixed[:, 2] ** 2
    inliers = _ransac(moving, fixed, tolerance, config)
    for _ in range(2):  # refit on the inliers, then take the inliers of the refit
        if inliers.sum() < config.min_inliers:
            return None
        transform, _ = kabsch(moving[inliers], fixed[inliers])
        inliers = _residuals(transform[None], moving, fixed)[0] < tolerance
    count = int(inliers.sum())
    if count < config.min_inliers or count < config.min_inlier_ratio * matches:
        return None
    if _spread(fixed[inliers]) < config.min_spread_m:
        return None
    transform, _ = kabsch(moving[inliers], fixed[inliers])
    transform = _refine_reprojection(transform, fixed[inliers], source.pixels[source_index[inliers]], source.K)
    return FeatureMotion(transform, count, count / matches)


def _refine_reprojection(target_from_source: np.ndarray, target_points: np.ndarray, source_pixels: np.ndarray,
                         K: np.ndarray) -> np.ndarray:
    """The motion refined to fit the target's 3D points to where the source image saw them
    (Levenberg-Marquardt on reprojection error). Why: the 3D fit weighs each point's depth noise,
    which grows with z^2, as much as its position; a keypoint's pixel is precise to a fraction of a
    pixel, so the reprojection fit is several times tighter at a few metres."""
    import cv2

    source_from_target = np.linalg.inv(target_from_source)
    rotation_vector, _ = cv2.Rodrigues(source_from_target[:3, :3])
    found, rotation_vector, translation = cv2.solvePnP(
        target_points.reshape(-1, 1, 3), source_pixels.reshape(-1, 1, 2).astype(np.float64), K, None,
        rotation_vector, source_from_target[:3, 3].reshape(3, 1).copy(), useExtrinsicGuess=True,
        flags=cv2.SOLVEPNP_ITERATIVE)
    if not found or not np.all(np.isfinite(translation)):
        return target_from_source
    refined = np.eye(4)
    refined[:3, :3] = cv2.Rodrigues(rotation_vector)[0]
    refined[:3, 3] = translation.ravel()
    return np.linalg.inv(refined)


def _ransac(moving: np.ndarray, fixed: np.ndarray, tolerance: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """The inlier mask of the best-supported three-point hypothesis (the first of the best, in the
    order drawn), scored all at once, or batch by batch until `ransac_confidence` is reached."""
    rng = np.random.default_rng(config.seed)
    # A sample that repeats a match is a degenerate fit that few matches support: it loses the vote.
    samples = rng.integers(0, len(moving), (config.ransac_hypotheses, 3))
    batch = len(samples) if config.ransac_confidence <= 0.0 else RANSAC_BATCH
    best, best_count = np.zeros(len(moving), bool), -1
    for start in range(0, len(samples), batch):
        chosen = samples[start:start + batch]
        inliers = _residuals(_kabsch_batch(moving[chosen], fixed[chosen]), moving, fixed) < tolerance
        counts = inliers.sum(axis=1)
        top = int(np.argmax(counts))
        if counts[top] > best_count:
            best, best_count = inliers[top], int(counts[top])
        if start + batch < len(samples) and start + batch >= _hypotheses_needed(best_count / len(moving), config.ransac_confidence):
            break
    return best


def _hypotheses_needed(inlier_ratio: float, confidence: float) -> float:
    """How many three-point samples draw at least one of inliers alone with probability `confidence`."""
    all_inliers = inlier_ratio ** 3
    if all_inliers <= 0.0:
        return math.inf
    if all_inliers >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log(1.0 - all_inliers)


def _kabsch_batch(moving: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Kabsch fits (H, 4, 4) of H point triples (H, 3, 3); a degenerate triple gives some rotation
    that few matches support, so it loses the vote by itself."""
    moving_mean, fixed_mean = moving.mean(axis=1, keepdims=True), fixed.mean(axis=1, keepdims=True)
    covariance = np.swapaxes(fixed - fixed_mean, 1, 2) @ (moving - moving_mean)
    u, _, vt = np.linalg.svd(covariance)
    flip = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= flip[:, None]
    rotation = u @ vt
    transforms = np.tile(np.eye(4), (len(moving), 1, 1))
    transforms[:, :3, :3] = rotation
    transforms[:, :3, 3] = fixed_mean[:, 0] - (rotation @ moving_mean[:, 0, :, None])[..., 0]
    return transforms


def _residuals(transforms: np.ndarray, moving: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Distances (H, N) between the fixed points and the moving points under each transform."""
    # All H rotations in one (N, 3) x (3, 3H) product: one BLAS call instead of H small ones.
    count = len(transforms)
    stacked = transforms[:, :3, :3].transpose(2, 0, 1).reshape(3, 3 * count)  # [j, 3h + i] = R_h[i, j]
    moved = (moving @ stacked).reshape(len(moving), count, 3) + transforms[None, :, :3, 3]
    difference = moved - fixed[:, None, :]
    return np.sqrt(np.einsum("nhk,nhk->hn", difference, difference))


def _spread(points: np.ndarray) -> float:
    """Standard deviation of the points along their second principal axis, metres."""
    if len(points) < 3:
        return 0.0
    singular = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(singular[1] / math.sqrt(len(points)))
