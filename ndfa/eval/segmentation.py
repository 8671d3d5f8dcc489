"""Scoring the geometric segmentation against ground-truth instance masks (evaluation only; the
method itself never sees ground truth): matching segments to instances, relabelling segments with
the instance ids they recover, and the recall over a recording."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ndfa.core.conventions import depth_in_range
from ndfa.perception.segmentation import segment_frame
from ndfa.perception.segmentation_config import SegmentationConfig


def relabel_to_truth(segments: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None,
                     min_iou: float = 0.5, fresh_id: int = 60000) -> np.ndarray:
    """For evaluation only: each segment takes the ground-truth instance id it overlaps most if
    their IoU (over `valid` pixels, e.g. those with depth) is >= `min_iou`, else `fresh_id + label`.

    The method never uses the ids beyond grouping one frame's pixels; this only makes the
    detector's reports (which name an object by its first mask id) scorable against ground truth.
    A fresh id belongs to no ground-truth mug, so reports of such segments go unscored.
    """
    out = np.zeros_like(segments)
    for label, instance, iou in match_segments(segments, truth, valid):
        out[segments == label] = instance if iou >= min_iou else fresh_id + label
    return out


def match_segments(segments: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
                   ) -> list[tuple[int, int, float]]:
    """(segment label, best ground-truth id or 0, IoU) for every segment, over `valid` pixels."""
    mask = np.ones(segments.shape, dtype=bool) if valid is None else valid
    seg, gt = segments[mask].astype(np.int64), truth[mask].astype(np.int64)
    result = []
    gt_sizes = np.bincount(gt[gt > 0])
    for label in np.unique(seg[seg > 0]).tolist():
        inside = gt[seg == label]
        overlaps = np.bincount(inside[inside > 0])
        if len(overlaps) == 0 or overlaps.max() == 0:
            result.append((label, 0, 0.0))
            continue
        instance = int(overlaps.argmax())
        intersection = overlaps[instance]
        iou = intersection / (len(inside) + gt_sizes[instance] - intersection)
        result.append((label, instance, float(iou)))
    return result


@dataclass(frozen=True)
class SegmentationRecall:
    """How well `segment_frame` recovers ground-truth instances (`segmentation_recall`).

    observations: ground-truth instances in a frame with >= `min_points` pixels of valid depth.
    recovered: those matched by one segment with IoU >= `min_iou` (over pixels of valid depth).
    segments: segments produced; spurious: segments matching no instance with IoU >= `min_iou`.
    ms_per_frame: wall time of `segment_frame`; cpu_ms_per_frame: its process CPU time (what a
        frame costs when the machine is shared).
    """

    frames: int
    observations: int
    recovered: int
    segments: int
    spurious: int
    ms_per_frame: float
    cpu_ms_per_frame: float

    @property
    def recall(self) -> float:
        return self.recovered / self.observations if self.observations else 1.0


def segmentation_recall(frames, config: SegmentationConfig = SegmentationConfig(), min_points: int = 200,
                        min_iou: float = 0.5) -> SegmentationRecall:
    """Segment every frame that has ground-truth masks and count the instances recovered."""
    n_frames = observations = recovered = segments = spurious = 0
    seconds = cpu_seconds = 0.0
    for frame in frames:
        if frame.instances is None:
            continue
        started, cpu_started = time.perf_counter(), time.process_time()
        labels = segment_frame(frame, config)
        seconds += time.perf_counter() - started
        cpu_seconds += time.process_time() - cpu_started
        valid = depth_in_range(frame.depth, config.min_depth_m, config.max_depth_m)
        truth = frame.instances
        ious = _iou_matrix(labels[valid], truth[valid])          # (segments + 1, instances + 1)
        sizes = np.bincount(truth[valid].astype(np.int64), minlength=ious.shape[1])
        seen = np.flatnonzero(sizes >= min_points)
        seen = seen[seen > 0]
        best_per_instance = ious[1:, seen].max(axis=0) if ious.shape[0] > 1 else np.zeros(len(seen))
        present = np.unique(labels[labels > 0])
        n_frames += 1
        observations += len(seen)
        recovered += int((best_per_instance >= min_iou).sum())
        segments += len(present)
        spurious += int((ious[present, 1:].max(axis=1, initial=0.0) < min_iou).sum())
    return SegmentationRecall(n_frames, observations, recovered, segments, spurious,
                              1e3 * seconds / max(n_frames, 1), 1e3 * cpu_seconds / max(n_frames, 1))


def _iou_matrix(labels: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """IoU of every label value (rows) with every truth value (columns), from the joint histogram."""
    a, b = labels.astype(np.int64), truth.astype(np.int64)
    rows, cols = int(a.max(initial=0)) + 1, int(b.max(initial=0)) + 1
    joint = np.bincount(a * cols + b, minlength=rows * cols).reshape(rows, cols)
    union = joint.sum(axis=1)[:, None] + joint.sum(axis=0)[None, :] - joint
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, joint / union, 0.0)
