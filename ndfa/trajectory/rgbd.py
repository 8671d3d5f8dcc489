"""Camera poses from colour and depth: frame-to-keyframe RGB-D odometry with loop closure.

Why not depth alone (kiss.py): indoors a depth camera often sees only a wall and the floor, and
two planes leave the slide along their intersection unconstrained; KISS-ICP lost the synthetic
`paper` scene's target session that way. Colour pins that slide down wherever the surfaces carry
texture. Dense RGB-D odometry (Open3D's tensor `rgbd_odometry_multi_scale`: projective
association, a coarse-to-fine image pyramid, Huber losses on depth and intensity residuals) uses
both terms at once.

Per frame:
1. First guess from features (features.py): ORB keypoints matched to the keyframe's, lifted to 3D,
   RANSAC over three-point fits. They need no prior, so a step of 8-10 cm and 5 degrees, beyond
   the dense terms' basin, is still found. When the keyframe has too little left in common with
   the frame (both have keypoints but they do not match), the previous frame becomes the keyframe
   and the frame is matched to it. Without enough keypoints (dark, untextured, no colour) the
   guess is the constant-velocity prediction (the last motion again).
2. Degeneracy check: the 6x6 information matrix of the depth term (point-to-plane) of the frame.
   Rotations are rescaled to arc length at the median depth so both halves are in metres; a
   smallest eigenvalue far below the largest means a direction depth cannot see
   (`degenerate_ratio`). The image is textured when enough pixels have an intensity gradient.
   Term used: degenerate and textured -> intensity alone (the depth term would only pull the slide
   toward the guess); untextured (dark, or no colour) -> point-to-plane alone (the intensity term
   would fit noise); otherwise the hybrid of both.
3. Dense registration to the keyframe (not the previous frame: errors then add up per keyframe,
   not per frame) from the guess. From a feature guess, a result that leaves it by more than a few
   centimetres or degrees fell into another minimum, and the feature estimate is kept. From the
   prediction, the other term is tried when the result lands far from it (the nearer wins), and a
   result with too little overlap or too large a correction is rejected.
4. A new keyframe when the motion since the keyframe, or its overlap with it, passes a threshold.
   Each new keyframe is matched (features, then dense) to old keyframes that look at the same
   place in the current estimate but lie far back along the path; a verified match is a loop
   edge (pose_graph.py). Features need no guess, so loops are found however far the odometry
   drifted.

`finish()` optimises the keyframe graph and returns every frame's pose: a non-keyframe keeps its
pose relative to its keyframe, so it follows the keyframe's correction. Callers that write each
frame as it comes can use `update`'s poses, the odometry alone (the importers instead write first
and replace the poses with the whole-session estimate: rewrite.py).

World frame: as kiss.py, the estimate starts at the first frame's given pose (`anchor_to_first_pose`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M
from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.trajectory.checks import GapClock
from ndfa.trajectory.degeneracy import depth_degeneracy, plane_information, textured_fraction
from ndfa.trajectory.features import (
    FeatureConfig,
    FeatureMotion,
    Features,
    detect_features,
    estimate_motion,
    no_features,
)
from ndfa.trajectory.pose_graph import PoseEdge, PoseGraphConfig, optimize_pose_graph

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
    iterations: Gauss-Newton iterations per pyramid level, finest level first (Open3D's order).
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
        (fitness) with the keyframe falls below this.
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
    """

    min_depth_m: float = MIN_DEPTH_M
    max_depth_m: float = MAX_DEPTH_M
    max_width: int = 320
    iterations: tuple[int, ...] = (10, 10, 10)
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
    anchor_to_first_pose: bool = True
    features: FeatureConfig | None = field(default_factory=FeatureConfig)
    min_features: int = 100
    prediction_agreement_m: float = 0.1
    prediction_agreement_deg: float = 5.0
    prediction_overlap_ratio: float = 2.0
    feature_agreement_m: float = 0.05
    feature_agreement_deg: float = 3.0

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


@dataclass
class _View:
    """One frame prepared for registration: subsampled images as Open3D tensors."""

    rgbd: object  # open3d.t.geometry.RGBDImage (colour uint8, depth float32 metres, 0 = invalid)
    features: Features  # ORB keypoints of the full-resolution image (none without colour)
    K: object  # open3d.core.Tensor (3, 3) float64, of the subsampled image
    plane_information: np.ndarray  # (6, 6) of the frame's own point-to-plane term (`plane_information`)
    median_depth_m: float
    valid_fraction: float
    textured: bool


@dataclass
class _Keyframe:
    frame: int  # index of the frame in the session
    pose: np.ndarray  # (4, 4) odometry pose, in the first camera's frame
    view: _View
    travelled_m: float  # path length from the first keyframe, metres (odometry)


@dataclass
class RgbdOdometry:
    """Frame-to-keyframe RGB-D odometry with loop closure; see the module docstring. One instance
    per session, frames in time order: `update(frame)` per frame, then `finish()` once."""

    config: RgbdOdometryConfig = field(default_factory=RgbdOdometryConfig)

    def __post_init__(self) -> None:
        import cv2  # noqa: F401  (imported here, once, so that no frame's time counts the imports)
        import open3d  # noqa: F401

        self._anchor: np.ndarray | None = None
        self._poses: list[np.ndarray] = []  # odometry pose of every frame (first camera's frame)
        self._keyframe_of: list[int] = []  # per frame, the index of its keyframe in self.keyframes
        self.keyframes: list[_Keyframe] = []
        self.edges: list[PoseEdge] = []
        self.terms: list[str] = []  # per frame, the term it was registered with
        self.degenerate: list[bool] = []  # per frame, whether depth alone was ambiguous
        self.starved_frames = 0  # too little valid depth: not registered
        self._clock = GapClock()
        self.rejected_frames = 0  # registration rejected: the prediction kept
        self._previous: tuple[_View, np.ndarray] | None = None  # last frame if not a keyframe: view, T_keyframe_frame
        self.promoted_frames = 0  # previous frames made keyframes when the keyframe had too little in common
        self.feature_frames = 0  # frames whose first guess came from feature matches
        self.prediction_wins = 0  # feature-led result far from the prediction, and the prediction's overlapped better
        self.feature_fallbacks = 0  # dense result left the feature estimate, even after promoting: the latter kept
        self.seconds = 0.0

    @property
    def frames(self) -> int:
        return len(self._poses)

    @property
    def loop_closures(self) -> int:
        return sum(edge.loop for edge in self.edges)

    @property
    def degenerate_frames(self) -> list[int]:
        """Indices of the frames whose depth term was degenerate."""
        return [index for index, flag in enumerate(self.degenerate) if flag]

    @property
    def ms_per_frame(self) -> float:
        """Mean time per frame of `update` and `finish`, milliseconds (NaN before the first frame)."""
        return 1000.0 * self.seconds / self.frames if self.frames else float("nan")

    def update(self, frame: Frame) -> np.ndarray:
        """Register `frame`; its (4, 4) camera-to-world pose by odometry alone (before loop closure)."""
        started = time.perf_counter()
        if self._anchor is None:
            self._anchor = frame.pose_world_camera.copy() if self.config.anchor_to_first_pose else np.eye(4)
        view = self._prepare(frame)
        pose, term, degenerate = self._track(view, after_gap=self._clock.after_gap(frame.timestamp))
        self._poses.append(pose)
        self.terms.append(term)
        self.degenerate.append(degenerate)
        self._keyframe_of.append(len(self.keyframes) - 1)
        self.seconds += time.perf_counter() - started
        return self._anchor @ pose

    def finish(self) -> list[np.ndarray]:
        """Every frame's (4, 4) camera-to-world pose after loop closure (the odometry's where there
        was no loop)."""
        started = time.perf_counter()
        odometry = [keyframe.pose for keyframe in self.keyframes]
        corrected = odometry
        if self.config.loop_closure and self.loop_closures:
            graph = PoseGraphConfig(max_correspondence_distance_m=self.config.loop_max_correction_m)
            corrected = optimize_pose_graph(odometry, self.edges, graph)
        poses = []
        for pose, keyframe in zip(self._poses, self._keyframe_of):
            if keyframe >= 0:
                pose = corrected[keyframe] @ np.linalg.inv(odometry[keyframe]) @ pose
            poses.append(self._anchor @ pose)
        self.seconds += time.perf_counter() - started
        return poses

    # -- one frame --------------------------------------------------------------------------------

    def _track(self, view: _View, after_gap: bool = False) -> tuple[np.ndarray, str, bool]:
        """The odometry pose of the frame, the term used, and whether depth was degenerate."""
        config = self.config
        if not self._poses:
            self._add_keyframe(view, np.eye(4), edge=None)
            return np.eye(4), NO_TERM, False
        last = self._poses[-1]
        before = self._poses[-2] if len(self._poses) > 1 else last
        # Constant velocity; across a time gap the motion is unknown, so no motion is the guess.
        prediction = last if after_gap else last @ np.linalg.inv(before) @ last
        if view.valid_fraction < config.min_valid_fraction or not self.keyframes:
            self.starved_frames += 1
            self._previous = None  # not registered: no keyframe material
            return prediction, NO_TERM, False

        keyframe = self.keyframes[-1]
        predicted = np.linalg.inv(keyframe.pose) @ prediction  # T_keyframe_frame
        degenerate = depth_degeneracy(view.plane_information, view.median_depth_m) < config.degenerate_ratio
        term = _choose_term(degenerate, view.textured and keyframe.view.textured)
        keyframe_from_frame, fitness, motion = None, 0.0, None
        if config.features is not None:
            keyframe_from_frame, fitness, motion = self._from_features(view, keyframe.view, term)
            matchable = min(len(view.features), len(keyframe.view.features)) >= config.min_features
            if keyframe_from_frame is None and self._previous is not None and matchable:
                # Too little left in common with the keyframe (too few matches, or a dense result
                # that leaves them) though both images have features: the previous frame, which is
                # always close, becomes the keyframe, and the frame is registered to it instead.
                keyframe = self._promote_previous()
                predicted = np.linalg.inv(keyframe.pose) @ prediction
                keyframe_from_frame, fitness, motion = self._from_features(view, keyframe.view, term)
        if keyframe_from_frame is not None:
            self.feature_frames += 1
            if len(self._poses) > 1 and not _near(keyframe_from_frame, predicted, config.prediction_agreement_m,
                                                  config.prediction_agreement_deg):
                # Far from where the camera was heading: a real jerk, or features fooled by a
                # repeated pattern (floor tiles, planks) with the dense terms agreeing on the same
                # wrong shift. The registration from the prediction too; a much better overlap wins.
                candidate, candidate_fitness = self._register(view, keyframe.view, predicted, term)
                if candidate is not None and candidate_fitness > config.prediction_overlap_ratio * fitness:
                    keyframe_from_frame, fitness = candidate, candidate_fitness
                    self.prediction_wins += 1
        elif motion is not None:  # the dense result left the feature estimate: that is kept
            self.feature_fallbacks += 1
            keyframe_from_frame = motion.target_from_source
        else:
            keyframe_from_frame, fitness, term = self._from_prediction(view, keyframe.view, predicted, term)
        pose = keyframe.pose @ keyframe_from_frame
        self._previous = (view, keyframe_from_frame)

        moved = np.linalg.norm(keyframe_from_frame[:3, 3])
        turned = _angle_deg(keyframe_from_frame[:3, :3])
        if (moved > config.keyframe_translation_m or turned > config.keyframe_rotation_deg
                or fitness < config.keyframe_min_fitness):
            information = self._information(view, keyframe.view, keyframe_from_frame)
            self._add_keyframe(view, pose, PoseEdge(len(self.keyframes), len(self.keyframes) - 1,
                                                    keyframe_from_frame, information))
            self._previous = None
        return pose, term, degenerate

    def _promote_previous(self) -> _Keyframe:
        """Make the previous frame (tracked, not a keyframe) the newest keyframe; returns it."""
        assert self._previous is not None
        view, keyframe_from_previous = self._previous
        keyframe = self.keyframes[-1]
        information = self._information(view, keyframe.view, keyframe_from_previous)
        self._add_keyframe(view, self._poses[-1], PoseEdge(len(self.keyframes), len(self.keyframes) - 1,
                                                           keyframe_from_previous, information), frame=len(self._poses) - 1)
        self._keyframe_of[-1] = len(self.keyframes) - 1
        self._previous = None
        self.promoted_frames += 1
        return self.keyframes[-1]

    def _from_features(self, view: _View, keyframe: _View, term: str) -> tuple[np.ndarray | None, float, FeatureMotion | None]:
        """T_keyframe_frame by dense registration from the feature estimate (None when there is no
        estimate, or the dense result lands far from it), its fitness, and the feature estimate.

        Matched features need no guess, so they hold where the constant velocity does not; they are
        only as precise as the depth at a few hundred corners, which the dense terms then refine.
        A dense result far from the feature estimate fell into another minimum."""
        config = self.config
        assert config.features is not None
        motion = estimate_motion(view.features, keyframe.features, config.features)
        if motion is None:
            return None, 0.0, None
        result, fitness = self._register(view, keyframe, motion.target_from_source, term)
        if result is None or not _near(result, motion.target_from_source, config.feature_agreement_m,
                                       config.feature_agreement_deg):
            return None, fitness, motion
        return result, fitness, motion

    def _from_prediction(self, view: _View, keyframe: _View, predicted: np.ndarray, term: str) -> tuple[np.ndarray, float, str]:
        """T_keyframe_frame by dense registration from the constant-velocity prediction (no feature
        estimate: too few matches), its fitness and term."""
        config = self.config
        result, fitness = self._register(view, keyframe, predicted, term)
        if term != INTENSITY and _jump(result, predicted) > config.cross_check_m:
            # Dense odometry on a few planes has false minima a few centimetres off; the camera
            # moves smoothly, so of the two terms' results the one nearer the prediction wins.
            other = POINT_TO_PLANE if term == HYBRID else HYBRID
            if other == POINT_TO_PLANE or view.textured:
                candidate, candidate_fitness = self._register(view, keyframe, predicted, other)
                if _jump(candidate, predicted) < _jump(result, predicted):
                    result, fitness, term = candidate, candidate_fitness, other
        if result is None or fitness < config.min_fitness or _jump(result, predicted) > config.max_correction_m:
            self.rejected_frames += 1
            return predicted, fitness, term
        return result, fitness, term

    def _add_keyframe(self, view: _View, pose: np.ndarray, edge: PoseEdge | None, frame: int | None = None) -> None:
        """Append a keyframe (by default the frame being tracked), its edge to the last keyframe,
        and look for loops from it."""
        travelled = 0.0
        if self.keyframes:
            last = self.keyframes[-1]
            travelled = last.travelled_m + float(np.linalg.norm(pose[:3, 3] - last.pose[:3, 3]))
        frame = len(self._poses) if frame is None else frame
        self.keyframes.append(_Keyframe(frame=frame, pose=pose, view=view, travelled_m=travelled))
        if edge is not None:
            self.edges.append(edge)
        if self.config.loop_closure:
            self._close_loops()

    def _close_loops(self) -> None:
        """Register the newest keyframe to the old keyframes that look at the same place; each
        verified match is a loop edge."""
        config = self.config
        new_index = len(self.keyframes) - 1
        new = self.keyframes[new_index]
        candidates = []
        for index, old in enumerate(self.keyframes[:max(0, new_index - config.loop_min_gap + 1)]):
            if new.travelled_m - old.travelled_m < config.loop_min_travel_m:
                continue  # a neighbour along the path: the odometry already joins them
            relative = np.linalg.inv(old.pose) @ new.pose
            # Where the two cameras look, not where they stand: the same table seen from two
            # places a metre apart is a loop; two cameras back to back at one spot are not.
            distance = float(np.linalg.norm(_view_centre(new) - _view_centre(old)))
            axis_angle = math.degrees(math.acos(np.clip(old.pose[:3, 2] @ new.pose[:3, 2], -1.0, 1.0)))
            if distance <= config.loop_radius_m and axis_angle <= config.loop_angle_deg:
                candidates.append((distance, index, relative))
        for _, index, initial in sorted(candidates, key=lambda c: c[0])[:config.loop_candidates]:
            old = self.keyframes[index]
            measured = self._register_loop(new.view, old.view, initial)
            if measured is None or np.linalg.norm(measured[:3, 3] - initial[:3, 3]) > config.loop_max_correction_m:
                continue
            information = self._information(new.view, old.view, measured)
            self.edges.append(PoseEdge(new_index, index, measured, information, loop=True))

    def _register_loop(self, new: _View, old: _View, estimate: np.ndarray) -> np.ndarray | None:
        """T_old_new for a loop edge, or None when the two views do not verifiably overlap. With
        features: their motion (stricter than the odometry's: a wrong loop bends the whole
        trajectory), refined densely and kept when the refinement stays near it; it needs no
        guess, so a loop is found however far the odometry drifted. Without: dense registration
        from the current estimate, accepted on its overlap."""
        config = self.config
        if config.features is not None and len(new.features) and len(old.features):
            loop_features = dataclasses.replace(config.features, min_inliers=config.loop_min_inliers)
            motion = estimate_motion(new.features, old.features, loop_features)
            if motion is None:
                return None
            term = HYBRID if new.textured and old.textured else POINT_TO_PLANE
            measured, _ = self._register(new, old, motion.target_from_source, term)
            near = measured is not None and _near(measured, motion.target_from_source, config.feature_agreement_m,
                                                   config.feature_agreement_deg)
            return measured if near else None
        term = HYBRID if new.textured and old.textured else POINT_TO_PLANE
        measured, fitness = self._register(new, old, estimate, term)
        return measured if measured is not None and fitness >= config.loop_min_fitness else None

    # -- Open3D ------------------------------------------------------------------------------------

    def _prepare(self, frame: Frame) -> _View:
        """Subsample the frame to at most `max_width` pixels wide, drop depth out of range, and
        wrap the images as Open3D tensors."""
        import open3d as o3d

        config = self.config
        height, width = frame.image_size
        step = max(1, math.ceil(width / config.max_width))
        depth = frame.depth[::step, ::step].copy()
        depth[~(np.isfinite(depth) & (depth >= config.min_depth_m) & (depth <= config.max_depth_m))] = np.nan
        rows, cols = depth.shape
        if frame.rgb is not None:
            # Blurred, then every step-th pixel: intensity residuals need an image without aliasing,
            # and centred on the depth samples (a block mean is centred half a pixel off them, and
            # the intensity term then pulls every frame's rotation the same way).
            rgb = frame.rgb if step == 1 else _smooth(frame.rgb, step)
            rgb = rgb[::step, ::step][:rows, :cols]
        else:
            rgb = np.zeros((rows, cols, 3), np.uint8)
        valid = np.isfinite(depth)
        features = no_features(frame.K)
        if frame.rgb is not None and config.features is not None:
            full_depth = np.where(frame.depth >= config.min_depth_m, frame.depth, np.nan)
            gray = frame.rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
            features = detect_features(gray.astype(np.uint8), full_depth, frame.K, config.features)
        K = frame.K.copy()
        K[:2] /= step  # pixel (step*i) becomes pixel i: centres at integer coordinates stay so
        rgbd = o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(np.ascontiguousarray(rgb)),
                                        o3d.t.geometry.Image(np.ascontiguousarray(depth[..., None])))
        return _View(rgbd=rgbd, features=features, K=o3d.core.Tensor(K), plane_information=plane_information(depth, K),
                     median_depth_m=float(np.median(depth[valid])) if valid.any() else 1.0,
                     valid_fraction=float(valid.mean()),
                     textured=frame.rgb is not None and textured_fraction(rgb, valid, config.gradient_threshold) >= config.textured_fraction)

    def _register(self, source: _View, target: _View, initial: np.ndarray, term: str) -> tuple[np.ndarray | None, float]:
        """T_target_source by RGB-D odometry from `initial`, and its fitness (None, 0 when it failed)."""
        import open3d as o3d

        odometry = o3d.t.pipelines.odometry
        config = self.config
        method = {HYBRID: odometry.Method.Hybrid, INTENSITY: odometry.Method.Intensity,
                  POINT_TO_PLANE: odometry.Method.PointToPlane}[term]
        criteria = [odometry.OdometryConvergenceCriteria(iterations) for iterations in config.iterations]
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

    def _information(self, source: _View, target: _View, target_from_source: np.ndarray) -> np.ndarray:
        """The depth term's 6x6 information matrix of T_target_source (Open3D's (rotation,
        translation) order); zeros when there are no correspondences."""
        import open3d as o3d

        try:
            information = o3d.t.pipelines.odometry.compute_odometry_information_matrix(
                source.rgbd.depth, target.rgbd.depth, source.K, o3d.core.Tensor(target_from_source),
                self.config.depth_outlier_trunc_m, 1.0, self.config.max_depth_m).numpy()
        except RuntimeError:
            return np.zeros((6, 6))
        return information if np.all(np.isfinite(information)) else np.zeros((6, 6))



def _smooth(image: np.ndarray, step: int) -> np.ndarray:
    """A Gaussian blur wide enough to subsample `image` by `step` without aliasing."""
    import cv2

    return cv2.GaussianBlur(image, (0, 0), sigmaX=0.5 * step)


def _view_centre(keyframe: _Keyframe) -> np.ndarray:
    """The point a keyframe's camera looks at: its median depth along the optical axis."""
    return keyframe.pose[:3, 3] + keyframe.view.median_depth_m * keyframe.pose[:3, 2]


def _near(transform: np.ndarray, reference: np.ndarray, distance_m: float, angle_deg: float) -> bool:
    """Whether two poses are within `distance_m` and `angle_deg` of each other."""
    difference = np.linalg.inv(reference) @ transform
    return bool(np.linalg.norm(difference[:3, 3]) <= distance_m and _angle_deg(difference[:3, :3]) <= angle_deg)


def _jump(transform: np.ndarray | None, initial: np.ndarray) -> float:
    """How far (metres) a registration moved the camera from its initial pose (inf if it failed)."""
    return float(np.linalg.norm(transform[:3, 3] - initial[:3, 3])) if transform is not None else math.inf


def _choose_term(degenerate: bool, textured: bool) -> str:
    """Which residuals to register with; see the module docstring."""
    if not textured:
        return POINT_TO_PLANE
    return INTENSITY if degenerate else HYBRID


def _angle_deg(rotation: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
