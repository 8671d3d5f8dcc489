"""Per-frame figures of the geometric segmentation: which clusters pass, their shapes, and what the
objectness gate (`ndfa.perception.objectness`) makes of them.

    python studies/segmentation_study.py REC.mcap [--start 0] [--stop N] [--step 10] [--clusters]

Each frame is segmented with the gate off (`objectness=None`), so every cluster that passes the
size filters gets a label; the gate's verdict is then printed next to it. With `--clusters` every
cluster of `min_cluster_points` is listed: points, bottom/top above its plane, footprint
length x width, depth, what the size filters said, and the gate's verdict. When the recording has
instance masks, each labelled segment is matched to ground truth (IoU >= 0.5 over pixels with
depth), and the summary counts the gate's verdicts on true mugs and on the rest separately.
Used for the figures in docs/segmentation.md.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import Counter

import numpy as np

from ndfa.eval.segmentation import match_segments
from ndfa.io.recording import RecordingReader
from ndfa.perception.objectness import ObjectnessConfig, rejection
from ndfa.perception.segmentation import explain_frame
from ndfa.perception.segmentation_config import SegmentationConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording")
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--stop", type=int, default=None)
    parser.add_argument("--step", type=int, default=10)
    parser.add_argument("--clusters", action="store_true", help="list every cluster, not only per-frame counts")
    args = parser.parse_args()

    config = dataclasses.replace(SegmentationConfig(), objectness=None)
    gate = ObjectnessConfig()
    reader = RecordingReader(args.recording)
    size_verdicts: Counter[str] = Counter()
    gate_verdicts = {"mug": Counter(), "other": Counter(), "unknown": Counter()}
    shapes: dict[str, list] = {"mug": [], "other": [], "unknown": []}
    frames = 0
    for frame in reader.frames(args.start, args.stop, args.step):
        frames += 1
        labels, verdicts = explain_frame(frame, config)
        truth = {}
        if frame.instances is not None:
            truth = {label: instance for label, instance, iou in match_segments(labels, frame.instances, frame.depth > 0)
                     if iou >= 0.5 and instance}
        passed = [v for v in verdicts if v.rejected is None]
        gated = [rejection(v.shape, gate) for v in passed]
        size_verdicts.update(v.rejected or "passed" for v in verdicts)
        print(f"frame {frame.index:4d}: {len(verdicts):3d} clusters, {len(passed):3d} pass the size filters, "
              f"{gated.count(None):3d} pass the gate"
              + (f", {len(truth)} segments match a true instance" if frame.instances is not None else ""))
        for verdict in verdicts:
            s = verdict.shape
            kind = "unknown" if frame.instances is None else ("mug" if verdict.label in truth else "other")
            gate_reason = rejection(s, gate) if verdict.rejected is None else None
            if verdict.rejected is None:
                gate_verdicts[kind][gate_reason or "kept"] += 1
                shapes[kind].append((s.top_m, s.bottom_m, s.length_m, s.width_m))
            if args.clusters:
                size = verdict.rejected or f"label {verdict.label}"
                gated_text = "" if verdict.rejected else f"  gate: {gate_reason or 'kept'}"
                truth_text = f"  truth {truth[verdict.label]}" if verdict.label in truth else ""
                print(f"    {s.points:5d} pts  h {s.bottom_m * 100:5.1f}..{s.top_m * 100:5.1f} cm  "
                      f"footprint {s.length_m * 100:5.1f} x {s.width_m * 100:4.1f} cm  at {s.depth_m:4.2f} m  "
                      f"{size}{gated_text}{truth_text}")

    print(f"\n{frames} frames; clusters by the size filters: {dict(size_verdicts)}")
    for kind, counts in gate_verdicts.items():
        if not counts:
            continue
        print(f"gate on {kind} segments ({sum(counts.values())}): {dict(counts)}")
        table = np.array(shapes[kind]) * 100
        for name, column in zip(("top", "bottom", "length", "width"), table.T):
            p = np.percentile(column, [5, 25, 50, 75, 95])
            print(f"    {name:6s} cm  p5 {p[0]:5.1f}  p25 {p[1]:5.1f}  median {p[2]:5.1f}  p75 {p[3]:5.1f}  p95 {p[4]:5.1f}")


if __name__ == "__main__":
    main()
