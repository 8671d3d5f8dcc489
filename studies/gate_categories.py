"""The objectness gate per category on simulated views: which objects each gate keeps, and which
non-objects it lets through (docs/segmentation.md, "Objects, not mugs").

    python studies/gate_categories.py REC.mcap [REC.mcap ...] [--step 4]

Each frame of a recording with instance masks (a scene of `ndfa ingest sim --categories all
--clutter N`: objects of every category, papers and cables) is segmented from its depth alone, with
the mugs' gate (`SegmentationConfig()`), the objects' (`.for_objects()`) and the objects' without
its outline rule (`max_outline_goes_on=None`: docs/categories.md, "Objects in real rooms"). A view
of an object (its mask holds `VISIBLE_PIXELS` pixels with depth) is *kept* when a segment matches it
with IoU >= 0.5 (`ndfa.eval.segmentation.match_segments`); recall per category is kept / views. A
kept segment that matches no object is a *false object*, named by what most of its pixels are: a
paper, a cable, part of an object (IoU < 0.5), or the room and the tables (walls' edges, table
rims, the floor). Categories: the ground truth's `category` of the scene's objects and clutter
(an object without one is a mug; a clutter item without one is its kind, a non-object).
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import Counter

import numpy as np

from ndfa.core.conventions import depth_in_range, is_visible
from ndfa.eval.segmentation import match_segments
from ndfa.io.recording import RecordingReader
from ndfa.perception.segmentation import segment_frame
from ndfa.perception.segmentation_config import SegmentationConfig

GATES = {"mugs": SegmentationConfig(), "objects": SegmentationConfig().for_objects(),
         "objects without the outline": dataclasses.replace(SegmentationConfig().for_objects(), max_outline_goes_on=None)}


def instance_names(truth: dict) -> dict[int, str]:
    """Instance id -> its category, or a non-object's kind ("paper:" prefixed: "non-object:paper")."""
    names = {int(o["instance_id"]): str(o.get("category", "mug")) for o in truth.get("objects", [])}
    for item in truth.get("clutter", []):
        category = item.get("category")
        names[int(item["instance_id"])] = category if category else f"non-object:{item['kind']}"
    return names


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recordings", nargs="+")
    parser.add_argument("--step", type=int, default=4)
    args = parser.parse_args()

    views: Counter[str] = Counter()
    kept = {gate: Counter() for gate in GATES}
    false_objects = {gate: Counter() for gate in GATES}
    frames = 0
    for path in args.recordings:
        reader = RecordingReader(path)
        names = instance_names(reader.ground_truth or {})
        for frame in reader.frames(step=args.step):
            frames += 1
            with_depth = depth_in_range(frame.depth)
            ids, counts = np.unique(frame.instances[with_depth], return_counts=True)
            visible = {int(i): names.get(int(i), "?") for i, n in zip(ids, counts) if i and is_visible(n)}
            views.update(visible.values())
            for gate, config in GATES.items():
                labels = segment_frame(frame, config)
                matched = match_segments(labels, frame.instances, with_depth)
                found = {instance for _, instance, iou in matched if iou >= 0.5 and instance}
                kept[gate].update(name for i, name in visible.items() if i in found)
                for _, instance, iou in matched:
                    name = names.get(int(instance), "room and tables") if instance else "room and tables"
                    if name.startswith("non-object"):
                        false_objects[gate][name] += 1
                    elif iou < 0.5:
                        false_objects[gate]["part of an object" if instance else name] += 1
    print(f"{frames} frames of {len(args.recordings)} recordings, every {args.step}th\n")
    print("| category | views | " + " | ".join(f"kept, {gate}" for gate in GATES) + " |")
    print("|---|---|" + "---|" * len(GATES))
    for name in sorted(views, key=lambda n: (n.startswith("non-object"), n)):
        cells = [f"{kept[g][name]} ({kept[g][name] / views[name]:.0%})" for g in GATES]
        print(f"| {name} | {views[name]} | {' | '.join(cells)} |")
    print("\nfalse objects (kept segments that are no object), per gate:")
    for gate in GATES:
        print(f"  {gate}: {dict(false_objects[gate]) or 'none'}")


if __name__ == "__main__":
    main()
