"""Scene-level hypotheses of T_rel (target world -> source world) for the registrar to verify.

The paper registers the sessions by shape-matched objects alone, which needs N of them; a real
table with two mugs never gets there. Two things outside the object maps can propose a T_rel,
which the object pairs then verify (`ndfa.change.register.verify_prior`):

- **shared world**: both sessions' poses live in one world (one dataset, one SLAM map). Each
  session was levelled on its own (`ndfa.run.world`), so the hypothesis is the source's levelling
  after the target's undone, not quite the identity. Whether the worlds are shared is checked on
  the scene (`check_shared_world`): the upright surfaces of the target's fused cloud must lie on
  the source's under it, and less so when it is nudged.
- **scene alignment**: poses estimated per session (each world starts at its own first camera,
  both levelled so z is up): the sessions' fused clouds are aligned globally (FPFH features and
  RANSAC, Open3D), then by ICP that turns about z and shifts only (both are levelled; 4 DoF).

Either hypothesis, once proposed, is also judged on its own evidence (`ndfa.run.scene_evidence`):
when it is strong, the registrar accepts it where too few object pairs can confirm it (a table
where most objects changed; docs/registration.md).

A fused cloud is the depth of `frames` frames spread over the session, back-projected with the
poses the detector will use, in the session's levelled world. Why these defaults, and what they
gave on the kitchen sequence: `docs/detector.md`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ndfa.change.register import RegistrationPrior
from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M
from ndfa.core.events import RegistrationMethod
from ndfa.core.geometry import backproject, make_pose, rotation_z
from ndfa.io.recording import RecordingReader
from ndfa.run.cloud_align import AlignConfig, apply_transform, global_alignment, overlap, upright, voxel_thin
from ndfa.run.scene_evidence import OwnEvidence, better_from_halves, own_evidence
from ndfa.run.world import KeepDepth, KeptFrame, SessionWorld

RegistrationMode = Literal["auto", "objects", "shared-world", "scene"]
REGISTRATION_MODES: tuple[str, ...] = ("auto", "objects", "shared-world", "scene")


@dataclass
class SceneAlignment:
    """A scene-level T_rel hypothesis and the figures that accepted or rejected it."""

    method: RegistrationMethod       # "shared world" or "scene alignment"
    ok: bool
    transform: np.ndarray | None     # (4, 4) target world -> source world (both levelled)
    fitness: float                   # share of the target cloud within icp_distance_m of the source's
    rmse_m: float                    # RMS distance of those points
    points: tuple[int, int]          # (source, target) points of the thinned clouds
    seconds: float
    reason: str                      # one line: why it holds or not
    binding: bool = False            # RANSAC's fits must agree with it (`RegistrationPrior.binding`)
    evidence: OwnEvidence | None = None  # a scene alignment judged on its own (`ndfa.run.scene_evidence`)

    def prior(self) -> RegistrationPrior | None:
        if not self.ok or self.transform is None:
            return None
        standalone = self.evidence is not None and self.evidence.ok
        return RegistrationPrior(self.method, self.transform, binding=self.binding or standalone,
                                 standalone=standalone,
                                 evidence="" if self.evidence is None else self.evidence.describe())

    def describe(self) -> str:
        verdict = "proposed" if self.ok else "not proposed"
        if not np.isfinite(self.fitness):
            return f"{self.method} {verdict}: {self.reason}"
        rmse = f", rmse {self.rmse_m * 100:.1f} cm" if np.isfinite(self.rmse_m) else ""
        evidence = "" if self.evidence is None else f"; own evidence {self.evidence.describe()}"
        return (f"{self.method} {verdict}: {self.reason}; fitness {self.fitness:.2f}{rmse}, "
                f"{self.points[0]} / {self.points[1]} points, {self.seconds:.1f} s{evidence}")

    def as_dict(self) -> dict:
        def number(value: float) -> float | None:  # JSON has no NaN
            return None if not np.isfinite(value) else round(float(value), 4)

        return {"method": self.method, "ok": self.ok, "reason": self.reason, "fitness": number(self.fitness),
                "rmse_m": number(self.rmse_m), "points": list(self.points), "seconds": round(self.seconds, 2),
                "transform": None if self.transform is None else [round(float(v), 6) for v in self.transform.ravel()],
                "own_evidence": None if self.evidence is None else self.evidence.as_dict()}


def registration_prior(source: RecordingReader, target: RecordingReader, worlds: dict[str, SessionWorld],
                       mode: RegistrationMode = "auto", config: AlignConfig = AlignConfig()) -> SceneAlignment | None:
    """The scene-level hypothesis `mode` asks for, or None (`objects`: the paper's object pairs alone).

    auto: the shared world, checked on the scene, when neither session's poses were estimated (two
    estimates each start their world at their own first camera); the scene alignment when one was.
    A given-pose pair whose worlds differ gets no hypothesis in `auto` (`scene` asks for one).
    shared-world: the user's word, unchecked. scene: the global alignment whatever the poses.
    """
    if mode not in REGISTRATION_MODES:
        raise ValueError(f"registration mode must be one of {REGISTRATION_MODES}, got {mode!r}")
    if mode == "objects":
        return None
    shared = shared_world_transform(worlds["source"], worlds["target"])
    if mode == "shared-world":
        return SceneAlignment("shared world", True, shared, float("nan"), float("nan"), (0, 0), 0.0,
                              "as given (--registration shared-world), unchecked", binding=True)
    started = time.perf_counter()
    source_cloud = scene_cloud(source, worlds["source"], config)
    target_cloud = scene_cloud(target, worlds["target"], config)
    estimated = worlds["source"].poses is not None or worlds["target"].poses is not None
    if mode == "auto" and estimated and not (_is_truth(worlds["source"]) and _is_truth(worlds["target"])):
        mode = "scene"
    result = align_scenes(source_cloud, target_cloud, config) if mode == "scene" else \
        check_shared_world(source_cloud, target_cloud, shared, config)
    if result.ok and result.transform is not None and config.evidence is not None:
        # A scene alignment, or a shared world that the upright surfaces did not refute: either is
        # judged by the same bars. The shared world's check (`check_shared_world`) asks little
        # (given poses in different worlds can overlap that much by chance); its own evidence asks
        # what a found alignment must show, halves aligned from scratch and no rival included.
        result.evidence = own_evidence(source_cloud, target_cloud, result.transform, config)
        if result.method == "scene alignment":
            _move_to_a_better_half(source_cloud, target_cloud, result, config)
        unbind_without_upright_overlap(result)
    result.seconds = time.perf_counter() - started
    return result


def _move_to_a_better_half(source_cloud: np.ndarray, target_cloud: np.ndarray, alignment: SceneAlignment,
                           config: AlignConfig) -> None:
    """Where a half that contradicts the alignment (`better_from_halves`) fits the whole target
    better, the alignment moves there and is judged again, once."""
    assert alignment.evidence is not None and alignment.transform is not None
    better = better_from_halves(source_cloud, target_cloud, alignment.evidence, alignment.fitness, config)
    if better is None:
        return
    transform, fitness, rmse = better
    alignment.reason += (f"; moved to where a half's own alignment put it: the whole fits {fitness:.2f} there, "
                         f"{alignment.fitness:.2f} at RANSAC's")
    alignment.transform, alignment.fitness, alignment.rmse_m = transform, fitness, rmse
    alignment.binding = fitness >= config.binding_fitness
    alignment.evidence = own_evidence(source_cloud, target_cloud, transform, config)


def unbind_without_upright_overlap(alignment: SceneAlignment) -> None:
    """A found scene alignment binds RANSAC's fits (`binding`, from its overall fitness) only where
    its upright surfaces overlap too: floors and table tops coincide under any turn or shift of
    levelled worlds, so a rectangular room turned half a turn still overlaps 0.6 overall (random
    seed 1 raw: upright 0.46, and it vetoed an object-pair fit of 13 inliers; docs/registration.md).
    A shared world's own check already asks its upright surfaces (`check_shared_world`)."""
    evidence = alignment.evidence
    if alignment.method == "scene alignment" and alignment.binding and evidence is not None \
            and not evidence.upright_overlap:
        alignment.binding = False
        alignment.reason += (f" (its upright surfaces overlap below {evidence.config.min_fitness}: "
                             "RANSAC's fits need not agree with it)")


def shared_world_transform(source: SessionWorld, target: SessionWorld) -> np.ndarray:
    """T_rel if both sessions' poses are in one world: each was levelled by its own rotation about
    the world origin, so a target point goes back through the target's levelling and forward
    through the source's."""
    source_levelling = np.eye(3) if source.levelling is None else source.levelling
    target_levelling = np.eye(3) if target.levelling is None else target.levelling
    return make_pose(source_levelling @ target_levelling.T, np.zeros(3))


def scene_cloud(reader: RecordingReader, world: SessionWorld, config: AlignConfig = AlignConfig()) -> np.ndarray:
    """(N, 3) the session's depth fused over `config.frames` frames, in its levelled world, one point
    per voxel; from the depth the odometry kept of them (`SessionWorld.kept_depth`) when it kept
    them as `config` asks, else read from the recording (the same points)."""
    keep = scene_depth(config)
    if world.kept_depth is not None and world.kept_depth[0] == keep:
        kept = world.kept_depth[1]
    else:
        kept = [KeptFrame(frame.index, frame.K, frame.pose_world_camera,
                          frame.depth[::config.pixel_stride, ::config.pixel_stride])
                for frame in reader.frames(positions=keep.positions(len(reader), world.posed))]
    clouds = []
    for frame in kept:
        rows, cols = np.nonzero((frame.depth > MIN_DEPTH_M) & (frame.depth < MAX_DEPTH_M))
        points = backproject(frame.K, rows * config.pixel_stride, cols * config.pixel_stride, frame.depth[rows, cols])
        pose = world.camera_pose(frame.index, frame.pose)
        clouds.append(points @ pose[:3, :3].T + pose[:3, 3])
    cloud = np.concatenate(clouds) if clouds else np.zeros((0, 3))
    return voxel_thin(cloud, config.voxel_m)


def scene_depth(config: AlignConfig = AlignConfig()) -> KeepDepth:
    """Which frames' depth `scene_cloud` fuses, for the odometry to keep (`ndfa.run.world.prepare_session`)."""
    return KeepDepth(config.frames, config.pixel_stride)


def check_shared_world(source_cloud: np.ndarray, target_cloud: np.ndarray, hypothesis: np.ndarray,
                       config: AlignConfig = AlignConfig()) -> SceneAlignment:
    """Do the clouds' upright surfaces lie on each other under `hypothesis`, and best there?

    Upright points only (normals off the vertical: walls, furniture, objects): floors and table
    tops coincide under any shift once both worlds are levelled, so they prove nothing. Best
    there: shifting the hypothesis by `peak_shift_m` along x or y, or turning it by `peak_turn_deg`,
    must lose overlap; where it does not, the overlap is surfaces sliding along each other.
    """
    points = (len(source_cloud), len(target_cloud))
    if min(points) < 3:
        return SceneAlignment("shared world", False, None, 0.0, float("nan"), points, 0.0, "a session has no depth")
    source_upright, target_upright = upright(source_cloud, config), upright(target_cloud, config)
    fitness, rmse = overlap(source_upright, target_upright, hypothesis, config.icp_distance_m)
    if fitness < config.shared_min_fitness:
        return SceneAlignment("shared world", False, None, fitness, rmse, points, 0.0,
                              f"the upright surfaces do not overlap under it (fitness below {config.shared_min_fitness})")
    center = apply_transform(hypothesis, target_upright).mean(axis=0)
    for dx, dy, turn in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
        rotation = rotation_z(np.radians(turn * config.peak_turn_deg))
        nudge = make_pose(rotation, center - rotation @ center + config.peak_shift_m * np.array([dx, dy, 0.0]))
        nudged, _ = overlap(source_upright, target_upright, nudge @ hypothesis, config.icp_distance_m)
        if nudged >= fitness:
            return SceneAlignment("shared world", False, None, fitness, rmse, points, 0.0,
                                  f"not a peak: {nudged:.2f} of the upright surfaces overlap "
                                  f"{config.peak_shift_m * 100:g} cm or {config.peak_turn_deg:g} deg off it")
    return SceneAlignment("shared world", True, hypothesis, fitness, rmse, points, 0.0,
                          "the upright surfaces overlap under it, and less when it is shifted or turned", binding=True)


def align_scenes(source_cloud: np.ndarray, target_cloud: np.ndarray,
                 config: AlignConfig = AlignConfig()) -> SceneAlignment:
    """Global registration of the target's cloud onto the source's (`global_alignment`)."""
    points = (len(source_cloud), len(target_cloud))
    if min(points) < 3:
        return SceneAlignment("scene alignment", False, None, 0.0, float("nan"), points, 0.0, "a session has no depth")
    transform, fitness, rmse = global_alignment(source_cloud, target_cloud, config)
    ok = fitness >= config.min_fitness
    reason = "FPFH + RANSAC, then ICP about z" + ("" if ok else f" (fitness below {config.min_fitness})")
    binding = fitness >= config.binding_fitness
    if ok and not binding:
        reason += f" (a weak overlap, below {config.binding_fitness}: RANSAC's fits need not agree with it)"
    return SceneAlignment("scene alignment", ok, transform, fitness, rmse, points, 0.0, reason, binding=binding)


def _is_truth(world: SessionWorld) -> bool:
    """Poses from a simulator's ground-truth channel: every session of it is in the simulator's world."""
    return world.pose_source.startswith("true")
