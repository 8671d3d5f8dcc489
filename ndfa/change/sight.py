"""Whether a session's frames showed a place well enough for the detector to have found an object there.

"Added" says the source had no object where the target has one; "removed" says the target has
none where the source had one. Either rests on the *other* session having looked: an object it
could not have taken (seen only from afar, where it falls below perception's pixel minimum; only
past a monitor; only cut by the image border; never) is absent from its map whether or not it
stood there, and its absence is then no evidence of a change. So for each frame the detector takes
(`SessionViews.add`), its camera and a coarse copy of its depth are kept, and `SessionViews.sight`
asks of a place: in how many frames was an object of the category there in view (whole, inside
the image), in the depth range, and how many pixels would the best of them have given it, counting
only the parts whose line of sight the measured depth leaves free? The place counts as shown when
that reaches the pixel minimum perception itself takes an object from (`SightRule`, filled by the
pipeline from `ObservationConfig`: one bar for both).

The object is a vertical cylinder of the category's size (`EvidenceConfig.sight_radius_m`,
`sight_height_m`) standing at the place's center. Its pixels in a view are its projected area (the
side's rectangle foreshortened by the view's elevation, the top's ellipse), times the claimed
object's own size where its own views show it smaller than a median mug (`own_size`: a small cup
seen from where a mug would just have shown would not have), times the share of its
camera-facing surface samples not hidden: a sample is hidden when the depth at its pixel is more
than `OCCLUSION_MARGIN_M` nearer than the sample, or missing (a black screen, the aligned
sensor's band at an edge: nothing says what is behind). Where the place was empty the depth there
is the table or the wall behind it, which hides nothing. Centred at the object's center, the
cylinder of an object shorter than it (a small box, a can) reaches into the support, whose top
would hide those samples from every view: the samples below the height the object stands at (its
views' lowest points, `SessionObject.base_height`) are left out of that share (not of the tests of
emptiness below, which read how far a face the depth stopped on rises).

Shown is not yet shown *empty*: a claim of a change says the other session saw no object there,
and a place whose depth ended on something standing in it was not seen empty, whatever perception
made of that something (an object just below its gate, one seen too few times to be tested, one
cut or half hidden in every view). So `sight` also asks, of each frame that showed the place well
enough (its pixels reaching the rule's minimum), whether its depth passed through the place: of the
cylinder's camera-facing samples at or above the place's center height (lower ones meet the
support itself at grazing views) and not hidden, a sample is *seen through* when the measured depth
lies more than the cylinder's radius beyond it (the ray crossed the place's front half and met
nothing), and *stopped* when it ends closer (on a surface in the place). A frame shows something
standing in the place when more of them are stopped than seen through and the surface the depth
ended on inside the place rises (`STANDING_M`: not a table top that drift between the sessions set
the place into) or the frame did not see the place's upper half (`SAW_UPPER` of those samples not
hidden: the few rays left ending on the table under a place hidden above say nothing of what stood
in it), and the place empty otherwise; the place counts as seen empty when at least half the frames that showed it well
showed it empty (`Sight.seen_empty`). The detector asks it only where
the other session's map holds no object at the place to explain what stood there (a switch:
`ndfa.change.detector`).

Memory stays bounded in the recording's length: every frame's camera is kept (128 bytes), the
depth of at most `MAX_DEPTHS` frames. A frame whose camera stands within `SAME_VIEW_M` of a kept
frame's (`view_distance`: the cameras' distance plus their turn in radians times `TURN_SCALE_M`)
keeps no depth: a session that walks the same places again, or stands still, keeps one depth per
viewpoint. Past `MAX_DEPTHS` the kept depths are thinned as an object's history is
(`ndfa.change.associate.keep_in_history`): every other one dropped, and from then on every other new
viewpoint skipped, an even sample of the walk. `sight` counts the frames in view over every camera
and takes the pixels from the frames whose depth is kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M, VISIBLE_PIXELS

# A sample counts as hidden when the measured depth along its ray is this much nearer than it:
# more than the sensor's noise at a few metres, less than the depth of a monitor or another mug
# standing in front.
OCCLUSION_MARGIN_M = 0.05
# Every STRIDE-th pixel of a frame's depth is kept: a mug 3 m away still spans ~4 kept pixels.
STRIDE = 4
# The cylinder's surface samples: around it, up it, and across its top.
AROUND, UP, ACROSS = 16, 5, 3
# The most frames whose depth a session keeps (~38 kB each at 640x480: ~39 MB); a recording of up
# to this many frames per session keeps every one.
MAX_DEPTHS = 1024
# A frame whose camera stands within this `view_distance` of a kept frame's shows nothing new to the
# rule (at 3 m, a mug's pixels change by under 1 %); its depth is not kept.
SAME_VIEW_M = 0.01
# A turn of the camera by one radian counts as a step of this many metres (a point 1 m away moves as far).
TURN_SCALE_M = 1.0
# Something stands in a place when the surface the depth ended on inside it rises at least this
# much (10th to 90th percentile of the ended points' heights): a table top seen in the place (the
# place set a few cm too low by drift between the sessions, or its foot) lies flat within the
# depth's noise (the Kinect's disparity step at 3 m, ~2.5 cm along the ray, under 1.5 cm in height
# at the usual downward views); a mug's face seen there spans 5-7 cm.
STANDING_M = 0.03
# An object's own size (`own_size`) is read at this percentile of its views' pixels against the
# cylinder's: its fullest views show it whole, the others partly hidden or cut by the support.
OWN_SIZE_PERCENTILE = 90
# A sample of the place's cylinder this far above the object's own top (its views' highest points)
# is of no part of it (`SessionViews.sight`'s `ceiling_m`): a few millimetres for the top's
# percentile and the depth's noise, less than a row of the cylinder's samples (2.75 cm apart).
OVER_TOP_M = 0.01
# A frame's flat stop (`STANDING_M`) counts as the place seen empty only where it saw at least this
# share of the place's upper facing samples (not hidden by a nearer surface, not without depth): the
# rest of its upper half hidden, the few rays left ending low say nothing of what stood in it.
SAW_UPPER = 0.5


@dataclass(frozen=True)
class SightRule:
    """Perception's bar for taking an object from a view (`ndfa.perception.observations`'s
    `ObservationConfig` fills it in the pipeline): pixels, depth range, and whether a view cut by
    the image border counts."""

    min_pixels: int = VISIBLE_PIXELS
    min_depth_m: float = MIN_DEPTH_M
    max_depth_m: float = MAX_DEPTH_M
    skip_border: bool = True


@dataclass(frozen=True)
class Sight:
    """What a session's frames showed of one place. `shown`: the best frame reaches the rule's
    pixels; `pixels`: the best frame's expected pixels (0 when never in view); `frame_index`,
    `distance_m`, `unhidden`: that frame's, its distance to the place and the share of the
    object's facing surface not hidden; `in_view`: frames with the place whole in view and in range;
    `well`: frames (of those whose depth is kept) whose pixels reach the rule's minimum, `empty`: of
    those, the ones whose depth passed through the place (the module docstring says how);
    `stopped`: the share of the upper facing samples the depth ended on in the best such frame that
    did not show it empty (NaN when every one did), `hidden_above`: the share of that frame's upper
    facing samples hidden; `size`: the object's pixels as a share of the cylinder's (`own_size`)."""

    shown: bool
    pixels: float
    frames: int
    in_view: int = 0
    frame_index: int | None = None
    distance_m: float = float("nan")
    unhidden: float = float("nan")
    min_pixels: int = VISIBLE_PIXELS
    well: int = 0
    empty: int = 0
    stopped: float = float("nan")
    stopped_frame: int | None = None
    hidden_above: float = float("nan")
    size: float = 1.0

    @property
    def seen_empty(self) -> bool:
        """Whether the frames that showed the place well mostly saw it empty (true when none
        showed it well, or when no frames are known: a replay)."""
        return 2 * self.empty >= self.well

    def describe_occupied(self, session: str) -> str:
        """One line: why the place, though shown, does not count as seen empty by `session`."""
        return (f"shown but not seen empty: the {session}'s depth ended inside it, or did not reach its upper half, in "
                f"{self.well - self.empty} of the {self.well} frames that showed it well (frame {self.stopped_frame}: "
                f"{self.stopped:.0%} of its upper surface stopped, {self.hidden_above:.0%} of it hidden), and the "
                f"{session}'s map has no object there: something stood there that was not taken as an object")

    def describe(self, session: str) -> str:
        """One line: why the place counts as shown by `session`, or not."""
        if self.frames == 0:
            return f"the {session}'s frames are not known"
        if self.in_view == 0:
            return f"never whole in view of the {session}'s {self.frames} frames within range"
        size = "" if self.size >= 1 else f" for an object of its own size ({self.size:.0%} of a mug's)"
        best = (f"at best {self.pixels:.0f} px expected{size} (frame {self.frame_index}, {self.distance_m:.1f} m away, "
                f"{self.unhidden:.0%} not hidden) in {self.in_view} of the {session}'s {self.frames} frames")
        verb = "shown" if self.shown else f"not shown well enough to find an object there (< {self.min_pixels} px)"
        return f"{verb}: {best}"

    def as_dict(self) -> dict[str, object]:
        def number(value: float) -> float | None:
            return None if not np.isfinite(value) else round(float(value), 3)

        return {"shown": self.shown, "pixels": round(float(self.pixels), 1), "frames": self.frames,
                "in_view": self.in_view, "frame": self.frame_index, "distance_m": number(self.distance_m),
                "unhidden": number(self.unhidden), "well": self.well, "empty": self.empty}


@dataclass
class SessionViews:
    """The frames one session gave the detector, coarsely: what `sight` needs of them: every frame's
    camera, and the depth of at most `max_depths` of them (the module docstring says which)."""

    rule: SightRule = field(default_factory=SightRule)
    max_depths: int = MAX_DEPTHS
    indices: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)      # camera -> world, (4, 4)
    K: np.ndarray | None = None
    shape: tuple[int, int] = (0, 0)                            # the full image's (H, W)
    # The frames whose depth is kept, in frame order: their positions in `indices` and their depth
    # (every STRIDE-th pixel, float16 metres); of the frames that stand apart from every kept one,
    # every `stride`-th is kept (`candidates` counts them).
    kept: list[int] = field(default_factory=list)
    depths: list[np.ndarray] = field(default_factory=list)
    stride: int = 1
    candidates: int = 0
    _kept_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))   # the kept frames' poses

    def __len__(self) -> int:
        return len(self.indices)

    def add(self, frame_index: int, depth: np.ndarray, K: np.ndarray, pose_world_camera: np.ndarray) -> None:
        """One frame the detector takes (its depth in metres, 0 or non-finite: none)."""
        depth = np.asarray(depth)
        self.K, self.shape = np.asarray(K, dtype=float), depth.shape
        self.indices.append(int(frame_index))
        self.poses.append(np.asarray(pose_world_camera, dtype=float))
        kept_poses = self._kept_poses[:len(self.kept)]
        if self.kept and view_distance(self.poses[-1], kept_poses).min() < SAME_VIEW_M:
            return
        self.candidates += 1
        if (self.candidates - 1) % self.stride:
            return
        if len(self.kept) >= self.max_depths:
            self.kept, self.depths, self.stride = self.kept[::2], self.depths[::2], 2 * self.stride
            self._kept_poses[:len(self.kept)] = kept_poses[::2]
            if (self.candidates - 1) % self.stride:
                return
        if len(self.kept) == len(self._kept_poses):
            self._kept_poses = np.concatenate([self._kept_poses, np.zeros((max(len(self.kept), 64), 4, 4))])
        self._kept_poses[len(self.kept)] = self.poses[-1]
        coarse = np.asarray(depth[STRIDE // 2::STRIDE, STRIDE // 2::STRIDE], dtype=np.float32)
        self.kept.append(len(self.poses) - 1)
        self.depths.append(np.nan_to_num(coarse, nan=0.0, posinf=0.0, neginf=0.0).astype(np.float16))

    def cameras(self, frames: list[int]) -> np.ndarray | None:
        """The camera centers (N, 3) of the given frames (this session's world); None when any of
        them is not among the frames given (a replay gives none)."""
        indices = np.asarray(self.indices, dtype=int)
        position = np.searchsorted(indices, np.asarray(frames, dtype=int))
        if not len(indices) or (position >= len(indices)).any() or (indices[np.minimum(position, len(indices) - 1)] != frames).any():
            return None
        return np.array([self.poses[i][:3, 3] for i in position]).reshape(-1, 3)

    def sight(self, place_world: np.ndarray, radius_m: float, height_m: float, size: float = 1.0,
              floor_m: float = -np.inf, ceiling_m: float = np.inf) -> Sight:
        """How well these frames showed an object of `radius_m` and `height_m` standing centred at
        `place_world` (this session's world; the module docstring says how); `size`: the object's
        pixels as a share of that cylinder's (`own_size`, at most 1), which scales the pixels that
        decide `shown` and nothing else (the frames that judge emptiness are the cylinder's);
        `floor_m`: the height the object stands at: the samples below it are inside the support,
        not hidden by anything in front, and are left out of the share not hidden (an object shorter
        than the cylinder); whether the place was seen empty is judged on every sample as before;
        `ceiling_m`: the height the object reaches (its views' highest points): the samples more than
        `OVER_TOP_M` above it (and above the place's center) are of no part of it, and are left out of
        the share not hidden and of whether the place was seen empty (a ray passing over a cup's rim
        does not say the cup is gone)."""
        rule = self.rule
        if not self.indices:
            return Sight(True, float("nan"), 0, min_pixels=rule.min_pixels)
        assert self.K is not None
        poses = np.stack(self.poses)
        cameras = poses[:, :3, 3]
        samples, normals = _cylinder(np.asarray(place_world, dtype=float), radius_m, height_m)
        # (frames, samples, 3) in each camera
        world_to_camera = np.linalg.inv(poses)
        points = np.einsum("fij,sj->fsi", world_to_camera[:, :3, :3], samples) + world_to_camera[:, None, :3, 3]
        z = points[..., 2]
        safe_z = np.where(z > 1e-6, z, np.inf)
        u = self.K[0, 0] * points[..., 0] / safe_z + self.K[0, 2]
        v = self.K[1, 1] * points[..., 1] / safe_z + self.K[1, 2]
        height, width = self.shape
        border = 1.0 if rule.skip_border else 0.0
        inside = (z > 0) & (u >= border) & (u <= width - 1 - border) & (v >= border) & (v <= height - 1 - border)
        center_depth = np.einsum("fj,fj->f", world_to_camera[:, 2, :3], np.broadcast_to(place_world, cameras.shape)) \
            + world_to_camera[:, 2, 3]
        in_view = inside.all(axis=1) & (center_depth >= rule.min_depth_m) & (center_depth <= rule.max_depth_m)
        if not in_view.any():
            return Sight(False, 0.0, len(self), min_pixels=rule.min_pixels)
        # the samples of the object's own height: none above its top (and the place's center row always)
        of_it = samples[:, 2] <= max(ceiling_m, float(np.asarray(place_world)[2])) + OVER_TOP_M
        facing = (np.einsum("fsj,sj->fs", cameras[:, None, :] - samples[None], normals) > 0) & of_it[None]
        rows = np.clip(np.rint((v - STRIDE // 2) / STRIDE), 0, self.depths[0].shape[0] - 1).astype(int)
        cols = np.clip(np.rint((u - STRIDE // 2) / STRIDE), 0, self.depths[0].shape[1] - 1).astype(int)
        kept = [k for k, f in enumerate(self.kept) if in_view[f]]    # the frames in view with their depth
        if not kept:
            return Sight(False, 0.0, len(self), int(in_view.sum()), min_pixels=rule.min_pixels)
        frames = np.array([self.kept[k] for k in kept])
        measured = np.stack([self.depths[k][rows[f], cols[f]] for k, f in zip(kept, frames)]).astype(np.float32)
        free = (measured > 0) & (measured >= z[frames] - OCCLUSION_MARGIN_M)
        # ... of the samples above the floor (those under it are inside the support); the tests of
        # emptiness below keep every sample: a face the depth stopped on rises from the support up
        above = facing[frames] & (samples[:, 2] >= floor_m)[None]
        unhidden = (free & above).sum(axis=1) / np.maximum(above.sum(axis=1), 1)
        # Seen through or stopped: the upper facing samples not hidden (the module docstring).
        upper_facing = facing[frames] & (samples[:, 2] >= float(np.asarray(place_world)[2]) - 1e-9)[None]
        upper = upper_facing & free
        through = upper & (measured > z[frames] + radius_m)
        n_through, n_upper = through.sum(axis=1), upper.sum(axis=1)
        # ... of a place whose upper half the frame saw: most of those samples not hidden
        saw_upper = n_upper >= SAW_UPPER * upper_facing.sum(axis=1)
        # ... and what stopped them rises: the heights of the points where the facing rays ended
        # inside the place (any height), from the 10th to the 90th percentile
        stopped = facing[frames] & free & (measured <= z[frames] + radius_m)
        ended = points[frames] * (measured / np.where(z[frames] > 1e-6, z[frames], np.inf))[..., None]
        heights = np.einsum("fj,fsj->fs", poses[frames, 2, :3], ended) + poses[frames, 2, 3][:, None]
        rise = np.array([np.subtract(*np.percentile(h[m], [90, 10])) if m.sum() > 1 else 0.0
                         for h, m in zip(heights, stopped)])
        # no more stopped than seen through (none: no evidence), or what stopped them lies flat, the
        # latter only where the frame saw the place's upper half (a few rays left ending on the
        # table under a place hidden above say nothing of what stood in it)
        empty = (n_through >= n_upper - n_through) | (saw_upper & (rise < STANDING_M))
        offsets = np.asarray(place_world, dtype=float) - cameras[frames]
        distance = np.linalg.norm(offsets, axis=1)
        pixels = cylinder_pixels(self.K, radius_m, height_m, offsets) * unhidden
        # the frames that judge whether the place was seen empty are the cylinder's own; the object's
        # size (at most 1) only lowers what the best frame would have given it
        well = pixels >= rule.min_pixels
        pixels = size * pixels
        best = int(np.argmax(pixels))
        occupied = np.flatnonzero(well & ~empty)
        worst = int(occupied[np.argmax(pixels[occupied])]) if len(occupied) else None
        return Sight(bool(pixels[best] >= rule.min_pixels), float(pixels[best]), len(self), int(in_view.sum()),
                     self.indices[frames[best]], float(distance[best]), float(unhidden[best]), rule.min_pixels,
                     int(well.sum()), int((well & empty).sum()),
                     float("nan") if worst is None else float(1 - n_through[worst] / max(n_upper[worst], 1)),
                     None if worst is None else self.indices[frames[worst]],
                     float("nan") if worst is None else float(1 - n_upper[worst] / max(upper_facing[worst].sum(), 1)),
                     size)


def projected_area(radius_m: float, height_m: float, elevation: np.ndarray) -> np.ndarray:
    """The area (m^2, at 1 m) a vertical cylinder shows a camera whose sight line to it slopes by
    `elevation` (its sine): the side's rectangle foreshortened, and the top's ellipse."""
    return np.asarray(2 * radius_m * height_m * np.sqrt(1 - elevation**2) + np.pi * radius_m**2 * elevation)


def cylinder_pixels(K: np.ndarray, radius_m: float, height_m: float, offsets: np.ndarray) -> np.ndarray:
    """The pixels a vertical cylinder of `radius_m` x `height_m` covers, unhidden, in each view
    whose camera sees its center at `offsets` ((N, 3): center less camera, in a z-up world)."""
    distance = np.maximum(np.linalg.norm(offsets, axis=1), 1e-9)
    elevation = np.abs(offsets[:, 2]) / distance  # sin of the sight line's slope
    return np.asarray(K[0, 0] * K[1, 1] * projected_area(radius_m, height_m, elevation) / distance**2)


def own_size(pixels: np.ndarray, cameras: np.ndarray, center: np.ndarray, K: np.ndarray, radius_m: float,
             height_m: float) -> float:
    """How large an object showed in its own views, as a share of a cylinder of `radius_m` x
    `height_m` standing at its `center`: each view's pixels (`pixels`, 0: not known) over those the
    cylinder would have given from that view's camera (`cameras`, (N, 3), the same world), at
    `OWN_SIZE_PERCENTILE` of the views; at most 1, and 1 when no view's pixels are known."""
    pixels = np.asarray(pixels, dtype=float)
    known = pixels > 0
    if not known.any():
        return 1.0
    cylinder = cylinder_pixels(K, radius_m, height_m, np.asarray(center, dtype=float) - np.asarray(cameras, dtype=float)[known])
    return float(min(1.0, np.percentile(pixels[known] / cylinder, OWN_SIZE_PERCENTILE)))


def view_distance(pose: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """How far apart a camera (camera -> world, (4, 4)) stands from each of `poses` ((N, 4, 4)):
    the distance of their centers plus the angle between their orientations times `TURN_SCALE_M`."""
    cosine = (np.einsum("ij,nij->n", pose[:3, :3], poses[:, :3, :3]) - 1) / 2
    turn = np.arccos(np.clip(cosine, -1.0, 1.0))
    return np.asarray(np.linalg.norm(poses[:, :3, 3] - pose[:3, 3], axis=1) + TURN_SCALE_M * turn)


def _cylinder(center: np.ndarray, radius_m: float, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples of a vertical cylinder's surface (side and top) and their outward normals."""
    angles = np.linspace(0, 2 * np.pi, AROUND, endpoint=False)
    heights = np.linspace(-height_m / 2, height_m / 2, UP)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    side = (center + radius_m * ring[None, :, :] + np.array([0, 0, 1.0]) * heights[:, None, None]).reshape(-1, 3)
    side_normals = np.broadcast_to(ring, (UP, AROUND, 3)).reshape(-1, 3)
    across = np.linspace(-radius_m * 0.6, radius_m * 0.6, ACROSS)
    top = np.array([[center[0] + x, center[1] + y, center[2] + height_m / 2] for x in across for y in across])
    top_normals = np.tile([0.0, 0.0, 1.0], (len(top), 1))
    return np.concatenate([side, top]), np.concatenate([side_normals, top_normals])
