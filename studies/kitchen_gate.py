"""The mugs' and the objects' gate (with and without its outline rule) on the 7-Scenes kitchen: the
segments each keeps that are not one of the two mugs (docs/segmentation.md, "Objects, not mugs";
docs/categories.md, "Objects in real rooms").

    python studies/kitchen_gate.py ../shared/data/redkitchen_7scenes [--step 10]

Frames 0-499 every `--step`-th, levelled by the dataset's gravity, given poses (read as
tests/test_objectness.py reads them); a segment whose center lies within 8 cm of a mug (the test's
positions) is that mug, any other is listed with its center (world, metres) and shape.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import test_objectness as kitchen  # noqa: E402  (the kitchen's frames and mugs, as the tests read them)

from ndfa.perception.segmentation import Outline, _world_points, explain_frame  # noqa: E402
from ndfa.perception.segmentation_config import SegmentationConfig  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--step", type=int, default=10)
    args = parser.parse_args()
    kitchen.REDKITCHEN = args.dataset
    gates = {"mugs": SegmentationConfig(), "objects": SegmentationConfig().for_objects(),
             "objects without the outline": dataclasses.replace(SegmentationConfig().for_objects(), max_outline_goes_on=None)}
    counts = {gate: {"mug": 0, "other": 0} for gate in gates}
    others: dict[str, list[str]] = {gate: [] for gate in gates}
    attached: Counter[str] = Counter()  # the objects' gate's "attached" segments, by the parts that went on
    for index in range(0, 500, args.step):
        frame = kitchen._redkitchen_frame(index)
        for gate, config in gates.items():
            labels, verdicts = explain_frame(frame, config)
            attached.update(_parts(v.outline) for v in verdicts if v.rejected == "attached" and v.outline is not None)
            shapes = {v.label: v.shape for v in verdicts}
            for label in range(1, int(labels.max()) + 1):
                rows, cols = np.nonzero(labels == label)
                center = _world_points(frame, rows, cols).mean(axis=0)
                if min(np.linalg.norm(center[:2] - mug) for mug in (kitchen._PATTERNED_MUG, kitchen._WHITE_MUG)) < 0.08:
                    counts[gate]["mug"] += 1
                    continue
                counts[gate]["other"] += 1
                s = shapes.get(label)
                others[gate].append(f"frame {index} {np.round(center, 2).tolist()}" + ("" if s is None else
                                    f" top {s.top_m * 100:.1f} cm, {s.length_m * 100:.1f} x {s.width_m * 100:.1f} cm "
                                    f"at {s.depth_m:.2f} m"))
    print(counts)
    print("turned away by the outline rule, by the parts going on over half:", dict(sorted(attached.items())))
    for gate in gates:
        print(f"gate {gate}, segments that are no mug:")
        print("\n".join(f"  {line}" for line in others[gate]))


def _parts(outline: Outline) -> str:
    """Which parts of `Outline.goes_on` exceed 0.5: "top", "sides", "hanging", joined by "+"."""
    sides = None if outline.left is None or outline.right is None else min(outline.left, outline.right)
    return "+".join(name for name, share in (("top", outline.top), ("sides", sides), ("hanging", outline.hanging))
                    if share is not None and share > 0.5)


if __name__ == "__main__":
    main()
