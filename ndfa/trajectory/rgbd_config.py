"""Settings of the RGB-D odometry (rgbd.py) and the names of the terms a frame is registered with."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ndfa.core.color_camera import ColorCamera
from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M
from ndfa.core.errors import TrajectoryError
from ndfa.trajectory.features import FeatureConfig

# The term a frame was registered with, as reported per frame. "none": the first frame, or a frame
# with too little depth (its pose is the prediction).
HYBRID, INTENSITY, POINT_TO_PLANE, NO_TERM = "hybrid", "intensity", "point-to-plane", "none"


@dataclass(frozen=True)
class RgbdOdometryConfig:
    """RGB-D odometry settings (defaults for a 640x480, 60-90 degree camera at walking pace).

    min_depth_m, max_depth_m: depth used (the method's range, ndfa.core.conventions).
    max_width: images are subsampled by the smallest integer factor that brings them to at most
        this many pixels wide (640 -> 320): 4x less work, and the coarse-to-fine pyramid starts
        from there.
    iterations: at most this many Gauss-Newton iterations per pyramid level, coarsest level first
        (Open3D's order: the last is the `max_width` image itself, each before it half as wide).
    converged_change: a level's iterations stop when an iteration changes both the fitness and the
        inlier RMSE by less than this, relative (Open3D's criteria; its default, 1e-6, almost never
        stops early). Not where a frame without a feature estimate is registered from the
        constant-velocity prediction: those run all iterations (docs/odometry.md, "Iterations that
        stop early").
    depth_outlier_trunc_m: a depth pair farther apart than this is no correspondence.
    depth_huber_delta_m, intensity_huber_delta: Huber scales of the depth (metres) and intensity
        (0-1) residuals.
    degenerate_ratio: the depth term is degenerate when the smallest eigenvalue of its information
        matrix (rotations as arc length at the median depth) is below this fraction of the largest.
    gradient_threshold, textured_fraction: the image is textured when at least `textured_fraction`
        of its valid-depth pixels have an intensity gradient (0-1 per pixel) above the threshold.
    min_valid_fraction: a frame with less valid depth (of its pixels) is not registered.
    min_fitness: a registration whose inlier fraction is below this is rejected.
    max_correction_m: a registration that moves the camera farther than this from the prediction
        is rejected.
    cross_check_m: when a registration moves the camera farther than this from the prediction, the
        other term (hybrid <-> point-to-plane) is tried too and the result nearer the prediction kept.
    keyframe_translation_m, keyframe_rotation_deg, keyframe_min_fitness: a frame becomes the new
        keyframe when it has moved this far or turned this much from the keyframe, or its overlap
        with the keyframe falls below this.
    keyframe_overlap_of_depth: that overlap is the registration's inliers over the frame's pixels
        with depth. False, the default: over all its pixels (Open3D's fitness), so a frame with depth
        on half its pixels never overlaps more than 0.5 and nearly every frame becomes a keyframe.
        Opt-in: fewer keyframes also means fewer chances for a loop (paper-tex source 8 -> 2 loops,
        2.47 -> 2.72 cm; docs/odometry.md, "Prediction first, and the keyframe overlap").
    loop_closure: look for loops among the keyframes and optimise the pose graph in `finish()`.
    loop_radius_m, loop_angle_deg: a loop candidate's view centre (the point its camera looks at,
        at its median depth) is at most this far and its optical axis turned at most this much
        from the new keyframe's, in the current estimate.
    loop_min_gap, loop_min_travel_m: and it is at least this many keyframes older, and the camera
        travelled at least this far from it (nearer ones are the odometry's neighbours, not loops).
    loop_min_inliers: with features, a loop needs this many feature inliers (loop_min_fitness, the
        dense overlap, without).
    loop_max_correction_m: and a loop that corrects the estimate by more than this is refused.
    loop_candidates: at most this many candidates (the nearest) are registered per keyframe.
    keyframe_pairs: after loop closure, register pairs of keyframes that look at the same place
        (as a loop candidate) and whose depth sees every direction, and optimise the graph again
        (`ndfa.trajectory.keyframe_pairs`); only where the loops measured the chain's drift at
        `pair_min_drift` or more (docs/odometry.md, "Pairs where the loops measured drift").
        A pair that moves more than `pair_max_correction_m` from where the loop-closed graph puts
        it is left out.
    pair_min_drift: the pass runs only when the median loop edge's residual before optimisation
        (translation, metres) per metre travelled between its keyframes is at least this; a
        session without a loop is left as it is. 0: always.
    pair_candidates: each keyframe is paired with at most this many older ones, the nearest view
        centres first (0: every one that qualifies).
    pairs_per_frame: at most this many pairs per frame of the session are registered, those that
        span the longest path first, so that the pass's time grows with the frames, not the
        keyframes (0: every candidate).
    pair_voxel_m, pair_iterations: the pairs' coloured ICP runs on points thinned to one per
        `pair_voxel_m` cube, pairs within twice that, for at most `pair_iterations` iterations.
    anchor_to_first_pose: start the estimate at the first frame's given pose (see kiss.py).
    features: sparse feature matching for each frame's first guess (features.py); None: the
        constant-velocity prediction alone.
    min_features: when the frame and its keyframe both have at least this many keypoints but do not
        match, they have too little in common: the previous frame becomes the keyframe (with fewer,
        the images have too little texture for features, and the prediction is used instead).
    prediction_agreement_m, prediction_agreement_deg: a feature-led result farther than this from
        the constant-velocity prediction is checked against the registration from the prediction,
        which replaces it when its overlap (fitness) is `prediction_overlap_ratio` times as large
        (a shift by one period of a repeated pattern overlaps far less; a real jerk overlaps about
        as well or better from the features).
    feature_agreement_m, feature_agreement_deg: a dense registration that lands farther than this
        from the feature estimate it started at fell into another minimum: the feature estimate is
        kept instead.
    unseen_from_prediction, unseen_ratio: a registration from the prediction whose chosen term is
        one of these keeps the prediction along the directions the frame's depth cannot see
        (eigenvalues of its plane term, normals over a baseline of a fixed share of the image,
        `degeneracy.unseen_information`, below `unseen_ratio` times the largest: a bare wall's
        slide and roll), and such a frame does not update the velocity
        (`degeneracy.keep_prediction_where_unseen`); () turns this off. ("point-to-plane",), the
        default: the term an untextured frame is registered with; hybrid's intensity residuals
        still carry some of the slide on a wall's faint texture (docs/odometry.md).
    hybrid_where_unseen: an untextured frame (point-to-plane) whose depth leaves some direction
        unseen and whose result lands beyond `cross_check_m` from the prediction is registered by
        hybrid too, when both images have colour; the result nearer the prediction wins. A bare
        wall's colour can fall below the `textured` test and still pin the slide depth cannot see
        (the office's seed 3 target: hybrid 0.1-0.7 cm off per frame, point-to-plane 10-19 cm);
        with no texture at all hybrid slides as point-to-plane does, and point-to-plane with the
        prediction kept where unseen stays the choice (docs/odometry.md).
    faint_wall_keyframes: a frame tracked across such a wall by hybrid, and each frame after it
        tracked from the prediction until features take over, becomes a keyframe: hybrid's error
        on the faint texture grows with the baseline (2.9-5.7 cm on 5-frame keyframe edges against
        0.3-0.7 cm frame to frame there).
    faint_wall_contrast_px, faint_wall_contrast_gain: on those frames (a faint wall, and the
        frames after it until features take over) the intensity term compares the images' local
        contrast, the intensity less its Gaussian blur over this many pixels of the subsampled
        image, times the gain (`rgbd_view.local_contrast`): a light on the camera, vignetting or
        auto-exposure shade the image smoothly with the camera, and on faint texture that pulls
        the term towards no motion (docs/odometry.md). 0: the colour as it is.
    color_camera: the colour camera when the colour is not registered to the depth (a recording's
        meta says so: `ndfa.core.color_camera`, `session.rgbd_config_for`); each frame's colour is then
        carried onto its depth pixels before features and the intensity term use it. None: registered.
    prediction_first, prediction_first_overlap, prediction_first_max_m, prediction_first_max_deg,
    prediction_first_in_a_row: opt-in (False, the default: features on every frame). A textured
        frame (hybrid) that the prediction does not already make a keyframe is first registered
        densely from the constant-velocity prediction alone; that result stands, and the frame's
        features are never made, when it overlaps the keyframe by at least
        `prediction_first_overlap` (inliers over the pixels with depth), lands within
        `prediction_first_max_m` and `prediction_first_max_deg` of the prediction, does not make
        the frame a keyframe, and fewer than `prediction_first_in_a_row` frames just before it were
        registered so (a run of them drifts: each lands near a prediction that carries the last
        one's error). Otherwise the frame goes the feature way as before, so every keyframe edge is
        measured from features. Not the default: it costs the kitchen and the office accuracy
        (docs/odometry.md, "Prediction first, and the keyframe overlap").
    velocity_in_world: the constant-velocity model repeats the last shift in the world's frame
        (a person walking straight while panning the camera) instead of the camera's (a vehicle
        that turns with its heading); the turn is repeated in the camera's frame either way.
    """

    min_depth_m: float = MIN_DEPTH_M
    max_depth_m: float = MAX_DEPTH_M
    max_width: int = 320
    iterations: tuple[int, ...] = (10, 10, 10)
    converged_change: float = 1e-3
    depth_outlier_trunc_m: float = 0.07
    depth_huber_delta_m: float = 0.05
    intensity_huber_delta: float = 0.1
    degenerate_ratio: float = 0.003
    gradient_threshold: float = 0.02
    textured_fraction: float = 0.003
    min_valid_fraction: float = 0.05
    min_fitness: float = 0.1
    max_correction_m: float = 0.3
    cross_check_m: float = 0.015
    keyframe_translation_m: float = 0.3
    keyframe_rotation_deg: float = 15.0
    keyframe_min_fitness: float = 0.4
    loop_closure: bool = True
    loop_radius_m: float = 1.0
    loop_angle_deg: float = 45.0
    loop_min_gap: int = 8
    loop_min_travel_m: float = 2.0
    loop_min_fitness: float = 0.3
    loop_min_inliers: int = 40
    loop_max_correction_m: float = 1.0
    loop_candidates: int = 2
    keyframe_pairs: bool = True
    pair_max_correction_m: float = 0.1
    pair_min_drift: float = 0.01
    pair_candidates: int = 3
    pairs_per_frame: float = 0.1
    pair_voxel_m: float = 0.03
    pair_iterations: int = 30
    anchor_to_first_pose: bool = True
    features: FeatureConfig | None = field(default_factory=FeatureConfig)
    min_features: int = 100
    prediction_agreement_m: float = 0.1
    prediction_agreement_deg: float = 5.0
    prediction_overlap_ratio: float = 2.0
    feature_agreement_m: float = 0.05
    feature_agreement_deg: float = 3.0
    unseen_from_prediction: tuple[str, ...] = (POINT_TO_PLANE,)
    unseen_ratio: float = 0.005
    hybrid_where_unseen: bool = True
    faint_wall_keyframes: bool = True
    faint_wall_contrast_px: float = 8.0
    faint_wall_contrast_gain: float = 4.0
    velocity_in_world: bool = True
    keyframe_overlap_of_depth: bool = False
    prediction_first: bool = False
    prediction_first_overlap: float = 0.4
    prediction_first_max_m: float = 0.02
    prediction_first_max_deg: float = 2.0
    prediction_first_in_a_row: int = 1
    color_camera: ColorCamera | None = None

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_depth_m < self.max_depth_m:
            raise TrajectoryError(f"rgbd odometry needs 0 <= min_depth_m < max_depth_m, got {self.min_depth_m}, {self.max_depth_m}")
        if self.max_width < 16 or not self.iterations or min(self.iterations) < 1:
            raise TrajectoryError(f"rgbd odometry needs max_width >= 16 and iterations >= 1, got {self.max_width}, {self.iterations}")
        for name in ("depth_outlier_trunc_m", "depth_huber_delta_m", "intensity_huber_delta", "max_correction_m",
                     "keyframe_translation_m", "keyframe_rotation_deg", "loop_radius_m"):
            if not getattr(self, name) > 0.0:
                raise TrajectoryError(f"rgbd odometry {name} must be > 0, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        """Plain values, for provenance in a recording's meta."""
        return dataclasses.asdict(self)
