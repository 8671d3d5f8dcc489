"""Reading a TUM RGB-D folder (https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats) as `Frame`s.

A TUM folder holds `rgb.txt` and `depth.txt` (lines "timestamp relative/path.png", '#' comments),
optionally `groundtruth.txt` (lines "timestamp tx ty tz qx qy qz qw": the colour camera's optical
frame in the world, i.e. pose_world_camera with OpenCV axes), and the PNGs they name (`rgb/`,
`depth/` or `depths/`). Depth PNGs are 16-bit, `depth_scale` units per metre (TUM: 5000).

`TumFolder` only reads the three text files when it opens, so every problem with the folder's
index (missing depth.txt, unreadable lines, poses that cannot be placed) shows before any image is
decoded; `frames()` then decodes one frame at a time. The text files are parsed in tum_lists.py,
the PNGs decoded in tum_images.py, the file names are tum_layout.py's; writing a recording is
`ndfa.io.ingest.tum`'s job.

Decisions, each counted or noted so the summary says what happened:
- each depth frame takes the rgb frame nearest in time within `max_dt`, one-to-one and closest
  pairs first (as TUM's associate.py); a depth frame with no rgb partner is *kept* with rgb None
  (ndfa's method needs depth, colour is for looking at), and counted in `depth_without_rgb`;
- poses are interpolated to the depth stamps (linear translation, slerp rotation); a frame outside
  the groundtruth's time span, or inside a gap longer than `tum_lists.MAX_POSE_GAP_S`, is dropped;
- a list whose lines are out of time order is sorted by stamp (with a warning); stamps that are
  not usable even so (repeated, or negative) make the folder fall back to file order: line i of depth.txt pairs with line i of rgb.txt, frames get synthetic stamps
  i / `FALLBACK_RATE_HZ`, and groundtruth.txt pairs by line when it has one line per depth frame;
- a frame whose depth, rgb or mask PNG is missing is skipped and counted (checked when the folder
  is indexed, so the counts are known before anything is written).

Files beyond the TUM format that ndfa's exporter writes and this reader uses when present:
`calibration.txt` ("fx fy cx cy", used when no intrinsics are given), `masks/` (instance PNGs named
as the depth PNGs, used when no masks folder is given), `ndfa_ground_truth.json`
(the recording's ground truth) and `ndfa_true_poses.txt` (true poses when groundtruth.txt holds
perturbed ones; groundtruth.txt format).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ndfa.core.errors import IngestError
from ndfa.io.ingest import MAX_DT_S
from ndfa.io.ingest.tum_images import check_size, read_depth, read_mask, read_rgb
from ndfa.io.ingest.tum_layout import (
    CALIBRATION,
    DEFAULT_INTRINSICS,
    DEPTH_LIST,
    DEPTH_SCALE,
    GROUND_TRUTH_JSON,
    GROUNDTRUTH,
    INTRINSICS_PRESETS,
    MASKS_DIR,
    RGB_LIST,
    TRUE_POSES,
    Intrinsics,
    read_calibration,
)
from ndfa.io.ingest.tum_lists import StampedList, associate, poses_at, read_list
from ndfa.io.recording import Frame
from ndfa.io.recording.ground_truth import ground_truth_problem
from ndfa.io.tum_format import pose_from_fields

# Frame rate of the synthetic stamps when the folder's own stamps cannot be used (TUM's Kinect rate).
FALLBACK_RATE_HZ = 30.0


@dataclass
class TumEntry:
    """One depth frame of the folder, before its images are read."""

    line: int  # 0-based position in depth.txt (data lines only)
    timestamp: float  # seconds, as the frame will be written
    depth_path: Path
    rgb_path: Path | None
    mask_path: Path | None = None
    pose: np.ndarray | None = None  # (4, 4) pose_world_camera
    true_pose: np.ndarray | None = None  # (4, 4) from ndfa_true_poses.txt


@dataclass
class TumFolder:
    """A TUM RGB-D folder, indexed: which frames it has, their files and poses. See the module docstring.

    intrinsics: None (calibration.txt if present, else TUM's ROS default), "fr1" | "fr2" | "fr3",
        or (fx, fy, cx, cy) in pixels.
    masks: a folder with one 16-bit instance PNG per depth frame, named as the depth PNG (default:
        the folder's masks/ when it has one, as ndfa's exporter writes it).
    """

    folder: Path
    intrinsics: Intrinsics = None
    depth_scale: float = DEPTH_SCALE
    masks: Path | None = None
    max_dt: float = MAX_DT_S
    entries: list[TumEntry] = field(init=False)
    K: np.ndarray = field(init=False)
    has_groundtruth: bool = field(init=False)
    dropped: Counter = field(init=False)  # reason -> frames left out
    warnings: list[str] = field(init=False)
    info: dict[str, Any] = field(init=False)  # what the recording's meta should say about the import

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        if not self.folder.is_dir():
            raise IngestError(f"{self.folder}: no such directory")
        if not self.depth_scale > 0:
            raise IngestError(f"depth scale must be > 0 units per metre, got {self.depth_scale}")
        if self.masks is not None and not Path(self.masks).is_dir():
            raise IngestError(f"{self.masks}: no such mask directory")
        instances = f"masks from {self.masks}" if self.masks is not None else "none"
        if self.masks is None and (self.folder / MASKS_DIR).is_dir():
            self.masks, instances = self.folder / MASKS_DIR, f"masks from {MASKS_DIR}/ in the folder"
        self.dropped, self.warnings = Counter(), []
        self.K, intrinsics_info = self._resolve_intrinsics()
        self.info = {"folder": str(self.folder.resolve()), "intrinsics": intrinsics_info,
                     "png_depth_scale": self.depth_scale, "timestamps": "from depth.txt", "instances": instances}
        self.entries = self._index()

    # -- public -------------------------------------------------------------------------------

    @property
    def needs_poses(self) -> bool:
        """True when the folder has no groundtruth.txt: poses must come from an estimator."""
        return not self.has_groundtruth

    @property
    def ground_truth(self) -> dict | None:
        """The contents of ndfa_ground_truth.json, or None when the folder has none."""
        path = self.folder / GROUND_TRUTH_JSON
        if not path.is_file():
            return None
        try:
            value = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise IngestError(f"{path} is not valid JSON: {error}") from error
        if not isinstance(value, dict):
            raise IngestError(f"{path} must hold a JSON object, got {type(value).__name__}")
        problem = ground_truth_problem(value)
        if problem:
            raise IngestError(f"{path}: {problem}")
        return value

    def frames(self, images: bool = True) -> Iterator[Frame]:
        """Decode the indexed frames in order, numbered from 0. With images=False only depth is read
        (rgb and instances None) and every pose is an identity placeholder: what a pose estimator needs.
        A folder without poses (`needs_poses`) gives identity placeholders too: a recording written
        from it says "poses": "none", and the writer leaves them out."""
        for index, entry in enumerate(self.entries):
            yield self._load(entry, index, images)

    def keep_frames(self, start: int, stop: int | None) -> None:
        """Keep only the paired frames [start, stop) (stop None: to the end), renumbered from 0."""
        paired = len(self.entries)
        if start < 0 or (stop is not None and stop <= start):
            raise IngestError(f"{self.folder}: frames {start}:{'' if stop is None else stop} is not a range of frames "
                              "(start >= 0, stop > start)")
        if start >= paired:
            raise IngestError(f"{self.folder}: frames {start}:{'' if stop is None else stop} selects no frame: the "
                              f"folder has {paired} paired frames")
        self.entries = self.entries[start:stop]
        self.info["frames_selected"] = {"start": start, "stop": start + len(self.entries), "of": paired}

    def set_poses(self, poses: list[np.ndarray]) -> None:
        """Give the frames that `frames(images=False)` yields their poses (one per frame, in order);
        poses from groundtruth.txt, if any, become the true poses."""
        if len(poses) != len(self.entries):
            raise IngestError(f"{self.folder}: the pose estimator returned {len(poses)} poses for {len(self.entries)} frames")
        for entry, pose in zip(self.entries, poses):
            pose = np.asarray(pose, dtype=np.float64)
            if pose.shape != (4, 4):
                raise IngestError(f"{self.folder}: the pose estimator returned a pose of shape {pose.shape}, expected (4, 4)")
            entry.true_pose = entry.pose
            entry.pose = pose

    # -- index: text files --------------------------------------------------------------------

    def _index(self) -> list[TumEntry]:
        depth_list = read_list(self.folder, DEPTH_LIST, required=True)
        rgb_list = read_list(self.folder, RGB_LIST, required=False, likely_per_second=depth_list.per_second)
        groundtruth = read_list(self.folder, GROUNDTRUTH, required=False, likely_per_second=depth_list.per_second)
        self.has_groundtruth = groundtruth is not None
        # Lines out of time order are sorted by stamp when the stamps allow it for depth and rgb
        # alike; otherwise both stay in file order, to be paired line by line.
        depth_sorted = depth_list.in_time_order(negative_ok=False)
        rgb_sorted = rgb_list.in_time_order(negative_ok=True) if rgb_list is not None else None
        if depth_sorted.increasing and (rgb_sorted is None or rgb_sorted.increasing):
            depth_list, rgb_list = depth_sorted, rgb_sorted
            groundtruth = groundtruth.in_time_order(negative_ok=True) if groundtruth else None
        depth_list, rgb_list, groundtruth = (self._warned(stamped) for stamped in (depth_list, rgb_list, groundtruth))
        depth_usable = depth_list.increasing and bool(np.all(depth_list.stamps >= 0))
        in_time_order = depth_usable and (rgb_list is None or rgb_list.increasing)

        if in_time_order:
            rgb_of = associate(depth_list.stamps, rgb_list.stamps, self.max_dt) if rgb_list else {}
            stamps = depth_list.stamps
        else:
            bad = depth_list if not depth_usable else rgb_list
            self._warn(f"{bad.path}: timestamps cannot be used ({bad.disorder(negative_ok=bad is rgb_list)}); "
                       f"using file order with synthetic stamps at {FALLBACK_RATE_HZ:g} Hz, and pairing {RGB_LIST} "
                       f"and {DEPTH_LIST} line by line")
            self.info["timestamps"] = f"synthetic, file order at {FALLBACK_RATE_HZ:g} Hz ({bad.path.name} not increasing)"
            rgb_of = {i: i for i in range(min(len(depth_list.stamps), len(rgb_list.stamps)))} if rgb_list else {}
            stamps = np.arange(len(depth_list.stamps)) / FALLBACK_RATE_HZ

        entries = []
        for i, fields in enumerate(depth_list.fields):
            depth_path = self._data_path(fields[0])
            rgb_path = self._data_path(rgb_list.fields[rgb_of[i]][0]) if i in rgb_of else None
            mask_path = Path(self.masks) / depth_path.name if self.masks is not None else None
            entries.append(TumEntry(i, float(stamps[i]), depth_path, rgb_path, mask_path))
        self.info["depth_without_rgb"] = len(entries) - len(rgb_of)

        if groundtruth is not None:
            entries = self._place_poses(entries, groundtruth, depth_list, in_time_order, "pose")
            self.info["poses"] = f"given ({GROUNDTRUTH})"
            true_poses = read_list(self.folder, TRUE_POSES, required=False, likely_per_second=depth_list.per_second)
            if true_poses is not None:
                true_poses = self._warned(true_poses.in_time_order(negative_ok=True) if in_time_order else true_poses)
            if true_poses is not None:
                entries = self._place_poses(entries, true_poses, depth_list, in_time_order, "true_pose")
        entries = [entry for entry in entries if self._files_exist(entry)]
        if not entries:
            self._warn(f"{self.folder}: no frame of {DEPTH_LIST} can be imported")
        return entries

    def _warned(self, stamped: StampedList | None) -> StampedList | None:
        """A list as it is used, what reading it worked around (units, order) warned about."""
        if stamped is None:
            return None
        for message in stamped.warnings:
            self._warn(message)
        return stamped

    def _files_exist(self, entry: TumEntry) -> bool:
        """Whether the entry's PNGs are there; count the frame as dropped when one is not."""
        for kind, path in (("depth", entry.depth_path), ("rgb", entry.rgb_path), ("mask", entry.mask_path)):
            if path is not None and not path.is_file():
                self.dropped[f"missing {kind} PNG"] += 1
                return False
        return True

    def _data_path(self, relative: str) -> Path:
        """The image a list line names; 'depth/x.png' is also found as 'depths/x.png' and vice versa."""
        path = self.folder / relative
        head, separator, rest = relative.partition("/")
        alias = {"depth": "depths", "depths": "depth"}.get(head)
        if not path.exists() and alias and separator and (self.folder / alias / rest).exists():
            return self.folder / alias / rest
        return path

    def _place_poses(self, entries: list[TumEntry], poses: StampedList, depth_list: StampedList,
                     in_time_order: bool, attribute: str) -> list[TumEntry]:
        """Set entry.<attribute> from a groundtruth-format file; drop and count frames it cannot place."""
        matrices = np.array([pose_from_fields(row) for row in poses.fields]).reshape(-1, 4, 4)
        if len(matrices) == 0:
            raise IngestError(f"{poses.path} holds no poses")
        if in_time_order and poses.increasing:
            placed = poses_at(poses.stamps, matrices, depth_list.stamps[[e.line for e in entries]])
        elif len(matrices) == len(depth_list.stamps):
            self._warn(f"{poses.path}: pairing poses with {DEPTH_LIST} line by line (timestamps not usable)")
            placed = [(matrices[e.line], None) for e in entries]
        elif poses.increasing:
            placed = poses_at(poses.stamps, matrices, depth_list.stamps[[e.line for e in entries]])
        else:
            raise IngestError(f"{poses.path}: timestamps are not increasing and it has {len(matrices)} poses for "
                              f"{len(depth_list.stamps)} depth frames, so its poses cannot be placed")
        kept = []
        for entry, (pose, reason) in zip(entries, placed):
            if pose is None:
                self.dropped[f"{reason} ({poses.path.name})"] += 1
                continue
            setattr(entry, attribute, pose)
            kept.append(entry)
        return kept

    def _resolve_intrinsics(self) -> tuple[np.ndarray, dict[str, Any]]:
        chosen, source = self.intrinsics, None
        if isinstance(chosen, str):
            if chosen not in INTRINSICS_PRESETS:
                raise IngestError(f"unknown intrinsics preset {chosen!r}; expected one of "
                                  f"{', '.join(INTRINSICS_PRESETS)} or fx,fy,cx,cy")
            source, chosen = f"TUM preset {chosen}", INTRINSICS_PRESETS[chosen]
        elif chosen is not None:
            source = "given"
        elif (self.folder / CALIBRATION).is_file():
            source, chosen = CALIBRATION, read_calibration(self.folder / CALIBRATION)
        else:
            source, chosen = "TUM ROS default (no intrinsics given)", DEFAULT_INTRINSICS
        where = f"{self.folder / CALIBRATION}: " if source == CALIBRATION else ""  # else an option: no file to name
        try:
            fx, fy, cx, cy = (float(v) for v in chosen)
        except (TypeError, ValueError):
            raise IngestError(f"{where}intrinsics must be (fx, fy, cx, cy), got {chosen!r}") from None
        if not (0 < fx < np.inf and 0 < fy < np.inf and np.isfinite([cx, cy]).all()):
            raise IngestError(f"{where}intrinsics must have finite fx, fy > 0 and finite cx, cy, got {chosen!r}")
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return K, {"source": source, "fx": fx, "fy": fy, "cx": cx, "cy": cy}

    def _warn(self, message: str) -> None:
        self.warnings.append(message)

    # -- images -------------------------------------------------------------------------------

    def _load(self, entry: TumEntry, index: int, images: bool) -> Frame:
        """Decode one entry into a Frame."""
        depth = read_depth(entry.depth_path, self.depth_scale)
        rgb = instances = None
        if images and entry.rgb_path is not None:
            rgb = read_rgb(entry.rgb_path)
            check_size(entry.rgb_path, rgb.shape[:2], entry.depth_path, depth.shape)
        if images and entry.mask_path is not None:
            instances = read_mask(entry.mask_path)
            check_size(entry.mask_path, instances.shape, entry.depth_path, depth.shape)
        pose, true_pose = (entry.pose, entry.true_pose) if images and entry.pose is not None else (np.eye(4), None)
        try:
            return Frame(index=index, timestamp=entry.timestamp, rgb=rgb, depth=depth, K=self.K,
                         pose_world_camera=pose, instances=instances, pose_world_camera_true=true_pose)
        except ValueError as error:
            raise IngestError(f"{entry.depth_path}: cannot make a frame of it: {error}") from error


def read_tum_folder(folder: str | Path, **options: Any) -> Iterator[Frame]:
    """Yield the Frames of a TUM folder (options as `TumFolder`); the folder must have groundtruth.txt."""
    tum = TumFolder(Path(folder), **options)
    if tum.needs_poses:
        raise IngestError(no_poses_message(tum.folder))
    yield from tum.frames()


def no_poses_message(folder: Path) -> str:
    return (f"{folder} has no {GROUNDTRUTH}, so its frames have no poses: import it with `ndfa ingest tum` "
            "(`ndfa detect` then estimates them) or with `--poses estimate`")
