"""Camera poses from colour and depth: frame-to-keyframe RGB-D odometry with loop closure.

Why not depth alone (kiss.py): indoors a depth camera often sees only a wall and the floor, and
two planes leave the slide along their intersection unconstrained; KISS-ICP lost the synthetic
`paper` scene's target session that way. Colour pins that slide down wherever the surfaces carry
texture. Dense RGB-D odometry (Open3D's tensor `rgbd_odometry_multi_scale`: projective
association, a coarse-to-fine image pyramid, Huber losses on depth and intensity residuals) uses
both terms at once.

Per frame:
0. Opt-in (`prediction_first`): a textured frame is registered densely (step 3) from the
   constant-velocity prediction alone; when that result overlaps the keyframe well, lands near the
   prediction and does not make the frame a keyframe, it stands and the frame's features are never
   made. A doubtful result, and every keyframe, go on from step 1.
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
   would fit noise; but facing a bare wall, hybrid is tried too and the result nearer the
   prediction wins: faint texture below the test still pins the slide; past the wall's first frame
   hybrid compares the images' local contrast, as the camera's own shading outweighs faint
   texture); otherwise the hybrid of both.
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

`finish()` optimises the keyframe graph (where the loops measured drift, then again with more pairs of
keyframes that look at the same place, keyframe_pairs.py) and returns every frame's pose: a non-keyframe keeps its
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

from ndfa.core.frame import Frame
from ndfa.trajectory.checks import GapClock
from ndfa.trajectory.constant_velocity import motion_between, predict
from ndfa.trajectory.degeneracy import depth_degeneracy, keep_prediction_where_unseen
from ndfa.trajectory.features import FeatureMotion, estimate_motion
from ndfa.trajectory.keyframe_pairs import refine_with_keyframe_pairs
from ndfa.trajectory.pose_graph import PoseEdge, PoseGraphConfig, optimize_pose_graph
from ndfa.trajectory.rgbd_config import HYBRID, INTENSITY, NO_TERM, POINT_TO_PLANE, RgbdOdometryConfig
from ndfa.trajectory.rgbd_view import View, depth_information, keypoints, local_contrast, prepare_view, register_dense

__all__ = ["HYBRID", "INTENSITY", "NO_TERM", "POINT_TO_PLANE", "RgbdOdometry", "RgbdOdometryConfig"]


@dataclass
class _Keyframe:
    frame: int  # index of the frame in the session
    pose: np.ndarray  # (4, 4) odometry pose, in the first camera's frame
    view: View
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
        self._previous: tuple[View, np.ndarray] | None = None  # last frame if not a keyframe: view, T_keyframe_frame
        self.promoted_frames = 0  # previous frames made keyframes when the keyframe had too little in common
        self.feature_frames = 0  # frames whose first guess came from feature matches
        self.prediction_wins = 0  # feature-led result far from the prediction, and the prediction's overlapped better
        self.feature_fallbacks = 0  # dense result left the feature estimate, even after promoting: the latter kept
        self.seconds = 0.0
        # The motion of the last frame that pinned all six degrees of freedom (by features, or by
        # depth that saw every direction): the constant-velocity model's velocity. A frame facing
        # a bare wall takes its slide from it and does not feed its own back (rgbd_config:
        # unseen_from_prediction).
        self._velocity = np.eye(4)
        self._unseen = False
        self.unseen: list[bool] = []  # per frame, whether its registration kept the prediction along some direction
        # Whether this frame, and the last one, crossed a wall of faint texture by hybrid
        # (rgbd_config: hybrid_where_unseen, faint_wall_keyframes).
        self._faint_wall = False
        self._after_faint_wall = False
        self.faint_wall_frames = 0
        self.prediction_first_frames = 0  # frames registered from the prediction alone, no features (prediction_first)
        self._first_in_a_row = 0  # the frames just before this one registered so

    @property
    def frames(self) -> int:
        return len(self._poses)

    @property
    def unseen_frames(self) -> int:
        """Frames whose registration kept the prediction along some direction (rgbd_config)."""
        return sum(self.unseen)

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
        view = prepare_view(frame, self.config, defer_features=self.config.prediction_first)
        pose, term, degenerate = self._track(view, after_gap=self._clock.after_gap(frame.timestamp))
        self._poses.append(pose)
        self.terms.append(term)
        self.degenerate.append(degenerate)
        self.unseen.append(self._unseen)
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
        if self.config.loop_closure and self.config.keyframe_pairs:
            views = [keyframe.view for keyframe in self.keyframes]
            corrected = refine_with_keyframe_pairs(views, corrected, self.edges, self.config, odometry,
                                                   [keyframe.travelled_m for keyframe in self.keyframes],
                                                   len(self._poses))
        poses = []
        for pose, keyframe in zip(self._poses, self._keyframe_of):
            if keyframe >= 0:
                pose = corrected[keyframe] @ np.linalg.inv(odometry[keyframe]) @ pose
            poses.append(self._anchor @ pose)
        self.seconds += time.perf_counter() - started
        return poses

    # -- one frame --------------------------------------------------------------------------------

    def _track(self, view: View, after_gap: bool = False) -> tuple[np.ndarray, str, bool]:
        """The odometry pose of the frame, the term used, and whether depth was degenerate."""
        config = self.config
        if not self._poses:
            self._add_keyframe(view, np.eye(4), edge=None)
            return np.eye(4), NO_TERM, False
        last = self._poses[-1]
        # Constant velocity; across a time gap the motion is unknown, so no motion is the guess.
        prediction = last if after_gap else predict(last, self._velocity, self.config.velocity_in_world)
        self._unseen = False
        self._faint_wall = False
        if view.valid_fraction < config.min_valid_fraction or not self.keyframes:
            self.starved_frames += 1
            self._previous = None  # not registered: no keyframe material
            return prediction, NO_TERM, False

        keyframe = self.keyframes[-1]
        predicted = np.linalg.inv(keyframe.pose) @ prediction  # T_keyframe_frame
        degenerate = depth_degeneracy(view.plane_information, view.median_depth_m) < config.degenerate_ratio
        term = _choose_term(degenerate, view.textured and keyframe.view.textured)
        keyframe_from_frame, fitness, motion = None, 0.0, None
        first, first_keyframe = self._prediction_first(view, keyframe.view, predicted, term, after_gap), keyframe
        if first is not None and self._confident(view, keyframe, *first, predicted):
            keyframe_from_frame, fitness = first
            self.prediction_first_frames += 1
            self._first_in_a_row += 1
            return self._place(view, keyframe, keyframe_from_frame, fitness, last, term, degenerate)
        self._first_in_a_row = 0
        if config.features is not None:
            keyframe_from_frame, fitness, motion = self._from_features(view, keyframe.view, term)
            matchable = min(len(keypoints(view)), len(keypoints(keyframe.view))) >= config.min_features
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
                # (The registration from the prediction first, when it was made to this keyframe, is that.)
                candidate, candidate_fitness = (first if first is not None and keyframe is first_keyframe
                                                else register_dense(view, keyframe.view, predicted, term, self.config))
                if candidate is not None and candidate_fitness > config.prediction_overlap_ratio * fitness:
                    keyframe_from_frame, fitness = candidate, candidate_fitness
                    self.prediction_wins += 1
        elif motion is not None:  # the dense result left the feature estimate: that is kept
            self.feature_fallbacks += 1
            keyframe_from_frame = motion.target_from_source
        else:
            keyframe_from_frame, fitness, term = self._from_prediction(view, keyframe.view, predicted, term)
            # Until features take over again, the frames after such a wall are registered from
            # the prediction to a keyframe on it: they too become keyframes (see below).
            self._faint_wall = self._faint_wall or self._after_faint_wall
        self._after_faint_wall = self._faint_wall
        self.faint_wall_frames += self._faint_wall
        return self._place(view, keyframe, keyframe_from_frame, fitness, last, term, degenerate)

    def _place(self, view: View, keyframe: _Keyframe, keyframe_from_frame: np.ndarray, fitness: float,
               last: np.ndarray, term: str, degenerate: bool) -> tuple[np.ndarray, str, bool]:
        """The frame's pose from its registration to `keyframe`; the velocity; a new keyframe when
        the frame has moved, turned or lost overlap enough."""
        pose = keyframe.pose @ keyframe_from_frame
        self._previous = (view, keyframe_from_frame)
        if not self._unseen:  # a frame whose depth left some motion unseen keeps the last velocity
            self._velocity = motion_between(last, pose, self.config.velocity_in_world)

        if self._keyframe_due(view, keyframe_from_frame, fitness):
            information = depth_information(view, keyframe.view, keyframe_from_frame, self.config)
            self._add_keyframe(view, pose, PoseEdge(len(self.keyframes), len(self.keyframes) - 1,
                                                    keyframe_from_frame, information))
            self._previous = None
        return pose, term, degenerate

    def _keyframe_due(self, view: View, keyframe_from_frame: np.ndarray, fitness: float) -> bool:
        """Whether the frame so registered becomes the new keyframe: it moved or turned far enough
        from the keyframe, its overlap with it fell low, or it crossed a faint wall."""
        config = self.config
        moved = np.linalg.norm(keyframe_from_frame[:3, 3])
        turned = _angle_deg(keyframe_from_frame[:3, :3])
        return bool(moved > config.keyframe_translation_m or turned > config.keyframe_rotation_deg
                    or self._overlap(view, fitness) < config.keyframe_min_fitness
                    or (self._faint_wall and config.faint_wall_keyframes))

    def _overlap(self, view: View, fitness: float) -> float:
        """The overlap the keyframe rule reads: Open3D's fitness (inliers over all the frame's pixels),
        or with `keyframe_overlap_of_depth` over the pixels with depth only."""
        if self.config.keyframe_overlap_of_depth:
            return fitness / max(view.valid_fraction, 1e-9)
        return fitness

    def _prediction_first(self, view: View, keyframe: View, predicted: np.ndarray, term: str,
                          after_gap: bool) -> tuple[np.ndarray | None, float] | None:
        """With `prediction_first`, a textured frame's dense registration from the constant-velocity
        prediction (None where that does not apply: no features to fall back on, no velocity yet,
        after a time gap, not hybrid, a faint wall behind)."""
        config = self.config
        if (not config.prediction_first or config.features is None or len(self._poses) < 2 or after_gap
                or term != HYBRID or self._after_faint_wall or self._first_in_a_row >= config.prediction_first_in_a_row):
            return None
        if self._keyframe_due(view, predicted, 1.0):
            return None  # the prediction already makes it a keyframe: features, as for every keyframe
        return register_dense(view, keyframe, predicted, term, config)

    def _confident(self, view: View, keyframe: _Keyframe, result: np.ndarray | None, fitness: float,
                   predicted: np.ndarray) -> bool:
        """Whether the registration from the prediction stands without features: it overlaps the
        keyframe well, lands near the prediction, and does not make the frame a keyframe (a
        keyframe's edge carries every later frame, so it is measured from features)."""
        config = self.config
        if (result is None or fitness / max(view.valid_fraction, 1e-9) < config.prediction_first_overlap
                or not _near(result, predicted, config.prediction_first_max_m, config.prediction_first_max_deg)):
            return False
        return not self._keyframe_due(view, result, fitness)

    def _promote_previous(self) -> _Keyframe:
        """Make the previous frame (tracked, not a keyframe) the newest keyframe; returns it."""
        assert self._previous is not None
        view, keyframe_from_previous = self._previous
        keyframe = self.keyframes[-1]
        information = depth_information(view, keyframe.view, keyframe_from_previous, self.config)
        self._add_keyframe(view, self._poses[-1], PoseEdge(len(self.keyframes), len(self.keyframes) - 1,
                                                           keyframe_from_previous, information), frame=len(self._poses) - 1)
        self._keyframe_of[-1] = len(self.keyframes) - 1
        self._previous = None
        self.promoted_frames += 1
        return self.keyframes[-1]

    def _from_features(self, view: View, keyframe: View, term: str) -> tuple[np.ndarray | None, float, FeatureMotion | None]:
        """T_keyframe_frame by dense registration from the feature estimate (None when there is no
        estimate, or the dense result lands far from it), its fitness, and the feature estimate.

        Matched features need no guess, so they hold where the constant velocity does not; they are
        only as precise as the depth at a few hundred corners, which the dense terms then refine.
        A dense result far from the feature estimate fell into another minimum."""
        config = self.config
        assert config.features is not None
        motion = estimate_motion(keypoints(view), keypoints(keyframe), config.features)
        if motion is None:
            return None, 0.0, None
        result, fitness = register_dense(view, keyframe, motion.target_from_source, term, self.config)
        if result is None or not _near(result, motion.target_from_source, config.feature_agreement_m,
                                       config.feature_agreement_deg):
            return None, fitness, motion
        return result, fitness, motion

    def _from_prediction(self, view: View, keyframe: View, predicted: np.ndarray, term: str) -> tuple[np.ndarray, float, str]:
        """T_keyframe_frame by dense registration from the constant-velocity prediction (no feature
        estimate: too few matches), its fitness and term."""
        config = self.config
        # The frame after one tracked across a faint wall, until features take over: its keyframe is
        # on the wall too, and both images' colour is faint texture under the camera's own shading.
        # The first frame on the wall meets its keyframe off the wall in their colour (in local
        # contrast that keyframe's strong edges clip: docs/odometry.md).
        after_wall = self._after_faint_wall
        result, fitness = self._register(view, keyframe, predicted, term, after_wall)
        if term != INTENSITY and _jump(result, predicted) > config.cross_check_m:
            # Dense odometry on a few planes has false minima a few centimetres off; the camera
            # moves smoothly, so of the two terms' results the one nearer the prediction wins.
            other = POINT_TO_PLANE if term == HYBRID else HYBRID
            faint = other == HYBRID and not view.textured and self._faint_texture(view, keyframe)
            if other == POINT_TO_PLANE or view.textured or faint:
                candidate, candidate_fitness = self._register(view, keyframe, predicted, other, after_wall)
                if _jump(candidate, predicted) < _jump(result, predicted):
                    result, fitness, term = candidate, candidate_fitness, other
                    self._faint_wall = faint
        # Only the chosen result keeps the prediction where depth is blind: kept before the choice,
        # a point-to-plane result would always lie nearer the prediction and win it.
        result = self._keep_unseen(view, result, predicted, term)
        if result is None or fitness < config.min_fitness or _jump(result, predicted) > config.max_correction_m:
            self.rejected_frames += 1
            return predicted, fitness, term
        return result, fitness, term

    def _register(self, view: View, keyframe: View, initial: np.ndarray, term: str,
                  on_faint_wall: bool) -> tuple[np.ndarray | None, float]:
        """`register_dense`; `on_faint_wall`, the intensity term compares the images' local contrast
        (`faint_wall_contrast_px`, `rgbd_view.local_contrast`)."""
        config = self.config
        if on_faint_wall and term != POINT_TO_PLANE and config.faint_wall_contrast_px > 0.0:
            view = local_contrast(view, config.faint_wall_contrast_px, config.faint_wall_contrast_gain)
            keyframe = local_contrast(keyframe, config.faint_wall_contrast_px, config.faint_wall_contrast_gain)
        # From the prediction all iterations run: the prediction can be centimetres off, and sliding
        # along a bare wall changes the fitness and the residual too little to tell that the
        # registration is still on its way (docs/odometry.md, "Iterations that stop early").
        return register_dense(view, keyframe, initial, term, config, early_stop=False)

    def _faint_texture(self, view: View, keyframe: View) -> bool:
        """Whether an untextured frame's point-to-plane result should meet hybrid's (`hybrid_where_unseen`):
        both images have colour, and the frame's depth leaves some direction unseen (a bare wall)."""
        config = self.config
        return (config.hybrid_where_unseen and view.coloured and keyframe.coloured
                and depth_degeneracy(view.unseen_information, view.median_depth_m) < config.unseen_ratio)

    def _keep_unseen(self, view: View, result: np.ndarray | None, predicted: np.ndarray, term: str) -> np.ndarray | None:
        """`result` with the prediction kept along the directions the frame's depth cannot see, when
        `term` leans on depth alone (`keep_prediction_where_unseen`, rgbd_config)."""
        if result is None or term not in self.config.unseen_from_prediction:
            return result
        remapped = keep_prediction_where_unseen(result, predicted, view.unseen_information, view.median_depth_m,
                                                self.config.unseen_ratio)
        self._unseen = remapped is not result
        return remapped

    def _add_keyframe(self, view: View, pose: np.ndarray, edge: PoseEdge | None, frame: int | None = None) -> None:
        """Append a keyframe (by default the frame being tracked), its edge to the last keyframe,
        and look for loops from it."""
        travelled = 0.0
        if self.keyframes:
            last = self.keyframes[-1]
            travelled = last.travelled_m + float(np.linalg.norm(pose[:3, 3] - last.pose[:3, 3]))
        frame = len(self._poses) if frame is None else frame
        if view.pending is not None:  # features deferred (prediction_first): loops and later frames match against them
            keypoints(view)
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
        older = self.keyframes[:max(0, new_index - config.loop_min_gap + 1)]
        if not older:
            return
        # All older keyframes at once (a loop over them in Python took 15 ms per frame by 300
        # keyframes, and grows with the session).
        travelled = np.array([old.travelled_m for old in older])
        poses = np.array([old.pose for old in older])
        # Where the two cameras look, not where they stand: the same table seen from two
        # places a metre apart is a loop; two cameras back to back at one spot are not.
        centres = poses[:, :3, 3] + np.array([old.view.median_depth_m for old in older])[:, None] * poses[:, :3, 2]
        distance = np.linalg.norm(centres - _view_centre(new), axis=1)
        axis_angle = np.degrees(np.arccos(np.clip(poses[:, :3, 2] @ new.pose[:3, 2], -1.0, 1.0)))
        # Not a neighbour along the path (the odometry already joins those), and looking at the same place.
        chosen = np.flatnonzero((new.travelled_m - travelled >= config.loop_min_travel_m)
                                & (distance <= config.loop_radius_m) & (axis_angle <= config.loop_angle_deg))
        for index in chosen[np.argsort(distance[chosen], kind="stable")][:config.loop_candidates].tolist():
            old = self.keyframes[index]
            initial = np.linalg.inv(old.pose) @ new.pose
            measured = self._register_loop(new.view, old.view, initial)
            if measured is None or np.linalg.norm(measured[:3, 3] - initial[:3, 3]) > config.loop_max_correction_m:
                continue
            information = depth_information(new.view, old.view, measured, self.config)
            self.edges.append(PoseEdge(new_index, index, measured, information, loop=True))

    def _register_loop(self, new: View, old: View, estimate: np.ndarray) -> np.ndarray | None:
        """T_old_new for a loop edge, or None when the two views do not verifiably overlap. With
        features: their motion (stricter than the odometry's: a wrong loop bends the whole
        trajectory), refined densely and kept when the refinement stays near it; it needs no
        guess, so a loop is found however far the odometry drifted. Without: dense registration
        from the current estimate, accepted on its overlap."""
        config = self.config
        if config.features is not None and len(keypoints(new)) and len(keypoints(old)):
            loop_features = dataclasses.replace(config.features, min_inliers=config.loop_min_inliers)
            motion = estimate_motion(keypoints(new), keypoints(old), loop_features)
            if motion is None:
                return None
            term = HYBRID if new.textured and old.textured else POINT_TO_PLANE
            measured, _ = register_dense(new, old, motion.target_from_source, term, self.config)
            near = measured is not None and _near(measured, motion.target_from_source, config.feature_agreement_m,
                                                   config.feature_agreement_deg)
            return measured if near else None
        term = HYBRID if new.textured and old.textured else POINT_TO_PLANE
        measured, fitness = register_dense(new, old, estimate, term, self.config)
        return measured if measured is not None and fitness >= config.loop_min_fitness else None


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
