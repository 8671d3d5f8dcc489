"""How a frame without masks is segmented (`ndfa.perception.segmentation`): the parameters of
every step, in a module of their own because the plane search (`ndfa.perception.planes`), a step
the segmentation calls, reads them too.

Pure; no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ndfa.core import conventions
from ndfa.perception.objectness import ObjectnessConfig

# Which clusters of a segmented frame are objects (`ndfa.pipeline.PipelineConfig.gate`): "mugs", the
# segmentation's gate as configured (`SegmentationConfig()`: mugs); "objects", a rigid object of any
# category (`SegmentationConfig.for_objects`); "auto", objects when the NDF tells categories apart
# (NDF v3), else mugs: a model trained on mugs alone can neither encode nor name a bowl it is shown.
GATES = ("auto", "mugs", "objects")


@dataclass(frozen=True)
class SegmentationConfig:
    """How a frame without masks is segmented. Lengths in metres. The defaults fit mugs on tables
    (mugs 6-13 cm tall, 5-15 cm across, tables 0.75 m high) seen from 0.5-4 m by a 640x480 camera.

    stride: every `stride`-th pixel along each image axis is sampled (2: a quarter of the pixels).
        At 3 m a 640-px, 60 degree camera then samples a surface every ~11 mm, still under
        `dbscan_eps_m`. None: width // 320 (2 at 640x480, 1 at the sample's 320x240).
    min_depth_m, max_depth_m: depth range used (`ndfa.core.conventions`, as `ObservationConfig`'s).
    plane_distance_m: half-width of the height window of a plane's inliers (sensor noise is
        ~6 mm at 2 m); also the spacing of the height search.
    plane_max_tilt_deg: a refitted plane tilted further than this from horizontal is rejected.
    min_plane_points: a support plane must hold at least this many sampled points.
    max_planes: at most this many horizontal planes per frame (floor and a few table heights).
    min_height_m: candidates lie at least this far above their plane: the plane's own noise
        (a few mm) stays below. The lowest centimetre of an object is lost here and at filling.
    noise_sigmas, noise_base_m, noise_quadratic_per_m: ... and at least `noise_sigmas` times the
        depth noise sigma(z) = base + quadratic z^2 at the point's depth (the sensor model of
        `ndfa.sim.noise.DepthNoise`, ~Kinect v1 / RealSense: 7 mm at 2 m, 17 mm at 3.3 m). Off (0)
        by default: it cut the bottom off far mugs (recall on the `paper` scene fell by several
        points at 1.5-2.5 sigmas), and the far table tops' noise blobs it was meant to stop are
        caught by the cluster tests (`top_noise_sigmas`, the tall-column and bottom tests).
    min_plane_spread_m: a support plane's inliers must spread at least this much (standard
        deviation along their narrower horizontal axis): a strip of wall at one height is no table.
    band_height_m: ... and at most this far; above `max_object_height_m` on purpose, so that
        taller things (legs, walls) show points above an object's height and are recognised.
    footprint_cell_m, footprint_margin_m: a candidate must lie within `footprint_margin_m` of a
        grid cell holding inliers of its plane (horizontally): objects stand on the plane, whose
        visible surface surrounds them; things merely at the right height elsewhere do not.
    column_radius_m: a candidate with a point of the band higher than `max_object_height_m`
        within this distance horizontally is part of something taller (a wall, a cabinet's front,
        a leg) and dropped; about the reach of the 5 cm grid cells this test used before (a disc of
        a 5 cm cell's area has a 2.8 cm radius), without their edges (docs/segmentation.md).
    dbscan_eps_m, dbscan_min_points: DBSCAN's radius and core-point count. Mugs stand at least
        1 cm apart in the synthetic world; two closer than eps become one cluster.
    dbscan_voxel_m: DBSCAN runs on the candidates binned in voxels of this side, each voxel one
        point at its points' mean weighing their number (`ndfa.perception.dbscan.voxel_dbscan`):
        the clusters follow the exact ones up to about a voxel, for less CPU (docs/speed.md, seg33
        and seg35: masks and detections checked). 0: exact DBSCAN (before 2026-12-06).
    min_cluster_points: smaller clusters are dropped (at stride 2, a mug 4 m away still has ~60).
    min_extent_m, max_extent_m: horizontal extent (diagonal of the cluster's bounding box in the
        plane) of a kept cluster.
    min_object_height_m, max_object_height_m: height of a kept cluster's top above its plane;
        the top must also reach `top_noise_sigmas` times the depth noise at the cluster's median
        depth (noise of a far table top piles up into blobs 3-4 cm high).
    max_bottom_m: a kept cluster's bottom (5th percentile of height) is at most this (or 3 sigma of
        the depth noise) above its plane: objects stand on it; a wall seen above a table does not.
    occluder_look_px, occluder_gap_m: a cluster is dropped when, over most of its top edge, a
        surface `occluder_gap_m` closer lies within `occluder_look_px` pixels above (see `_hidden_above`).
    occluder_band_px: pixels without depth between a cluster's top and the surface above are
        skipped, up to this many: a depth camera leaves a band without depth at an occluding edge
        (a RealSense D435 aligned to colour: up to 20 px), and a nearer table top behind such a band
        still hides what is below it. 24 drops the office's desk-leg foot and keeps the kitchen
        halves at 0 changes with both mugs (docs/results.md, "The hand-held office"). 0: the band
        ends the look (before 2026-12-03).
    occluder_upper_half: the hidden test looks above the top edge of the cluster's upper half only
        (its samples at least half its top above the plane), not of every sample: the depth noise
        of a far floor or table top, clustered with the foot of a leg whose upper part a nearer
        table top hides, adds columns topped by the noise, with more floor above them, that
        outvoted the leg's (docs/categories.md, "The office with v3"). False (the mugs' gate):
        every sample, as before.
    fill_distance_m: a full-resolution pixel joins a cluster whose nearest point is closer than this.
    image_margin_px: a cluster with a sample within this many pixels of the image border is
        dropped: the image cuts it, so its shape (the gate's evidence) is unknown; on real data such
        cut-off pieces of counters and chairs were a large share of the spurious objects, and the
        detector sees a mug again whole a few frames later. The border is that of the pixels with
        depth (a Kinect v1 has none in its last 8 columns: a mug cut there looked whole). 0: off.
    objectness: the mug-likeness gate applied after the size filters (`ndfa.perception.objectness`):
        on real tables most clusters are clutter (magazines, counter edges, chair backs). None: off.
    max_outline_goes_on: a kept cluster whose outline goes on into something larger by more than
        this share (`ndfa.perception.segmentation.Outline.goes_on`: its top edge, both its sides, or
        the points right under its base continue) is turned away ("attached"): a chair's slanted
        leg, a strip of a wall or a cabinet's front, a chair's back at a table's edge. None (the
        mugs' gate): not measured. The objects' gate (`for_objects`): 0.5 (docs/categories.md,
        "Objects in real rooms").
    outline_look_samples, outline_gap_m: from each outline sample, this many samples outwards are
        looked at; the surface goes on where the farthest of them lies within max(`outline_gap_m`,
        3 sigma of the depth noise) of the outline's depth.
    base_band_m, hanging_radius_m, hanging_min_m, hanging_depth_m: a cluster's base is its points
        up to `base_band_m` above the plane; a base point hangs where a point of the frame lies
        within `hanging_radius_m` of it horizontally, between max(`hanging_min_m`, 3 sigma) and
        `hanging_depth_m` below the plane (right below: a table's own top hides the first
        centimetres under an object on it).
    plane_search_every: with a `ndfa.perception.segmentation.PlaneTracker` (a session's frames in
        order: `ndfa.pipeline.ChangeDetectionPipeline.new_plane_tracker`), the support planes'
        heights are searched in full every this many frames, and in any frame where one of the
        previous frame's planes, refitted to its points, fails the plane tests; between, those
        refitted planes are the frame's (`ndfa.perception.planes.track_horizontal_planes`; a
        plane coming into view waits for the next full search). 1 (default): a full search in
        every frame. Off because at 10 it cost 2 false changes on `paper --raw --textures` (TP 12 /
        FP 1 -> 3, in a cluster of close mugs) for 11-19 % of the segmentation's CPU (docs/speed.md,
        seg31). Without a tracker (`segment_frame` alone) every frame is searched in full.
    split_max_length_m: a cluster the gate finds too long, with a footprint up to this long, is
        split in two by 2-means on its footprint (`ndfa.perception.split`: two mugs closer than
        `dbscan_eps_m` form one cluster); the halves are kept if both pass the gate. 0 (default):
        no splitting. Off because on redkitchen it cut rows of brochures on a shelf (12 cm tall,
        20 cm long) into mug-sized pairs, and geometry alone does not tell them from two mugs;
        try 0.30 where mugs stand close together (docs/segmentation.md).
    """

    stride: int | None = None
    min_depth_m: float = conventions.MIN_DEPTH_M
    max_depth_m: float = conventions.MAX_DEPTH_M
    plane_distance_m: float = 0.01
    plane_max_tilt_deg: float = 10.0
    min_plane_points: int = 300
    max_planes: int = 4
    min_plane_spread_m: float = 0.04
    min_height_m: float = 0.01
    noise_sigmas: float = 0.0
    noise_base_m: float = 0.001
    noise_quadratic_per_m: float = 0.0015
    band_height_m: float = 0.30
    footprint_cell_m: float = 0.05
    footprint_margin_m: float = 0.10
    column_radius_m: float = 0.03
    dbscan_eps_m: float = 0.025
    dbscan_min_points: int = 4
    dbscan_voxel_m: float = 0.01
    min_cluster_points: int = 30
    min_extent_m: float = 0.04
    max_extent_m: float = 0.30
    min_object_height_m: float = 0.03
    max_object_height_m: float = 0.22
    top_noise_sigmas: float = 4.0
    max_bottom_m: float = 0.06
    occluder_look_px: int = 6
    occluder_gap_m: float = 0.10
    occluder_band_px: int = 24
    occluder_upper_half: bool = False
    fill_distance_m: float = 0.015
    image_margin_px: int = 4
    objectness: ObjectnessConfig | None = field(default_factory=ObjectnessConfig)
    max_outline_goes_on: float | None = None
    outline_look_samples: int = 3
    outline_gap_m: float = 0.03
    base_band_m: float = 0.03
    hanging_radius_m: float = 0.02
    hanging_min_m: float = 0.02
    hanging_depth_m: float = 0.10
    split_max_length_m: float = 0.0
    plane_search_every: int = 1

    def for_objects(self) -> SegmentationConfig:
        """These settings with the gate for objects of every category (`ObjectnessConfig.objects`)
        and room for their size: tops up to 36 cm (a bottle; the band above it to 45 cm, so that a
        wall's foot still shows as a column), footprints up to 42 cm across, tops from 2.5 cm (a
        flat box; papers and cables stay below); and the outline rule (`max_outline_goes_on`):
        a room's pieces of something larger have an object's size too."""
        return replace(self, objectness=ObjectnessConfig.objects(), min_object_height_m=0.025,
                       max_object_height_m=0.36, band_height_m=max(self.band_height_m, 0.45), max_extent_m=0.42,
                       max_outline_goes_on=0.5, occluder_upper_half=True)

    def __post_init__(self) -> None:
        if self.stride is not None and self.stride < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride}")
        if not 0 <= self.dbscan_voxel_m < self.dbscan_eps_m:
            raise ValueError(f"need 0 <= dbscan_voxel_m < dbscan_eps_m, got {self.dbscan_voxel_m}")
        if self.plane_search_every < 1:
            raise ValueError(f"plane_search_every must be >= 1, got {self.plane_search_every}")
        if not self.min_height_m < self.max_object_height_m < self.band_height_m:
            raise ValueError("need min_height_m < max_object_height_m < band_height_m")
