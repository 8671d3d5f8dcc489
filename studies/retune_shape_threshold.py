"""Re-tune the detector's delta_s (association.shape_similarity) by replay over several scenes.

    python studies/retune_shape_threshold.py TABLES_DIR [TABLES_DIR ...] [--values 0.5,0.55,...]

Each TABLES_DIR holds the tables of one `ndfa detect SRC TGT --tables TABLES_DIR` run (with the
weights under study). The detector is replayed on each run's observations (`ndfa.run.replay`: no
re-encoding, well under a second a scene) at every delta_s, and the TP / FP / FN summed over the
scenes are printed per value, with precision and recall; the scene-level registration prior a
run used is not replayed (the masked scenes' poses are given, where no prior is offered).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import polars as pl

from ndfa.change.config import DetectorConfig
from ndfa.eval.runs import score_replay
from ndfa.run.replay import replay


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tables", nargs="+", type=Path)
    parser.add_argument("--values", default="0.5,0.55,0.6,0.65,0.7,0.75,0.8,0.85,0.9")
    args = parser.parse_args()
    values = [float(v) for v in args.values.split(",")]
    observations = {path.name: pl.read_parquet(path / "observations.parquet") for path in args.tables}
    base = DetectorConfig()
    print(f"{'delta_s':>8} {'TP':>4} {'FP':>4} {'FN':>4} {'P':>6} {'R':>6}  per scene TP/FP/FN")
    for value in values:
        config = dataclasses.replace(base, association=dataclasses.replace(base.association, shape_similarity=value))
        totals, per_scene = [0, 0, 0], []
        for name, table in observations.items():
            result = score_replay(replay(table, config))
            if result is None:
                raise SystemExit(f"{name}: its observations table has no ground-truth labels")
            totals = [totals[0] + result.tp, totals[1] + result.fp, totals[2] + result.fn]
            per_scene.append(f"{name} {result.tp}/{result.fp}/{result.fn}")
        tp, fp, fn = totals
        precision, recall = tp / max(tp + fp, 1), tp / max(tp + fn, 1)
        marker = "  <- current" if abs(value - base.association.shape_similarity) < 1e-9 else ""
        print(f"{value:8.2f} {tp:4d} {fp:4d} {fn:4d} {precision:6.3f} {recall:6.3f}  {', '.join(per_scene)}{marker}")


if __name__ == "__main__":
    main()
