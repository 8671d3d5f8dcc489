"""Finding the mugs of a real sequence: the segmentation `ndfa detect` runs on raw data (support
planes, mug-sized clusters above them, the objectness gate: `ndfa.perception.segmentation`), the
masks turned into partial clouds as the pipeline does (`ndfa.perception.observations`), and the
clouds tracked over frames by where they are in the world (the given poses).

Tracking: each view's visible centroid joins the track whose mean horizontal position is nearest,
within `track_radius_m` (a mug's visible centroid moves by about its radius as the camera goes
round it; two mugs on a table stand farther apart), at most one view per track and frame; others
start tracks of their own. Tracks seen in enough frames are the mugs; clutter that passes the gate
now and then (a chair rail, brochures on a counter) is seen in a few frames only.

The NDF's own occupancy gate (`PipelineConfig.min_segment_occupancy`) is not applied: it depends on
the weights under test, and the views the protocol measures must be the same for every model.

No file I/O here.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np

from ndfa.core.errors import DataError
from ndfa.core.frame import Frame
from ndfa.core.geometry import transform_points
from ndfa.perception.observations import ObservationConfig, extract_observations
from ndfa.perception.segmentation import segment_frame
from ndfa.perception.segmentation_config import SegmentationConfig


@dataclass(frozen=True)
class TrackConfig:
    """How mugs are found and tracked. Lengths in metres.

    segmentation, observation: the detector's defaults (what `ndfa detect` does on raw data).
        A frame that has instance masks (a simulated recording) uses them instead.
    track_radius_m: a view joins a track whose mean visible centroid is within this, horizontally.
    min_views, min_view_fraction: a track is a mug when seen in at least this many views and this
        fraction of the frames looked at (on redkitchen, every 2nd frame: the mugs 86 and 42 views
        of 250, the next of 22 tracks 8; every frame: 172 and 82 of 500, then 16).
    """

    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    track_radius_m: float = 0.06
    min_views: int = 10
    min_view_fraction: float = 0.05

    def __post_init__(self) -> None:
        if not self.track_radius_m > 0:
            raise ValueError(f"track_radius_m must be > 0, got {self.track_radius_m}")
        if self.min_views < 2:
            raise ValueError(f"min_views must be >= 2, got {self.min_views}")
        if not 0 <= self.min_view_fraction <= 1:
            raise ValueError(f"min_view_fraction must be in [0, 1], got {self.min_view_fraction}")


@dataclass(frozen=True)
class MugView:
    """One view of one tracked mug: what the NDF is given, and what the protocol compares it with.

    track: the mug (0, 1, ...: brightest first). centroid_world: mean of the visible points in the
    (levelled) world. brightness: mean grey level (0-255) of the mask's colour pixels, nan without
    colour (a Kinect's colour is not exactly registered to depth: a cue, not a measurement).
    """

    track: int
    frame_index: int
    timestamp: float
    pose_world_camera: np.ndarray
    points_camera: np.ndarray
    centroid_world: np.ndarray
    n_pixels: int
    brightness: float


@dataclass
class MugTracks:
    """The views of the tracks kept as mugs, and counts that explain what was (not) found."""

    views: list[MugView]
    mugs: int
    frames: int                 # frames looked at
    frames_with_segments: int   # frames where the segmentation kept a cluster
    observations: int           # observations (masks with enough depth, not cut by the border)
    track_sizes: list[int]      # views of every track, largest first (kept and dropped)
    min_views: int              # what a track needed to be kept


def find_mugs(frames: Iterable[Frame], config: TrackConfig = TrackConfig()) -> MugTracks:
    """Segment, observe and track the mugs of `frames` (levelled, with poses); see the module docstring."""
    tracks: list[_Track] = []
    n_frames = with_segments = n_observations = 0
    for frame in frames:
        n_frames += 1
        if frame.instances is None:
            frame = replace(frame, instances=segment_frame(frame, config.segmentation))
        observations, _ = extract_observations(frame, config.observation)
        with_segments += bool(frame.instances.any())
        n_observations += len(observations)
        candidates = []
        for observation in observations:
            centroid = transform_points(frame.pose_world_camera, observation.points_camera).mean(axis=0)
            mask = frame.instances == observation.instance_id
            brightness = float(frame.rgb[mask].mean()) if frame.rgb is not None else float("nan")
            candidates.append((observation, centroid, brightness))
        _assign(tracks, frame, candidates, config.track_radius_m)

    need = max(config.min_views, int(np.ceil(config.min_view_fraction * n_frames)))
    kept = [track for track in tracks if len(track.views) >= need]
    kept.sort(key=lambda t: -np.nan_to_num(np.median([v.brightness for v in t.views]), nan=-1.0))
    views = [replace(view, track=number) for number, track in enumerate(kept) for view in track.views]
    return MugTracks(views=views, mugs=len(kept), frames=n_frames, frames_with_segments=with_segments,
                     observations=n_observations, track_sizes=sorted((len(t.views) for t in tracks), reverse=True),
                     min_views=need)


def no_mugs_message(tracks: MugTracks, wanted: int) -> str:
    """Why fewer than `wanted` mugs were found, in one line (without the sequence's name)."""
    found = f"{tracks.mugs} mug{'s' * (tracks.mugs != 1)} found (wanted {wanted})"
    if tracks.frames == 0:
        return f"{found}: no frames"
    if tracks.frames_with_segments == 0:
        return (f"{found}: the segmentation kept no mug-sized cluster above a support plane in any of "
                f"{tracks.frames} frames (world not z-up? depth in the wrong units? no table in view?)")
    if tracks.observations == 0:
        return (f"{found}: {tracks.frames_with_segments} of {tracks.frames} frames had segments, but none became an "
                "observation (too few pixels with depth, or cut by the image border)")
    sizes = ", ".join(str(s) for s in tracks.track_sizes[:5])
    return (f"{found}: {tracks.observations} observations in {tracks.frames} frames fell into "
            f"{len(tracks.track_sizes)} position tracks of {sizes}{' ...' * (len(tracks.track_sizes) > 5)} views; "
            f"a mug needs {tracks.min_views} (poses that drift make one mug several tracks)")


def require_mugs(tracks: MugTracks, wanted: int, where: str) -> None:
    """Raise DataError (one line naming `where`) unless at least `wanted` mugs were found."""
    if tracks.mugs < wanted:
        raise DataError(f"{where}: {no_mugs_message(tracks, wanted)}")


@dataclass
class _Track:
    views: list[MugView] = field(default_factory=list)
    xy_sum: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @property
    def xy(self) -> np.ndarray:
        mean: np.ndarray = self.xy_sum / len(self.views)
        return mean

    def add(self, view: MugView) -> None:
        self.views.append(view)
        self.xy_sum += view.centroid_world[:2]


def _assign(tracks: list[_Track], frame: Frame, candidates: list, radius: float) -> None:
    """Give each of the frame's observations to the nearest free track within `radius` (nearest
    pairs first), or a new track."""
    pairs = sorted((float(np.linalg.norm(track.xy - centroid[:2])), c, t)
                   for c, (_, centroid, _) in enumerate(candidates) for t, track in enumerate(tracks))
    taken_tracks: set[int] = set()
    track_of: dict[int, int] = {}
    for distance, c, t in pairs:
        if distance > radius:
            break
        if c in track_of or t in taken_tracks:
            continue
        track_of[c] = t
        taken_tracks.add(t)
    for c, (observation, centroid, brightness) in enumerate(candidates):
        view = MugView(-1, frame.index, frame.timestamp, frame.pose_world_camera, observation.points_camera,
                       centroid, observation.n_pixels, brightness)
        if c not in track_of:
            tracks.append(_Track())
            track_of[c] = len(tracks) - 1
        tracks[track_of[c]].add(view)
